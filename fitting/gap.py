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
"""
from __future__ import annotations

import math
from typing import Sequence

import jax.numpy as jnp
import numpy as np

from dejax import cycles

from .traces import Trace

__all__ = ["estimate_noise", "breakdown", "rms", "gap"]


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
        return np.asarray(volt(jnp.asarray(tr.time))), tr.frequency
    span = float(tr.time[-1] - tr.time[0])
    return np.asarray(tr.channels["stretch"], dtype=float), tr.frequency or (1.0 / span if span > 0 else None)


def rms(x) -> float:
    """Root mean square of ``x`` (0 for no entries)."""
    x = np.asarray(x, dtype=float)
    return float(np.sqrt(np.mean(x ** 2))) if x.size else 0.0


def gap(rms_value: float, sigma: float) -> float:
    """The gap beyond the noise: sqrt(max(RMS^2 - sigma^2, 0))."""
    return math.sqrt(max(rms_value ** 2 - sigma ** 2, 0.0))
