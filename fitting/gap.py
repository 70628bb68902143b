"""Where a model's gap to measured traces lies, and how large it is beyond the noise.

* ``estimate_noise(traces)``: the pooled white-noise sigma of the measured traces by 4th
  differences (sigma^2 = mean((Delta^4 y)^2) / 70, unbiased for white noise when the signal
  is smooth over 5 samples).
* ``breakdown(traces, preds)``: the residual (model - measured) per trace and condition,
  per cycle, loading vs unloading (sign of d command / dt), transient (first cycle) vs
  steady state, and per cycle feature (mean, amplitude, phase lag to the command, loop area
  in the (command, output) plane, 2nd/1st harmonic ratio). The command is the voltage, or
  for a stretch-driven (uniaxial) trace the stretch, a loading-unloading trace one cycle.
* ``rms(x)``; ``gap(rms, sigma)`` = sqrt(max(RMS^2 - sigma^2, 0)).
* ``shrinkage_spread(...)``: the uncertainty of the gaps before and after an effect is added
  and of their shrinkage, per set and per feature, from replicate noise and the fitted
  parameters' covariance.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from dejax import cycles, loads

from .traces import Trace

__all__ = ["estimate_noise", "breakdown", "rms", "gap", "shrinkage_spread"]


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
        command, freq = _command(tr)
        ids = cycles.trace_cycle_ids(tr.time, freq)
        du = np.gradient(command, tr.time)
        load = du > 0
        entry = {"name": tr.name, "role": tr.role, "conditions": dict(tr.conditions), "rms": rms(r),
                 "mean_residual": float(np.mean(r)),
                 "per_cycle_rms": [rms(r[ids == c]) for c in range(int(ids.max()) + 1)],
                 "loading_rms": rms(r[load]), "unloading_rms": rms(r[~load]),
                 "transient_rms": rms(r[ids == 0]), "steady_rms": rms(r[ids > 0]) if np.any(ids > 0) else None}
        fm = cycles.trace_cycle_measures(tr.time, y, command, freq)
        fp = cycles.trace_cycle_measures(tr.time, yp, command, freq)
        entry["features"] = {k: {"measured": fm[k].tolist(), "model": fp[k].tolist(),
                                 "gap": (fp[k] - fm[k]).tolist()} for k in fm}
        res["traces"].append(entry)
        for k in fm:
            feat_acc.setdefault(k, []).append((fp[k] - fm[k], fm[k]))
    for k, lst in feat_acc.items():
        gaps = np.concatenate([g for g, _ in lst]) if lst else np.zeros(0)
        meas = np.concatenate([m for _, m in lst]) if lst else np.zeros(0)
        scale = float(np.mean(np.abs(meas))) if meas.size else 0.0
        res["features"][k] = {"rms_gap": rms(gaps), "mean_gap": float(np.mean(gaps)) if gaps.size else 0.0,
                              "relative": rms(gaps) / scale if scale > 0 else None}
    return res


def _command(tr: Trace):
    """The command (n,) a trace is driven by and its frequency (Hz or None): the voltage;
    for a stretch-driven trace (uniaxial, no voltage) the stretch, the whole trace one cycle
    (a loading-unloading test) unless its conditions name a frequency."""
    volt = tr.voltage_history
    if volt is not None or "stretch" not in tr.channels:
        return np.asarray(loads.evaluate(volt, tr.time)), tr.frequency
    span = float(tr.time[-1] - tr.time[0])
    return np.asarray(tr.channels["stretch"], dtype=float), tr.frequency or (1.0 / span if span > 0 else None)


def rms(x) -> float:
    """Root mean square of ``x`` (0 for no entries)."""
    x = np.asarray(x, dtype=float)
    return float(np.sqrt(np.mean(x ** 2))) if x.size else 0.0


def gap(rms_value: float, sigma: float) -> float:
    """The gap beyond the noise: sqrt(max(RMS^2 - sigma^2, 0))."""
    return math.sqrt(max(rms_value ** 2 - sigma ** 2, 0.0))


def _spread(values) -> dict:
    """sd and 5-95 % range of the finite entries of ``values`` (None where there are none)."""
    v = np.asarray([x for x in values if x is not None and np.isfinite(x)], dtype=float)
    if v.size < 2:
        return {"sd": None, "lo": None, "hi": None}
    lo, hi = np.percentile(v, [5.0, 95.0])
    return {"sd": float(np.std(v, ddof=1)), "lo": float(lo), "hi": float(hi)}


def shrinkage_spread(traces: Sequence[Trace], before: Sequence[np.ndarray], after: Sequence[np.ndarray],
                     sigma: float, after_jac: Sequence[np.ndarray] | None = None, cov_sqrt: np.ndarray | None = None,
                     draws: int = 200, seed: int = 0) -> dict:
    """Uncertainty of "how far the gap shrinks" (the gaps of ``gap`` per set, and of ``breakdown``'s
    per-feature RMS gaps, before and after an effect is added, and the shrinkage 1 - after/before).

    ``draws`` replicates, each with

    * a new measurement y + e of every trace (e white, N(0, sigma^2): the noise that
      ``estimate_noise`` measured), the models held: the noise's share;
    * with ``after_jac`` ((n_i, k) per trace: d prediction / dz at the fitted point) and
      ``cov_sqrt`` ((k, k'), C = S S^T the Gauss-Newton covariance of the fitted normalized
      parameters z), the model after drawn to first order, after + J S xi (xi ~ N(0, I)): the
      fitted parameters' share. The model before is held (its own fit's uncertainty is left out).

    A replicate carries its own noise and the one in y: its gaps beyond the noise subtract
    2 sigma^2, and its spread is an upper estimate (by at most sqrt 2 where the noise dominates
    a statistic). Returns {"fit"|"holdout": {"gap_before"|"gap_after"|"shrinkage": spread},
    "features": {name: {...}}}, each spread {"sd", "lo", "hi"} (5-95 %)."""
    rng = np.random.default_rng(seed)
    commands = [_command(tr) for tr in traces]
    feat_before = [cycles.trace_cycle_measures(tr.time, b, u, f) for tr, b, (u, f) in zip(traces, before, commands)]
    roles = {"fit": [i for i, tr in enumerate(traces) if tr.role == "fit"],
             "holdout": [i for i, tr in enumerate(traces) if tr.role != "fit"]}
    roles = {k: v for k, v in roles.items() if v}
    keys = ("gap_before", "gap_after", "shrinkage")
    samples = {role: {k: [] for k in keys} for role in roles}
    feat_samples: dict = {}

    def excess(r):
        return math.sqrt(max(float(np.mean(r ** 2)) - 2.0 * sigma ** 2, 0.0))

    def shrinkage(g0, g1):
        return 1.0 - g1 / g0 if g0 > 0 else None

    for _ in range(int(draws)):
        ys = [np.asarray(tr.y, dtype=float) + rng.normal(0.0, sigma, len(tr)) for tr in traces]
        model = [np.asarray(a, dtype=float) for a in after]
        if after_jac is not None and cov_sqrt is not None and cov_sqrt.size:
            dz = cov_sqrt @ rng.standard_normal(cov_sqrt.shape[1])
            model = [a + J @ dz for a, J in zip(model, after_jac)]
        for role, idx in roles.items():
            g0 = excess(np.concatenate([before[i] - ys[i] for i in idx]))
            g1 = excess(np.concatenate([model[i] - ys[i] for i in idx]))
            for k, v in zip(keys, (g0, g1, shrinkage(g0, g1))):
                samples[role][k].append(v)
        gaps: dict = {}
        for tr, y, a, fb, (u, f) in zip(traces, ys, model, feat_before, commands):
            fm = cycles.trace_cycle_measures(tr.time, y, u, f)
            fa = cycles.trace_cycle_measures(tr.time, a, u, f)
            for k in fm:
                gaps.setdefault(k, ([], []))
                gaps[k][0].append(fb[k] - fm[k])
                gaps[k][1].append(fa[k] - fm[k])
        for k, (g_b, g_a) in gaps.items():
            g0, g1 = rms(np.concatenate(g_b)), rms(np.concatenate(g_a))
            d = feat_samples.setdefault(k, {kk: [] for kk in keys})
            for kk, v in zip(keys, (g0, g1, shrinkage(g0, g1))):
                d[kk].append(v)
    out = {role: {k: _spread(v) for k, v in d.items()} for role, d in samples.items()}
    out["features"] = {f: {k: _spread(v) for k, v in d.items()} for f, d in feat_samples.items()}
    return out
