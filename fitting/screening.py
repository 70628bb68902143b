"""Screening of candidate effects at the baseline (a score-type test): which effects, and
which pairs, the baseline residuals point to, before any is fitted.

One forward-difference column of the fit residuals per effect parameter, in the normalized
parameters z (``fitting.effects``; a simulation per model-effect parameter, none for a
sensor effect: ``fitting.forward.fd_jacobian``; a threshold parameter, ``Param.probe``, by
the secant from off to where it begins to act, ``Effect.starts``), then for every candidate
and every pair
the bounded linear least-squares fit of the baseline residuals on its columns: the step
``z``, the SSE the first-order model predicts and the BIC change that SSE would give
(``criteria``: Gaussian AIC and BIC of ``fitting.selection``).
"""
from __future__ import annotations

import dataclasses
from typing import Sequence

import numpy as np

from . import effects as fx
from .forward import Forward, fd_jacobian, residuals_at
from .selection import information_criteria
from .traces import Trace

__all__ = ["Screened", "screen", "criteria"]


def criteria(sse: float, n: int, k: int) -> tuple[float, float]:
    """(AIC, BIC) of a least-squares fit of ``k`` parameters to ``n`` points with residual
    sum of squares ``sse`` (``selection.information_criteria``, ``sse`` floored at 1e-300)."""
    ic = information_criteria(max(sse, 1e-300), n, k)
    return ic["aic"], ic["bic"]


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

    plist = fx.param_list(candidates)
    z_off = np.array([p.z_of(p.off) for _, p in plist])
    resid_many = residuals_at(fwd, candidates, traces)
    r_off = resid_many([z_off])[0]  # the baseline (its simulations cached)
    # a threshold effect (Param.probe: the amplifier's slew limit acts only below the command's
    # own rate) has no slope at off: its column is the secant from off to its middle data start
    # (else its start value); every other column the default forward difference
    def secant(name, p, z0):
        starts = [st[p.name] for st in fx.get(name).starts(traces) if p.name in st]
        return p.z_of(starts[len(starts) // 2] if starts else p.start) - z0

    probes = {j: secant(name, p, z0) for j, ((name, p), z0) in enumerate(zip(plist, z_off)) if p.probe}
    J = fd_jacobian(resid_many, z_off, r_off, overrides=probes)
    n = r0.size
    sse0 = float(r0 @ r0)
    _, bic0 = criteria(sse0, n, 0)
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
        out[g] = Screened(g, z_off[idx] + dz, sse, criteria(sse, n, k)[1] - bic0)
    return out
