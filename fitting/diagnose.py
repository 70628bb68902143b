"""Sim-to-real gap diagnosis: where the gap lies, which unmodelled effect explains it, how far
it shrinks. This module runs the steps and ranks the candidates; the steps are modules of
their own:

* the forward model (baseline + effects, simulations cached): ``fitting.forward``;
* the noise level and the residual breakdown: ``fitting.gap``;
* the screening at the baseline: ``fitting.screening``;
* the fits of candidate effects: ``fitting.effect_fit``.

Inputs: a baseline forward model (a dejax ``Problem`` whose material carries two dormant
viscous units, see ``fitting.effects``) and measured traces (``fitting.traces.Trace`` with a
``response`` channel and a commanded voltage history) with role "fit" or "holdout".

(a) WHERE: baseline residuals broken down per trace/condition, per cycle, loading vs
    unloading (sign of d phi_command/dt), transient (first cycle) vs steady state, and
    per cycle feature (mean, amplitude, phase lag to the command, loop area in the
    (command, output) plane, 2nd/1st harmonic ratio).
(b) WHICH: screened first, at the baseline: one forward-difference column of the fit
    residuals per effect parameter (a simulation per model-effect parameter, none for the
    sensor effects), and for every candidate and every pair the bounded linear
    least-squares fit of the baseline residuals on its columns (a score-type test: the
    SSE and BIC the first-order model predicts; the parameters of an effect switched off
    by its gate, such as a unit's relaxation time at zero modulus, act on nothing there and
    get a zero column without a simulation). The best ``fit_top`` candidates (and, when
    no single leaves residuals at the noise level, the best ``fit_pairs`` screened pairs,
    more while none does) are then fitted on the fit traces (their parameters only, the
    baseline held; start = the better of the off values and the screening's step; bounded
    Levenberg-Marquardt of ``fitting.least_squares`` on normalised parameters with a
    forward-difference Jacobian, Broyden-updated between its evaluations, so the one
    compiled ``simulate`` is reused); once a fitted single leaves residuals at the noise
    level, a further single is fitted only if its screened BIC comes within ``SKIP_MARGIN``
    x ``bic_threshold`` of that one's (else it could not be an equivalent explanation). Ranked:
    significant effects first (Delta BIC < -``bic_threshold``, and a holdout RMS not above
    the baseline's by more than its sampling sd 1/sqrt(2 n_hold): an effect that improves
    the fit traces but worsens the withheld ones explains nothing), within them by the holdout
    RMS; the screened-out ones follow with their linearized figures, never chosen.
    Gauss-Newton standard errors s^2 (J^T J)^-1 at the optimum.
    With ``refit`` (``dejax diagnose --refit``) the baseline's own parameters (factors on
    them, ``effects.refit_names``) are first refitted alone, that refitted baseline becomes
    the reference, and they are refitted jointly with every candidate (screening included);
    they count in no candidate's k.
(c) HOW FAR: RMS and "gap" = sqrt(max(RMS^2 - sigma^2, 0)) before/after, on fit and
    holdout, overall and per feature, each with its spread (``gap.shrinkage_spread``:
    replicate noise and the fitted effect's Gauss-Newton covariance, ``fitted_covariance``).

Noise level sigma: given, or estimated from the measured traces by 4th differences
(sigma^2 = mean((Delta^4 y)^2)/70, unbiased for white noise when the signal is smooth
over 5 samples). Verdict "no significant gap" when the baseline's fit residual passes
the chi-square test RMS^2/sigma^2 <= 1 + z sqrt(2/n) (z = 4) and no candidate lowers
BIC by more than ``bic_threshold`` (10: "very strong" evidence).

The forward model's builders (``forward_from_experiment``, ``block_forward``,
``synthetic_traces``) are named here too, as the diagnosis's inputs. The written report
(markdown, JSON, figures): ``fitting.report``; the verb: ``fitting.cli``.
"""
from __future__ import annotations

import dataclasses
import math
import time as _time
from typing import Mapping, Sequence

import numpy as np

from . import effects as fx
from .effect_fit import covariance_factor, fit_effects
from .forward import Forward, block_forward, fd_jacobian, forward_from_experiment, residuals_at, synthetic_traces
from .gap import breakdown, estimate_noise, gap, rms, shrinkage_spread
from .screening import criteria, screen
from .traces import Trace

__all__ = ["CandidateResult", "Diagnosis", "diagnose", "Forward", "forward_from_experiment", "block_forward",
           "synthetic_traces"]


@dataclasses.dataclass
class CandidateResult:
    name: str
    values: dict
    stderr: dict
    k: int
    sse_fit: float
    rms_fit: float
    rms_holdout: float | None
    aic: float
    bic: float
    d_aic: float
    d_bic: float
    n_sims: int
    seconds: float
    significant: bool = False
    worse_on_holdout: bool = False  # its holdout RMS exceeds the baseline's (beyond sampling)
    fitted: bool = True  # False: screened out (its figures are the screening's linearized ones)
    at_bounds: list = dataclasses.field(default_factory=list)  # "effect.param" fitted onto a bound (not off)

    def as_dict(self):
        return dataclasses.asdict(self)


@dataclasses.dataclass
class Diagnosis:
    verdict: str
    best: str | None
    noise: float
    chi2_ratio: float
    chi2_limit: float
    baseline: dict
    ranking: list
    breakdown_before: dict
    breakdown_after: dict | None
    shrinkage: dict | None
    n_fit: int
    seconds: float
    preds: dict = dataclasses.field(default_factory=dict, repr=False)
    # significant candidates the data do not tell apart from the best (see ``equivalent``)
    alternatives: list = dataclasses.field(default_factory=list)

    def table(self) -> str:
        lines = [f"{'rank':>4} {'effect':<20} {'k':>2} {'dBIC':>9} {'dAIC':>9} {'RMS fit':>10} {'RMS hold':>10} "
                 f"{'sig':>3}  parameters (+- 1 sd)"]
        for i, c in enumerate(self.ranking):
            pv = ", ".join(f"{n}.{k}={v:.4g}+-{c['stderr'].get(n, {}).get(k, float('nan')):.2g}"
                           for n, d in c["values"].items() for k, v in d.items())
            hold = f"{c['rms_holdout']:.3e}" if c["rms_holdout"] is not None else "-"
            if not c.get("fitted", True):
                pv += "  (screened out; linearized at the baseline)"
            if c.get("at_bounds"):
                pv += f"  (at a bound: {', '.join(c['at_bounds'])})"
            if c.get("worse_on_holdout"):
                pv += "  (worse than the baseline on the withheld traces: no explanation)"
            lines.append(f"{i + 1:>4} {c['name']:<20} {c['k']:>2} {c['d_bic']:>9.1f} {c['d_aic']:>9.1f} "
                         f"{c['rms_fit']:>10.3e} {hold:>10} {'*' if c['significant'] else '':>3}  {pv}")
        b = self.baseline
        hold = f"{b['rms_holdout']:.3e}" if b["rms_holdout"] is not None else "-"
        lines.insert(1, f"{'-':>4} {'baseline':<20} {0:>2} {0.0:>9.1f} {0.0:>9.1f} {b['rms_fit']:>10.3e} {hold:>10}")
        return "\n".join(lines)

    def as_dict(self):
        d = dataclasses.asdict(self)
        d.pop("preds")
        return d


SKIP_MARGIN = 10.0
"""Once a fitted single is at the noise level, a single whose screened BIC lies more than
SKIP_MARGIN x bic_threshold above it is not fitted (the screening's linearization was seen
to be pessimistic by tens: a sensor latency screened above a voltage lag it then equalled)."""


def diagnose(fwd: Forward, traces: Sequence[Trace], candidates: Sequence[str] | None = None,
             noise: float | None = None, bic_threshold: float = 10.0, z: float = 4.0, max_iter: int = 8,
             start: Mapping | None = None, verbose: bool = False, fit_top: int = 3, pairs: bool = True,
             fit_pairs: int = 3, max_pairs: int = 8, refit: Sequence[str] = ()) -> Diagnosis:
    """Run (a)-(c) of the module docstring. ``candidates``: effect names (default: all).

    ``fit_top``: how many candidates, best screened first, are fitted (0: every one, no
    screening); ``pairs``: also screen every pair and fit, best screened first, those whose
    screened BIC beats the best single's by ``bic_threshold``: ``fit_pairs`` of them, and
    more (up to ``max_pairs``) while no fitted candidate leaves residuals at the noise level
    (a pair of near-equivalent effects can screen above the true one); none when a single
    effect already does.

    ``refit``: material parameters of the baseline (e.g. the experiment's ``[fit] free``)
    refitted with every candidate (``effects.refit_names``: a factor in [1/10, 10] on each):
    first alone, and that refitted baseline is the reference of every comparison (its
    parameters are the baseline's own, counted in no candidate's k); then jointly with each
    candidate, so that an effect is not credited with what the baseline's parameters, fitted
    without it, absorbed (or failed to absorb) of the data. Each fit then has ``max_iter`` + 3
    per refitted parameter evaluations (more parameters, more steps to converge)."""
    t0 = _time.time()
    fit = [tr for tr in traces if tr.role == "fit"]
    hold = [tr for tr in traces if tr.role != "fit"]
    if not fit:
        raise ValueError("diagnose: no trace with role 'fit'")
    candidates = list(candidates or fx.names(fwd.pieces0))
    sigma = estimate_noise(traces) if noise is None else float(noise)
    n = int(sum(len(tr) for tr in fit))

    if verbose:
        print(f"[diagnose] baseline: simulating {len(traces)} trace(s) (the first call compiles the simulation) ...",
              flush=True)
    base_pred = dict(zip((tr.name for tr in traces), fwd.predict_many([({}, tr) for tr in traces])))
    if verbose:
        print(f"[diagnose] baseline done in {_time.time() - t0:.1f} s; {len(candidates)} candidate effect(s)",
              flush=True)
    refit_fx = fx.refit_names(refit)
    max_iter = max_iter + 3 * len(refit_fx)
    base_fx: dict = {}  # the baseline's refit factors (none without refit)
    refit_info = None
    if refit_fx:
        if fwd.pieces0.model is not None:  # a unit the baseline lacks: a clear error before any fit
            fx.apply_effects(fwd.pieces0, {name: {} for name in refit_fx})
        ts = _time.time()
        vals, sd, sse_r, _ = fit_effects(fwd, refit_fx, fit, max_iter=max_iter)
        base_fx = {name: vals[name] for name in refit_fx}
        before_refit = {
            "rms_fit": rms(np.concatenate([base_pred[tr.name] - tr.y for tr in fit])),
            "rms_holdout": rms(np.concatenate([base_pred[tr.name] - tr.y for tr in hold])) if hold else None}
        base_pred = dict(zip((tr.name for tr in traces), fwd.predict_many([(base_fx, tr) for tr in traces])))
        refit_info = {"values": {n: v["factor"] for n, v in base_fx.items()},
                      "stderr": {n: v["factor"] for n, v in sd.items()}, "before": before_refit}
        if verbose:
            print(f"[diagnose] baseline refitted ({', '.join(refit)}) in {_time.time() - ts:.1f} s: factors "
                  + ", ".join(f"{n[len(fx.REFIT_PREFIX):]} x{v:.4g}" for n, v in refit_info["values"].items())
                  + f"; RMS fit {before_refit['rms_fit']:.3e} -> {math.sqrt(sse_r / max(n, 1)):.3e}", flush=True)
    candidates = [c for c in candidates if c not in refit_fx]
    r0 = np.concatenate([base_pred[tr.name] - tr.y for tr in fit])
    sse0 = float(r0 @ r0)
    aic0, bic0 = criteria(sse0, n, 0)
    rms_h0 = rms(np.concatenate([base_pred[tr.name] - tr.y for tr in hold])) if hold else None
    n_hold = int(sum(len(tr) for tr in hold))
    baseline = {"sse_fit": sse0, "rms_fit": rms(r0), "rms_holdout": rms_h0, "aic": aic0, "bic": bic0,
                "refit": refit_info}
    chi = (sse0 / n) / sigma ** 2 if sigma > 0 else float("inf")
    chi_lim = 1.0 + z * math.sqrt(2.0 / n)
    before = breakdown(traces, [base_pred[tr.name] for tr in traces])

    results = []
    jacobians = {}  # of the fitted candidates, at their optimum, on the fit traces
    scr = None

    def screened_only(g):
        """Record the single ``g`` with the screening's linearized figures (not fitted)."""
        sc = scr[g]
        k = fx.get(g[0]).n_params
        aic, bic = criteria(sc.sse, n, k)
        vals = fx.values_at(list(g) + refit_fx, sc.z)
        results.append(CandidateResult(g[0], vals, {}, k, sc.sse, math.sqrt(sc.sse / n), None, aic, bic,
                                       aic - aic0, bic - bic0, 0, 0.0, fitted=False))

    pair_queue = []
    to_fit = [(name,) for name in candidates]
    if fit_top and len(candidates) > fit_top:
        ts = _time.time()
        s0 = fwd.n_sims
        scr = screen(fwd, candidates, fit, r0, pairs=pairs, extra=refit_fx, base=base_fx)
        singles = sorted(((name,) for name in candidates), key=lambda g: scr[g].d_bic)
        to_fit = singles[:fit_top]
        if pairs:  # pair candidates, best screened first, that beat the best single's screened BIC
            pair_queue = [g for g in sorted((g for g in scr if len(g) == 2), key=lambda g: scr[g].d_bic)
                          if scr[g].d_bic < scr[singles[0]].d_bic - bic_threshold]
        if verbose:
            print(f"[diagnose] screened {len(candidates)} candidate(s){' and their pairs' if pairs else ''} at the "
                  f"baseline in {_time.time() - ts:.1f} s ({fwd.n_sims - s0} simulation(s)); fitting "
                  + ", ".join("+".join(g) for g in to_fit)
                  + (f", then up to {max_pairs} of the pairs " + ", ".join("+".join(g) for g in pair_queue[:max_pairs])
                     if pair_queue else ""), flush=True)
        for g in singles[fit_top:]:
            screened_only(g)

    def at_noise(rs):
        return any(r.sse_fit / n <= chi_lim * sigma ** 2 for r in rs)

    def queue():
        """Singles, then pairs: none when a single leaves residuals at the noise level; the best
        ``fit_pairs`` screened pairs, and further ones (up to ``max_pairs``) while no fitted
        candidate reaches the noise level. Once a fitted single leaves residuals at the noise
        level, a further single is fitted only if its screened (linearized) BIC comes within
        ``SKIP_MARGIN`` x ``bic_threshold`` of that single's: one that could be an equivalent
        explanation (the linearization can be pessimistic by tens)."""
        for g in to_fit:
            done = [r for r in results if r.fitted and "+" not in r.name]
            if scr is not None and at_noise(done):
                best_bic = min(r.bic for r in done if r.sse_fit / n <= chi_lim * sigma ** 2)
                if criteria(scr[g].sse, n, fx.get(g[0]).n_params)[1] > best_bic + SKIP_MARGIN * bic_threshold:
                    if verbose:
                        print(f"  {g[0]} not fitted: its screened BIC is more than {SKIP_MARGIN * bic_threshold:g} "
                              "above a fitted effect's at the noise level", flush=True)
                    screened_only(g)
                    continue
            yield g
        for j, g in enumerate(pair_queue[:max_pairs]):
            fitted = [r for r in results if r.fitted]
            if at_noise(r for r in fitted if "+" not in r.name):
                if verbose:
                    print("  pairs not fitted: a single effect leaves residuals at the noise level", flush=True)
                return
            if j >= fit_pairs and at_noise(fitted):
                return
            yield g

    n_queue = len(to_fit) + len(pair_queue[:max_pairs])  # at most
    for i, g in enumerate(queue()):
        ts = _time.time()
        s0 = fwd.n_sims
        vals, sd, sse, jacobians[g] = fit_effects(fwd, list(g) + refit_fx, fit,
                                                  start={**dict(start or {}), **base_fx}, max_iter=max_iter,
                                                  z0=None if scr is None else scr[g].z)
        k = sum(fx.get(name).n_params for name in g)
        aic, bic = criteria(sse, n, k)
        rh = rms(fwd.residuals([vals], hold)[0]) if hold else None
        c = CandidateResult("+".join(g), vals, sd, k, sse, math.sqrt(sse / n), rh, aic, bic, aic - aic0, bic - bic0,
                            fwd.n_sims - s0, _time.time() - ts, at_bounds=at_bounds(vals))
        # a pair must also beat each of its fitted singles by the threshold (nested models)
        singles_bic = [r.bic for r in results if r.fitted and r.name in g and len(g) > 1]
        c.significant = c.d_bic < -bic_threshold and all(c.bic < b - bic_threshold for b in singles_bic)
        # an effect that improves the fit traces but worsens the withheld ones (beyond the
        # RMS's sampling sd) is no explanation
        c.worse_on_holdout = rh is not None and rh > rms_h0 * (1.0 + 1.0 / math.sqrt(2.0 * n_hold))
        c.significant = c.significant and not c.worse_on_holdout
        results.append(c)
        if verbose:
            rh_text = "-" if rh is None else f"{rh:.3e}"
            print(f"  [{i + 1}/{n_queue}] {c.name:<20} dBIC={c.d_bic:9.1f} rms_fit={c.rms_fit:.3e} "
                  f"rms_hold={rh_text} ({c.seconds:.1f} s)", flush=True)

    def key(c):
        return (not c.significant, not c.fitted, c.rms_holdout if c.rms_holdout is not None else c.rms_fit, c.bic)

    results.sort(key=key)
    best = results[0] if results and results[0].significant else None
    if best is not None:
        verdict = f"gap explained by '{best.name}'"
    elif chi > chi_lim:
        verdict = "significant gap, not explained by the candidate effects"
    else:
        verdict = "no significant gap"

    after = shrink = None
    preds = {"baseline": base_pred}
    if best is not None:
        bp = dict(zip((tr.name for tr in traces), fwd.predict_many([(best.values, tr) for tr in traces])))
        preds[best.name] = bp
        after = breakdown(traces, [bp[tr.name] for tr in traces])
        shrink = {}
        for role, rms0, rms1 in (("fit", baseline["rms_fit"], best.rms_fit), ("holdout", rms_h0, best.rms_holdout)):
            if rms0 is None:
                continue
            g0, g1 = gap(rms0, sigma), gap(rms1, sigma)
            shrink[role] = {"rms_before": rms0, "rms_after": rms1, "gap_before": g0, "gap_after": g1,
                            "gap_shrinkage": 1.0 - g1 / g0 if g0 > 0 else None}
        shrink["features"] = {}
        for f, d0 in before["features"].items():
            g0, g1 = d0["rms_gap"], after["features"][f]["rms_gap"]
            shrink["features"][f] = {"gap_before": g0, "gap_after": g1, "shrinkage": 1.0 - g1 / g0 if g0 > 0 else None}
        names = [*best.name.split("+"), *refit_fx]
        jac, cov_sqrt = fitted_covariance(fwd, names, best.values, traces, jacobians[tuple(best.name.split("+"))],
                                          best.sse_fit)
        spread = shrinkage_spread(traces, [base_pred[tr.name] for tr in traces], [bp[tr.name] for tr in traces],
                                  sigma, jac, cov_sqrt)
        for role in ("fit", "holdout"):
            if role in shrink:
                shrink[role]["spread"] = spread[role]
        for f in shrink["features"]:
            shrink["features"][f]["spread"] = spread["features"].get(f)
    alts = equivalent(best, results, n_hold=int(sum(len(tr) for tr in hold)) if hold else n) if best else []
    return Diagnosis(verdict, best.name if best else None, sigma, chi, chi_lim, baseline,
                     [c.as_dict() for c in results], before, after, shrink, n, _time.time() - t0, preds, alts)


def fitted_covariance(fwd: Forward, names: Sequence[str], values: Mapping, traces: Sequence[Trace],
                      J_fit: np.ndarray, sse: float) -> tuple[list[np.ndarray], np.ndarray]:
    """The fitted effects ``names`` at ``values``, ``J_fit`` their fit's Jacobian on the fit
    traces (``fit_effects``): per trace of ``traces`` the (n_i, k) Jacobian of the prediction
    with respect to the normalized parameters z (the fit's rows; forward differences on the
    other traces, k + 1 simulations of each), and S (k, k') with S S^T = s^2 (J^T J)^+
    (``effect_fit.covariance_factor``, s^2 = sse / (n_fit - k))."""
    plist = fx.param_list(names)
    z = np.array([p.z_of(values.get(nm, {}).get(p.name, p.off)) for nm, p in plist])
    hold = [tr for tr in traces if tr.role != "fit"]
    J_hold = np.zeros((0, z.size))
    if hold:
        resid_many = residuals_at(fwd, names, hold)
        J_hold = fd_jacobian(resid_many, z, resid_many([z])[0])  # d residual / dz = d prediction / dz
    rows = {"fit": iter(np.split(J_fit, np.cumsum([len(tr) for tr in traces if tr.role == "fit"])[:-1])),
            "hold": iter(np.split(J_hold, np.cumsum([len(tr) for tr in hold])[:-1]))}
    per_trace = [next(rows["fit" if tr.role == "fit" else "hold"]) for tr in traces]
    C, _ = covariance_factor(J_fit, sse / max(J_fit.shape[0] - z.size, 1))
    return per_trace, C


def at_bounds(values: Mapping) -> list[str]:
    """"effect.param" of the parameters in ``values`` ({effect: {param: value}}) that sit on a
    bound of their range other than their off value: the optimum lies beyond the range."""
    out = []
    for name, vals in values.items():
        for p in fx.get(name).params:
            x = vals.get(p.name, p.off)
            z = p.z_of(x)
            if (z <= 1e-6 or z >= 1.0 - 1e-6) and not math.isclose(x, p.off, rel_tol=1e-9, abs_tol=1e-300):
                out.append(f"{name}.{p.name}")
    return out


def equivalent(best: CandidateResult, results, n_hold: int, z: float = 2.0) -> list:
    """Names of the other significant fitted candidates whose holdout mean square (fit mean
    square without holdout traces) is within ``z`` standard deviations of the best's: an MSE
    over n points of Gaussian residuals has relative sd sqrt(2/n), so within a factor
    1 + z sqrt(2 / n_hold) the withheld data do not separate them (e.g. a creep unit whose
    relaxation time far exceeds the record acts as an elastic stiffness)."""
    def mse(c):
        return (c.rms_holdout if c.rms_holdout is not None else c.rms_fit) ** 2

    lim = mse(best) * (1.0 + z * math.sqrt(2.0 / n_hold))
    return [c.name for c in results if c is not best and c.fitted and c.significant and mse(c) <= lim]
