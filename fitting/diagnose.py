"""Sim-to-real gap diagnosis: where the gap lies, which unmodelled effect explains it, how far it shrinks.

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
    SSE and BIC the first-order model predicts). The best ``fit_top`` candidates (and the
    best pair when its screened BIC beats the best single's by ``bic_threshold``) are then
    fitted on the fit traces (their parameters only, the baseline held; start = the better
    of the off values and the screening's step; bounded
    Levenberg-Marquardt of ``fitting.least_squares`` on normalised parameters with a
    forward-difference Jacobian, Broyden-updated between its evaluations, so the one
    compiled ``simulate`` is reused), and ranked:
    significant effects first (Delta BIC < -``bic_threshold``), within them by the holdout
    RMS; the screened-out ones follow with their linearized figures, never chosen.
    Gauss-Newton standard errors s^2 (J^T J)^-1 at the optimum.
(c) HOW FAR: RMS and "gap" = sqrt(max(RMS^2 - sigma^2, 0)) before/after, on fit and
    holdout, overall and per feature.

Noise level sigma: given, or estimated from the measured traces by 4th differences
(sigma^2 = mean((Delta^4 y)^2)/70, unbiased for white noise when the signal is smooth
over 5 samples). Verdict "no significant gap" when the baseline's fit residual passes
the chi-square test RMS^2/sigma^2 <= 1 + z sqrt(2/n) (z = 4) and no candidate lowers
BIC by more than ``bic_threshold`` (10: "very strong" evidence).

The written report (markdown, JSON, figures): ``fitting.report``; the verb: ``fitting.cli``.
"""
from __future__ import annotations

import dataclasses
import math
import time as _time
from typing import Mapping, Sequence

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from dejax import cycles
from dejax import integrate as it
from dejax import loads

from . import effects as fx
from .traces import Trace

__all__ = ["Forward", "CandidateResult", "Diagnosis", "diagnose", "estimate_noise",
           "breakdown", "forward_from_experiment"]


class Forward:
    """Baseline + effects -> predicted outputs, reusing one compiled simulate.

    problem: a dejax Problem built with ``effects.augment_material(material)``;
    output: the output name (e.g. "lateral_stretch"); transform: optional y -> y' applied
    to the raw output before the sensor (e.g. stretch -> displacement).

    Newton: modified Newton (a reused factorization, Anderson-mixed corrections) by
    default, 4-5x cheaper per step than full Newton on the block and equal to it within
    1e-11 (lags of 10-20 ms, a fast unit, 100x added mass, at dt = 5e-4 and 1.25e-2 s); a
    run that fails with it is rerun with full Newton. A failed run is scored with output
    1e3 after the failure (a huge residual), not raised."""

    def __init__(self, problem, output: str = "lateral_stretch", rho_inf: float | None = None,
                 newton: it.NewtonOptions = it.NewtonOptions(tol=1e-8, max_iter=60, reuse=True), face_area: float | None = None,
                 pad_to: int | None = None, transform=None):
        self.problem = problem
        self.pieces0 = fx.make_pieces(problem, face_area)
        self.output = output
        self.scheme = it.GeneralizedAlpha(problem.rho_inf if rho_inf is None else rho_inf)
        self.newton = newton
        self.pad_to = pad_to
        self.transform = transform
        self._cache: dict = {}
        self.n_sims = 0

    @staticmethod
    def _key(effects: Mapping, trace: Trace):
        items = []
        for name in sorted(effects):
            if fx.get(name).kind == "model":
                items.append((name, tuple(sorted((k, round(float(v), 15)) for k, v in effects[name].items()))))
        return (trace.name, tuple(items))

    def _launch(self, effects: Mapping, trace: Trace):
        """Start the simulation of ``trace`` with the model effects of ``effects`` (JAX
        dispatches it asynchronously); returns what ``_finish`` turns into the output."""
        model_fx = {k: v for k, v in effects.items() if fx.get(k).kind == "model"}
        p = fx.apply_effects(self.pieces0, model_fx)
        loading = eqx.tree_at(lambda l: l.voltages[0].base, p.loading, trace.voltage_history)
        n = len(trace.time) - 1
        pad = max(self.pad_to or n, n)
        self.n_sims += 1
        return p.model, loading, pad, it.simulate(p.model, loading, trace.time, self.problem.output_fn, self.scheme,
                                                  self.newton, pad_to=pad, control=None)  # fixed steps, as fits

    def _finish(self, effects: Mapping, trace: Trace, launched) -> np.ndarray:
        model, loading, pad, sol = launched
        if not sol.ok and self.newton.reuse and int(sol.status) == int(it.Status.NEWTON_FAILED):
            full = dataclasses.replace(self.newton, reuse=False)
            sol = it.simulate(model, loading, trace.time, self.problem.output_fn, self.scheme, full, pad_to=pad,
                              control=None)
            self.n_sims += 1
        y = np.asarray(sol.outputs[self.output], dtype=float)
        if not sol.ok:  # failed run: report a huge residual rather than crash the ranking
            y = np.where(np.isfinite(y), y, 0.0)
            y[int(sol.fail_step) + 1:] = 1e3
        if self.transform is not None:
            y = np.asarray(self.transform(y))
        return y

    def raw_many(self, jobs: Sequence[tuple]) -> list[np.ndarray]:
        """Model outputs (before the sensor transform) of ``jobs`` = [(effects, trace)], each
        on its trace's time grid: the simulations not cached are all started before any is
        waited for, so that independent runs overlap on a multi-core CPU."""
        if len(self._cache) > 2000:
            self._cache.clear()
        started = {}
        for effects, trace in jobs:
            key = self._key(effects, trace)
            if key not in self._cache and key not in started:
                started[key] = (effects, trace, self._launch(effects, trace))
        for key, (effects, trace, launched) in started.items():
            self._cache[key] = self._finish(effects, trace, launched)
        return [self._cache[self._key(e, t)] for e, t in jobs]

    def raw(self, effects: Mapping, trace: Trace) -> np.ndarray:
        """Model output (before the sensor transform) on the trace's time grid."""
        return self.raw_many([(effects, trace)])[0]

    def predict_many(self, jobs: Sequence[tuple]) -> list[np.ndarray]:
        """Predicted measurements of ``jobs`` = [(effects, trace)] (simulations overlapped)."""
        ys = self.raw_many(jobs)
        out = []
        for (effects, trace), y in zip(jobs, ys):
            sensor_fx = {k: v for k, v in effects.items() if fx.get(k).kind == "sensor"}
            if sensor_fx:
                s = fx.apply_effects(self.pieces0, sensor_fx).sensor
                y = np.asarray(s(jnp.asarray(trace.time), jnp.asarray(y)))
            out.append(y)
        return out

    def predict(self, effects: Mapping, trace: Trace) -> np.ndarray:
        return self.predict_many([(effects, trace)])[0]


# ----------------------------------------------------------------------------- noise, breakdown


def estimate_noise(traces: Sequence[Trace]) -> float:
    """Pooled white-noise sigma from 4th differences: Var(Delta^4 e) = 70 sigma^2."""
    num, den = 0.0, 0
    for tr in traces:
        d = np.diff(np.asarray(tr.y, dtype=float), 4)
        num += float(np.sum(d ** 2))
        den += d.size
    return math.sqrt(num / (70.0 * max(den, 1)))


def breakdown(traces: Sequence[Trace], preds: Sequence[np.ndarray]) -> dict:
    """Residual (model - measured) broken down by trace/condition, cycle, loading/unloading,
    transient/steady state, and features (model - measured, per cycle and mean)."""
    res = {"traces": [], "features": {}}
    feat_acc: dict = {}
    for tr, yp in zip(traces, preds):
        y = tr.y
        r = np.asarray(yp) - y
        command = np.asarray(tr.voltage_history(jnp.asarray(tr.time)))
        ids = cycles.trace_cycle_ids(tr.time, tr.frequency)
        du = np.gradient(command, tr.time)
        load = du > 0
        entry = {"name": tr.name, "role": tr.role, "conditions": dict(tr.conditions), "rms": _rms(r),
                 "mean_residual": float(np.mean(r)),
                 "per_cycle_rms": [_rms(r[ids == c]) for c in range(int(ids.max()) + 1)],
                 "loading_rms": _rms(r[load]), "unloading_rms": _rms(r[~load]),
                 "transient_rms": _rms(r[ids == 0]), "steady_rms": _rms(r[ids > 0]) if np.any(ids > 0) else None}
        fm = cycles.trace_cycle_measures(tr.time, y, command, tr.frequency)
        fp = cycles.trace_cycle_measures(tr.time, yp, command, tr.frequency)
        entry["features"] = {k: {"measured": fm[k].tolist(), "model": fp[k].tolist(),
                                 "gap": (fp[k] - fm[k]).tolist()} for k in fm}
        res["traces"].append(entry)
        for k in fm:
            feat_acc.setdefault(k, []).append((fp[k] - fm[k], fm[k]))
    for k, lst in feat_acc.items():
        gaps = np.concatenate([g for g, _ in lst]) if lst else np.zeros(0)
        meas = np.concatenate([m for _, m in lst]) if lst else np.zeros(0)
        scale = float(np.mean(np.abs(meas))) if meas.size else 0.0
        res["features"][k] = {"rms_gap": _rms(gaps), "mean_gap": float(np.mean(gaps)) if gaps.size else 0.0,
                              "relative": _rms(gaps) / scale if scale > 0 else None}
    return res


def _rms(x) -> float:
    x = np.asarray(x, dtype=float)
    return float(np.sqrt(np.mean(x ** 2))) if x.size else 0.0


# ----------------------------------------------------------------------------- fitting one effect


def _to_z(p: fx.Param, x):
    lo, hi = p.bounds
    if p.scale == "log":
        return (math.log(x) - math.log(lo)) / (math.log(hi) - math.log(lo))
    return (x - lo) / (hi - lo)


def _from_z(p: fx.Param, z):
    lo, hi = p.bounds
    z = min(max(z, 0.0), 1.0)
    if p.scale == "log":
        return math.exp(math.log(lo) + z * (math.log(hi) - math.log(lo)))
    return lo + z * (hi - lo)


def _dx_dz(p: fx.Param, x):
    lo, hi = p.bounds
    return x * (math.log(hi) - math.log(lo)) if p.scale == "log" else (hi - lo)


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
    fitted: bool = True  # False: screened out (its figures are the screening's linearized ones)

    def as_dict(self):
        return dataclasses.asdict(self)


def _residuals(fwd: Forward, effects: Mapping, traces: Sequence[Trace]) -> np.ndarray:
    return _residuals_many(fwd, [effects], traces)[0]


def _residuals_many(fwd: Forward, effects_list: Sequence[Mapping], traces: Sequence[Trace]) -> list:
    """Residuals (model - measured, concatenated over ``traces``) of each effects dict, the
    simulations of all of them started together."""
    preds = fwd.predict_many([(e, tr) for e in effects_list for tr in traces])
    k = len(traces)
    return [np.concatenate([p - tr.y for p, tr in zip(preds[i * k:(i + 1) * k], traces)])
            for i in range(len(effects_list))]


def _plist(names: Sequence[str]) -> list:
    return [(n, p) for n in names for p in fx.get(n).params]


def _z_off(p: fx.Param, given: float | None = None) -> float:
    """Normalized position of a parameter's off value (or ``given``), inside [0, 1]."""
    x = p.off if given is None else given
    if p.scale == "log" and x <= 0:
        return 0.5
    return min(max(_to_z(p, min(max(x, p.bounds[0]), p.bounds[1])), 0.0), 1.0)


def _values_of(plist, z, names, fixed: Mapping) -> dict:
    out = {n: dict(fixed.get(n, fx.get(n).off())) for n in names}
    for (n, p), zi in zip(plist, z):
        out[n][p.name] = _from_z(p, zi)
    return {**fixed, **out}


FD_STEP = 1e-3
"""Finite-difference step of the diagnosis's Jacobians, in the normalized parameters z in
[0, 1] (one-sided, into the box)."""


def _fd_jacobian(resid_many, z, r, h: float = FD_STEP) -> np.ndarray:
    """(m, k) forward differences at z (backward where z + h leaves [0, 1]);
    ``resid_many(list of z) -> list of residuals`` evaluates the k points together."""
    steps = np.where(z + h <= 1.0, h, -h)
    points = []
    for j in range(z.size):
        zz = z.copy()
        zz[j] += steps[j]
        points.append(zz)
    return np.stack([(rj - r) / hj for rj, hj in zip(resid_many(points), steps)], axis=1)


def fit_effects(fwd: Forward, names: Sequence[str], traces: Sequence[Trace], start: Mapping | None = None,
                max_iter: int = 8, fixed: Mapping | None = None, rtol: float = 1e-4, z0=None):
    """Bounded Levenberg-Marquardt (``fitting.least_squares``) over the parameters of the
    effects ``names``, normalised to [0, 1] in lin or log scale, with a forward-difference
    Jacobian at the start and the solution, Broyden-updated between them (so the one
    compiled ``simulate`` is reused); others in ``fixed`` held. Starts from the better of
    the off values and ``z0`` (e.g. the screening's linearized optimum), without ``z0``
    of the off values and the effects' start values. At most ``max_iter`` evaluations
    besides the Jacobians'; stops when an accepted step lowers the SSE by less than
    ``rtol`` (relative). Returns (values, stderr, sse, J)."""
    from .least_squares import levenberg_marquardt

    fixed = dict(fixed or {})
    start = dict(start or {})
    plist = _plist(names)

    def resid_many(zs):
        return _residuals_many(fwd, [_values_of(plist, z, names, fixed) for z in zs], traces)

    def resid(z):
        return resid_many([z])[0]

    # starts: the off values (the baseline, cached) and z0 when given, else the effects'
    # start values; keep the better
    cands = [np.array([_z_off(p, start.get(n, {}).get(p.name, getattr(p, src))) for n, p in plist])
             for src in (("off",) if z0 is not None else ("off", "start"))]
    if z0 is not None:
        cands.append(np.clip(np.asarray(z0, dtype=float), 0.0, 1.0))
    best_z, best_sse = None, np.inf
    for z, r in zip(cands, resid_many(cands)):
        if r @ r < best_sse:
            best_z, best_sse = z, float(r @ r)
    res = levenberg_marquardt(resid, best_z, np.zeros(best_z.size), np.ones(best_z.size),
                              jacobian=lambda z, r: _fd_jacobian(resid_many, z, r), max_evals=max_iter + 1,
                              ftol=rtol, xtol=1e-7, broyden=True)
    z, sse, J = res.x, res.cost, res.J
    # Gauss-Newton covariance in natural units
    vals = _values_of(plist, z, names, fixed)
    stderr = {}
    n, k = res.r.size, z.size
    s2 = sse / max(n - k, 1)
    D = np.array([_dx_dz(p, vals[nm][p.name]) for nm, p in plist])
    Jx = J / D[None, :]
    try:
        cov = s2 * np.linalg.pinv(Jx.T @ Jx)
        sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    except np.linalg.LinAlgError:
        sd = np.full(k, np.nan)
    for (nm, p), s_ in zip(plist, sd):
        stderr.setdefault(nm, {})[p.name] = float(s_)
    return vals, stderr, sse, J


@dataclasses.dataclass
class Screened:
    """A candidate (one effect or a pair) linearized at the baseline: the bounded linear
    least-squares step ``z`` (normalized parameters) of the residuals' first-order model,
    the SSE it predicts, and the BIC change that SSE would give (``d_bic``)."""

    names: tuple
    z: np.ndarray
    sse: float
    d_bic: float


def screen(fwd: Forward, candidates: Sequence[str], traces: Sequence[Trace], r0: np.ndarray,
           pairs: bool = True) -> dict:
    """Score-type screening at the baseline (every effect off): one forward-difference column
    per parameter (a simulation for a model effect, none for a sensor effect), then for each
    candidate and each pair of candidates the bounded linear least-squares fit of the
    baseline residuals ``r0`` on its columns. Returns {names tuple: Screened}."""
    from scipy.optimize import lsq_linear

    plist = _plist(candidates)
    z_off = np.array([_z_off(p) for _, p in plist])

    def resid_many(zs):
        return _residuals_many(fwd, [_values_of(plist, z, candidates, {}) for z in zs], traces)

    r_off = resid_many([z_off])[0]  # the baseline (its simulations cached)
    J = _fd_jacobian(resid_many, z_off, r_off)
    n = r0.size
    sse0 = float(r0 @ r0)
    _, bic0 = _ic(sse0, n, 0)
    cols = {}
    for i, (name, _) in enumerate(plist):
        cols.setdefault(name, []).append(i)
    groups = [(c,) for c in candidates]
    if pairs:
        groups += [(a, b) for i, a in enumerate(candidates) for b in candidates[i + 1:]]
    out = {}
    for g in groups:
        idx = [i for name in g for i in cols[name]]
        A = J[:, idx]
        keep = np.any(A != 0.0, axis=0)  # a parameter without effect at the baseline (tau of a unit that is off)
        dz = np.zeros(len(idx))
        if np.any(keep):
            sol = lsq_linear(A[:, keep], -r_off, bounds=(-z_off[idx][keep], 1.0 - z_off[idx][keep]))
            dz[keep] = sol.x
        rl = r_off + A @ dz
        sse = float(rl @ rl)
        k = sum(fx.get(name).n_params for name in g)
        out[g] = Screened(g, z_off[idx] + dz, sse, _ic(sse, n, k)[1] - bic0)
    return out


# ----------------------------------------------------------------------------- diagnosis


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

    def table(self) -> str:
        lines = [f"{'rank':>4} {'effect':<20} {'k':>2} {'dBIC':>9} {'dAIC':>9} {'RMS fit':>10} {'RMS hold':>10} "
                 f"{'sig':>3}  parameters (+- 1 sd)"]
        for i, c in enumerate(self.ranking):
            pv = ", ".join(f"{n}.{k}={v:.4g}+-{c['stderr'].get(n, {}).get(k, float('nan')):.2g}"
                           for n, d in c["values"].items() for k, v in d.items())
            hold = f"{c['rms_holdout']:.3e}" if c["rms_holdout"] is not None else "-"
            if not c.get("fitted", True):
                pv += "  (screened out; linearized at the baseline)"
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


def _ic(sse, n, k):
    ll = n * math.log(max(sse, 1e-300) / n)
    return ll + 2 * k, ll + k * math.log(n)


def _gap(rms, sigma):
    return math.sqrt(max(rms ** 2 - sigma ** 2, 0.0))


def diagnose(fwd: Forward, traces: Sequence[Trace], candidates: Sequence[str] | None = None,
             noise: float | None = None, bic_threshold: float = 10.0, z: float = 4.0, max_iter: int = 8,
             start: Mapping | None = None, verbose: bool = False, fit_top: int = 3, pairs: bool = True) -> Diagnosis:
    """Run (a)-(c) of the module docstring. ``candidates``: effect names (default: all).

    ``fit_top``: how many candidates, best screened first, are fitted (0: every one, no
    screening); ``pairs``: also screen every pair and fit the best one when its screened
    BIC beats the best single's by ``bic_threshold``."""
    t0 = _time.time()
    fit = [tr for tr in traces if tr.role == "fit"]
    hold = [tr for tr in traces if tr.role != "fit"]
    if not fit:
        raise ValueError("diagnose: no trace with role 'fit'")
    candidates = list(candidates or fx.names())
    sigma = estimate_noise(traces) if noise is None else float(noise)
    n = int(sum(len(tr) for tr in fit))

    if verbose:
        print(f"[diagnose] baseline: simulating {len(traces)} trace(s) (the first call compiles the simulation) ...",
              flush=True)
    base_pred = dict(zip((tr.name for tr in traces), fwd.predict_many([({}, tr) for tr in traces])))
    if verbose:
        print(f"[diagnose] baseline done in {_time.time() - t0:.1f} s; {len(candidates)} candidate effect(s)",
              flush=True)
    r0 = np.concatenate([base_pred[tr.name] - tr.y for tr in fit])
    sse0 = float(r0 @ r0)
    aic0, bic0 = _ic(sse0, n, 0)
    rms_h0 = _rms(np.concatenate([base_pred[tr.name] - tr.y for tr in hold])) if hold else None
    baseline = {"sse_fit": sse0, "rms_fit": _rms(r0), "rms_holdout": rms_h0, "aic": aic0, "bic": bic0}
    chi = (sse0 / n) / sigma ** 2 if sigma > 0 else float("inf")
    chi_lim = 1.0 + z * math.sqrt(2.0 / n)
    before = breakdown(traces, [base_pred[tr.name] for tr in traces])

    results = []
    scr = None
    to_fit = [(name,) for name in candidates]
    if fit_top and len(candidates) > fit_top:
        ts = _time.time()
        s0 = fwd.n_sims
        scr = screen(fwd, candidates, fit, r0, pairs=pairs)
        singles = sorted(((name,) for name in candidates), key=lambda g: scr[g].d_bic)
        to_fit = singles[:fit_top]
        if pairs:
            best_pair = min((g for g in scr if len(g) == 2), key=lambda g: scr[g].d_bic, default=None)
            if best_pair is not None and scr[best_pair].d_bic < scr[singles[0]].d_bic - bic_threshold:
                to_fit.append(best_pair)  # fitted only if the best single leaves a gap (below)
        if verbose:
            print(f"[diagnose] screened {len(candidates)} candidate(s){' and their pairs' if pairs else ''} at the "
                  f"baseline in {_time.time() - ts:.1f} s ({fwd.n_sims - s0} simulation(s)); fitting "
                  + ", ".join("+".join(g) for g in to_fit), flush=True)
        for g in singles[fit_top:]:
            sc = scr[g]
            k = fx.get(g[0]).n_params
            aic, bic = _ic(sc.sse, n, k)
            vals = _values_of(_plist(g), sc.z, g, {})
            results.append(CandidateResult(g[0], vals, {}, k, sc.sse, math.sqrt(sc.sse / n), None, aic, bic,
                                           aic - aic0, bic - bic0, 0, 0.0, fitted=False))
    for i, g in enumerate(to_fit):
        fitted = [r for r in results if r.fitted]
        if len(g) > 1 and fitted and min(r.sse_fit for r in fitted) / n <= chi_lim * sigma ** 2:
            if verbose:
                print(f"  [{i + 1}/{len(to_fit)}] {'+'.join(g):<20} not fitted: the best single effect leaves "
                      "residuals at the noise level", flush=True)
            continue
        ts = _time.time()
        s0 = fwd.n_sims
        vals, sd, sse, _ = fit_effects(fwd, list(g), fit, start=start, max_iter=max_iter,
                                       z0=None if scr is None else scr[g].z)
        k = sum(fx.get(name).n_params for name in g)
        aic, bic = _ic(sse, n, k)
        rh = _rms(_residuals(fwd, vals, hold)) if hold else None
        c = CandidateResult("+".join(g), vals, sd, k, sse, math.sqrt(sse / n), rh, aic, bic, aic - aic0, bic - bic0,
                            fwd.n_sims - s0, _time.time() - ts)
        # a pair must also beat each of its fitted singles by the threshold (nested models)
        singles_bic = [r.bic for r in results if r.fitted and r.name in g and len(g) > 1]
        c.significant = c.d_bic < -bic_threshold and all(c.bic < b - bic_threshold for b in singles_bic)
        results.append(c)
        if verbose:
            rh_text = "-" if rh is None else f"{rh:.3e}"
            print(f"  [{i + 1}/{len(to_fit)}] {c.name:<20} dBIC={c.d_bic:9.1f} rms_fit={c.rms_fit:.3e} "
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
            g0, g1 = _gap(rms0, sigma), _gap(rms1, sigma)
            shrink[role] = {"rms_before": rms0, "rms_after": rms1, "gap_before": g0, "gap_after": g1,
                            "gap_shrinkage": 1.0 - g1 / g0 if g0 > 0 else None}
        shrink["features"] = {}
        for f, d0 in before["features"].items():
            g0, g1 = d0["rms_gap"], after["features"][f]["rms_gap"]
            shrink["features"][f] = {"gap_before": g0, "gap_after": g1, "shrinkage": 1.0 - g1 / g0 if g0 > 0 else None}
    return Diagnosis(verdict, best.name if best else None, sigma, chi, chi_lim, baseline,
                     [c.as_dict() for c in results], before, after, shrink, n, _time.time() - t0, preds)


# ----------------------------------------------------------------------------- experiment files


def forward_from_experiment(exp) -> tuple[Forward, list[Trace]]:
    """Forward model and traces (the experiment's, with their response channel) of a
    block-scenario Experiment. Response channel: ``stretch`` (lateral stretch) or
    ``displacement`` ((stretch - 1) L, m)."""
    from dejax import scenarios as sc
    from dejax.material import Material

    if exp.scenario != "block":
        raise NotImplementedError(f"diagnose supports the 'block' scenario for now, not '{exp.scenario}'")
    g = exp.geometry
    L = float(g.get("L", g.get("lx", 1e-3)))
    mat = fx.augment_material(Material(**exp.material_kwargs()))
    traces = []
    channel = None
    for tr in exp.traces:
        ch = "stretch" if "stretch" in tr.channels else "displacement" if "displacement" in tr.channels else None
        if ch is None:
            raise ValueError(f"trace '{tr.name}': needs a 'stretch' or 'displacement' channel for the block")
        if channel not in (None, ch):
            raise ValueError("all traces must carry the same response channel")
        channel = ch
        if tr.voltage_history is None:
            raise ValueError(f"trace '{tr.name}': no voltage column and no loading table")
        traces.append(dataclasses.replace(tr, response=ch))
    pad = max(len(t) for t in traces) - 1
    prob = sc.block(L=L, shape=tuple(g.get("mesh", (1, 1, 1))), material=mat,
                    gauss_order=int(exp.solver.get("gauss_order", 3)), damping=float(exp.solver.get("damping", 0.0)),
                    voltage=traces[0].voltage_history)
    transform = None if channel == "stretch" else (lambda y, L=L: (y - 1.0) * L)
    fwd = Forward(prob, "lateral_stretch", rho_inf=exp.solver.get("rho_inf"), pad_to=pad, transform=transform)
    return fwd, traces


# ----------------------------------------------------------------------------- synthetic studies


def block_forward(material=None, L: float = 1e-3, pad_to: int | None = None) -> Forward:
    """Forward model of the 1-element DE block (paper Sec. 4 material by default) with two
    dormant viscous units, output lateral_stretch."""
    from dejax import scenarios as sc

    mat = fx.augment_material(sc.block_material() if material is None else material)
    prob = sc.block(L=L, material=mat, voltage=loads.Sine(12e3, 1.0))
    return Forward(prob, "lateral_stretch", pad_to=pad_to)


def synthetic_traces(fwd: Forward, conditions, truth: Mapping, noise: float, seed: int = 0,
                     n_cycles: float = 3.0, samples_per_cycle: int = 40, channel: str = "stretch") -> list[Trace]:
    """Traces of the block made with the effects ``truth`` ({name: values}) plus white noise,
    their response ``channel`` (the forward's output), under a sine loading.
    conditions: sequence of (name, role, phi_max V, freq Hz)."""
    rng = np.random.default_rng(seed)
    out = []
    for name, role, phi, f in conditions:
        n = int(round(n_cycles * samples_per_cycle))
        t = np.linspace(0.0, n_cycles / f, n + 1)
        tr = Trace(t, {channel: np.zeros_like(t)}, role, {"phi_max": phi, "freq": f}, name=name,
                   loading={"kind": "sine", "phi_max": phi, "freq": f}, response=channel)
        y = fwd.predict(truth, tr)
        out.append(dataclasses.replace(tr, channels={channel: y + noise * rng.standard_normal(y.shape)}))
    return out
