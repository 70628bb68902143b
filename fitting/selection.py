"""Choosing between fitted models: least squares in the data's unit, information criteria,
multi-start fits and whether they reach the same optimum, per-curve errors.

* ``per_point_least_squares(targets, noise)``: the targets with ``scale`` = ``noise``
  and ``weight`` = their number of points, so that ``fitting.fit.fit`` minimizes
  ``sum over all points of ((pred - y) / noise)^2``: ordinary least squares with one
  noise level for every point (the digitizing noise of a set of curves), which is what
  the Gaussian information criteria below assume. (fit's default, the mean square of
  each trace over its amplitude, weighs a small curve as much as a large one.)
* ``information_criteria(rss, n, k)``: AIC and BIC of a least-squares fit with Gaussian
  residuals of one unknown variance: ``n ln(RSS / n) + 2 k`` and ``n ln(RSS / n) + k ln n``
  (additive constants dropped: compare only fits of the same n points). ``fit_criteria
  (result)``: the same for a FitResult's training traces.
* ``sort_units(params)``: the viscous units renumbered by increasing relaxation time
  ``tau_i = eta_i / (2 mu_i)`` (units are interchangeable: a permutation is the same
  model), so that fits from different starts compare parameter by parameter;
  ``unit_order(params)`` and ``renumber(names, order)`` apply that renumbering to other
  name-keyed results (standard errors, correlation labels).
* ``multistart(run, starts)``: ``run(start) -> FitResult`` for every start, timed; a start
  whose simulation fails (FloatingPointError) is recorded, not raised. ``agreement(results)``:
  how many starts reach the best loss (relative ``loss_rtol``) and the best parameters
  (``|ln p - ln p_best| <= param_atol`` for every free parameter, units sorted first).
* ``curve_errors(result)``: per trace, RMS error and peak error (model peak minus measured
  peak), in the trace's unit.
* ``text_table(header, rows)``: a fixed-width text table.
"""
from __future__ import annotations

import dataclasses
import math
import time as _time
from typing import Callable, Mapping, Sequence

import numpy as np

from dejax import parameters

__all__ = ["per_point_least_squares", "information_criteria", "fit_criteria", "relaxation_times", "unit_order", "renumber", "sort_units",
           "StartOutcome", "multistart", "agreement", "curve_errors", "text_table"]


def per_point_least_squares(targets, noise: float) -> list:
    """The targets (``fitting.traces.Trace``) with ``scale = noise`` and ``weight = number of
    points``: fit's loss becomes sum_points ((pred - y) / noise)^2."""
    if not noise > 0:
        raise ValueError(f"per_point_least_squares: noise = {noise} must be > 0")
    return [dataclasses.replace(t, scale=float(noise), weight=float(np.asarray(t.y).size)) for t in targets]


def information_criteria(rss: float, n: int, k: int) -> dict:
    """dict(aic, bic, rss, n, k) of a least-squares fit of ``k`` parameters to ``n`` points
    with residual sum of squares ``rss`` (Gaussian residuals, one unknown variance)."""
    n, k = int(n), int(k)
    if n <= 0 or k < 0:
        raise ValueError(f"information_criteria: need n > 0 and k >= 0, got n = {n}, k = {k}")
    if not rss > 0:
        raise ValueError(f"information_criteria: rss = {rss} must be > 0")
    base = n * math.log(rss / n)
    return dict(aic=base + 2 * k, bic=base + k * math.log(n), rss=float(rss), n=n, k=k)


def _residuals(result, group):
    return np.concatenate([np.asarray(result.predictions[t.name]) - t.y for t in group])


def fit_criteria(result) -> dict:
    """``information_criteria`` of a FitResult on its training traces (every point counts
    once, k = the free parameters)."""
    r = _residuals(result, result.targets)
    return information_criteria(float(r @ r), r.size, len(result.free))


def relaxation_times(params: Mapping[str, float]) -> dict:
    """Unit number -> relaxation time eta_i / (2 mu_i) (s) of every unit in ``params``."""
    out = {}
    for name in params:
        g = parameters.PATTERN.match(name)
        if g and g.group(2) == "mu":
            i = int(g.group(3))
            out[i] = float(params[f"eta_{i}"]) / (2.0 * float(params[name]))
    return dict(sorted(out.items()))


def unit_order(params: Mapping[str, float]) -> dict:
    """Old unit number -> new unit number, the units numbered 1..N by increasing relaxation
    time (ties keep their order)."""
    taus = relaxation_times(params)
    return {old: new for new, old in enumerate(sorted(taus, key=lambda i: taus[i]), start=1)}


def renumber(names, order: Mapping[int, int]):
    """Unit parameter names renumbered by ``order`` (old -> new unit number); other names
    unchanged. ``names``: a dict (keys renamed, values and key order kept) or a sequence
    of names (returned as a list)."""
    def rename(name):
        g = parameters.PATTERN.match(name)
        if g and g.group(2) and int(g.group(3)) in order:
            return f"{g.group(2)}_{order[int(g.group(3))]}"
        return name

    if isinstance(names, Mapping):
        return {rename(k): v for k, v in names.items()}
    return [rename(k) for k in names]


def sort_units(params: Mapping[str, float]) -> dict:
    """``params`` with the viscous units renumbered 1..N by increasing relaxation time
    (each unit's mu, K, Jm, eta move together), in the key order of ``params``."""
    out = renumber(params, unit_order(params))
    return {k: out[k] for k in params}


@dataclasses.dataclass
class StartOutcome:
    """One start of ``multistart``: its initial parameters, the FitResult (None if the fit
    failed), the failure message, the wall time (s)."""

    start: dict
    result: object | None
    error: str | None
    seconds: float


def multistart(run: Callable, starts: Sequence[Mapping[str, float]], say: Callable | None = print) -> list:
    """``run(start) -> FitResult`` for every start (in order); a FloatingPointError (the
    simulation failed at the start) is recorded in its StartOutcome. Returns the outcomes."""
    out = []
    for i, s in enumerate(starts):
        tic = _time.perf_counter()
        try:
            res, err = run(dict(s)), None
        except FloatingPointError as e:
            res, err = None, str(e)
        dt = _time.perf_counter() - tic
        out.append(StartOutcome(dict(s), res, err, dt))
        if say is not None:
            say(f"start {i + 1}/{len(starts)}: " + (f"loss {res.loss:.6g}" if res is not None else f"failed: {err}")
                + f" ({dt:.1f} s)")
    return out


def agreement(outcomes, loss_rtol: float = 1e-2, param_atol: float = 0.05) -> dict:
    """How the starts of ``multistart`` agree.

    Returns dict(n (starts), n_ok (fits that ran), best (index of the lowest loss), losses,
    same_loss (indices within ``loss_rtol`` of the best loss), same_params (indices whose
    free parameters, units sorted by relaxation time, are within ``param_atol`` in ln p of
    the best's), spread (free parameter -> max |ln p - ln p_best| over same_loss))."""
    res = [o.result if isinstance(o, StartOutcome) else o for o in outcomes]
    ok = [i for i, r in enumerate(res) if r is not None]
    if not ok:
        return dict(n=len(res), n_ok=0, best=None, losses=[None] * len(res), same_loss=[], same_params=[], spread={})
    losses = [None if r is None else float(r.loss) for r in res]
    best = min(ok, key=lambda i: losses[i])
    lb = losses[best]
    same_loss = [i for i in ok if losses[i] <= lb * (1.0 + loss_rtol) + 1e-300]
    free = list(res[best].free)
    p_best = sort_units(res[best].params)
    sorted_p = {i: sort_units(res[i].params) for i in ok}

    def dist(i):
        return {k: abs(math.log(sorted_p[i][k]) - math.log(p_best[k])) for k in free}

    same_params = [i for i in ok if max(dist(i).values()) <= param_atol]
    spread = {k: max(dist(i)[k] for i in same_loss) for k in free}
    return dict(n=len(res), n_ok=len(ok), best=best, losses=losses, same_loss=same_loss, same_params=same_params,
                spread=spread)


def curve_errors(result) -> list[dict]:
    """Per trace of a FitResult (training, then held out): dict(name, role, n, rms,
    peak_data, peak_model, peak_error = peak_model - peak_data, rel_peak_error), in the
    trace's unit; the peaks are the maxima of the measured and predicted values."""
    rows = []
    for role, group in (("fit", result.targets), ("holdout", result.holdout)):
        for t in group:
            pred = np.asarray(result.predictions[t.name])
            e = pred - t.y
            pd, pm = float(np.max(t.y)), float(np.max(pred))
            rows.append(dict(name=t.name, role=role, n=int(t.y.size), rms=float(np.sqrt(np.mean(e * e))),
                             peak_data=pd, peak_model=pm, peak_error=pm - pd,
                             rel_peak_error=(pm - pd) / abs(pd) if pd != 0 else float("nan")))
    return rows


def text_table(header: Sequence[str], rows: Sequence[Sequence], fmt: str = "{:.4g}") -> str:
    """Fixed-width text table: numbers formatted with ``fmt``, strings as they are, columns
    right-aligned to their widest entry."""
    def cell(v):
        if isinstance(v, str):
            return v
        if v is None or (isinstance(v, float) and math.isnan(v)):
            return "-"
        if isinstance(v, (int, np.integer)) and not isinstance(v, bool):
            return str(int(v))
        return fmt.format(v)

    cells = [[str(h) for h in header]] + [[cell(v) for v in r] for r in rows]
    if any(len(r) != len(header) for r in cells):
        raise ValueError("text_table: every row needs one entry per column")
    w = [max(len(r[j]) for r in cells) for j in range(len(header))]
    lines = ["  ".join(c.rjust(w[j]) for j, c in enumerate(r)) for r in cells]
    lines.insert(1, "  ".join("-" * x for x in w))
    return "\n".join(lines)
