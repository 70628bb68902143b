"""Screening of candidate effects at the baseline (a score-type test): which effects, and
which pairs, the baseline residuals point to, before any is fitted.

One forward-difference column of the fit residuals per effect parameter, in the normalized
parameters z (``fitting.effects``; a simulation per model-effect parameter, none for a
sensor effect: ``fitting.forward.fd_jacobian``; a threshold parameter, ``Param.probe``, by
the secant from off to where it begins to act, ``Effect.starts``), then for every candidate
and every pair
the bounded linear least-squares fit of the baseline residuals on its columns: the step
``z``, the SSE the first-order model predicts and the BIC change that SSE would give
(``criteria``: Gaussian AIC and BIC of ``fitting.selection``). With baseline refits
(``extra``: ``effects.refit_names``), their columns join every candidate's least-squares fit
(the linearized joint refit), their parameters not counted in its BIC.
"""
from __future__ import annotations

import dataclasses
from typing import Mapping, Sequence

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


def inert_columns(names: Sequence[str], z: np.ndarray) -> list[int]:
    """Indices of the parameters of ``names`` (``effects.param_list``) that act on nothing at
    the normalized point z: those of an effect whose gate parameter (``Effect.gate``, e.g. a
    unit's modulus) is at its off value. Their forward-difference columns are zero (to the
    dormant unit's round-off) without a simulation."""
    values = fx.values_at(names, z)
    return [j for j, (name, p) in enumerate(fx.param_list(names))
            if (gate := fx.get(name).gate) is not None and p.name != gate
            and values[name][gate] == fx.get(name).off()[gate]]


def screen(fwd: Forward, candidates: Sequence[str], traces: Sequence[Trace], r0: np.ndarray,
           pairs: bool = True, extra: Sequence[str] = (), base: Mapping | None = None) -> dict:
    """Score-type screening at the baseline (every effect off): one forward-difference column
    per parameter (a simulation for a model effect, none for a sensor effect), then for each
    candidate and each pair of candidates the bounded linear least-squares fit of the
    baseline residuals ``r0`` on its columns and those of the effects ``extra`` (the
    baseline's refits, at their values in ``base``, {name: values}). Returns {names tuple:
    Screened}; ``Screened.z`` holds the group's parameters, then those of ``extra``."""
    from scipy.optimize import lsq_linear

    extra = [e for e in extra if e not in candidates]
    base = dict(base or {})
    names = list(candidates) + extra
    plist = fx.param_list(names)
    z_off = np.array([p.z_of(base.get(name, {}).get(p.name, p.off)) for name, p in plist])
    resid_many = residuals_at(fwd, names, traces)
    r_off = resid_many([z_off])[0]  # the baseline (its simulations cached)
    # a threshold effect (Param.probe: the amplifier's slew limit acts only below the command's
    # own rate) has no slope at off: its column is the secant from off to its middle data start
    # (else its start value); every other column the default forward difference
    def secant(name, p, z0):
        starts = [st[p.name] for st in fx.get(name).starts(traces) if p.name in st]
        return p.z_of(starts[len(starts) // 2] if starts else p.start) - z0

    probes = {j: secant(name, p, z0) for j, ((name, p), z0) in enumerate(zip(plist, z_off)) if p.probe}
    J = fd_jacobian(resid_many, z_off, r_off, overrides=probes, zero=inert_columns(names, z_off))
    n = r0.size
    sse0 = float(r0 @ r0)
    _, bic0 = criteria(sse0, n, 0)
    cols = {}
    for i, (name, _) in enumerate(plist):
        cols.setdefault(name, []).append(i)
    groups = [(c,) for c in candidates]
    if pairs:
        groups += [(a, b) for i, a in enumerate(candidates) for b in candidates[i + 1:]]

    def linear_fit(group):
        idx = [i for name in list(group) + extra for i in cols[name]]
        A = J[:, idx]
        keep = np.any(A != 0.0, axis=0)  # a parameter without effect at the baseline (tau of a unit that is off)
        dz = np.zeros(len(idx))
        if np.any(keep):
            sol = lsq_linear(A[:, keep], -r_off, bounds=(-z_off[idx][keep], 1.0 - z_off[idx][keep]))
            dz[keep] = sol.x
        rl = r_off + A @ dz
        return z_off[idx] + dz, float(rl @ rl)

    if extra:  # the reference: the baseline's refit alone, linearized
        bic0 = criteria(min(linear_fit(())[1], sse0), n, 0)[1]
    out = {}
    for g in groups:
        z, sse = linear_fit(g)
        k = sum(fx.get(name).n_params for name in g)
        out[g] = Screened(g, z, sse, criteria(sse, n, k)[1] - bic0)
    return out
