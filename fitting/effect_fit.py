"""Candidate effects fitted to the traces, the baseline held: ``fit_effects``.

Bounded Levenberg-Marquardt (``fitting.least_squares``) over the effects' normalized
parameters z in [0, 1] (``fitting.effects``), on the residuals of the diagnosis's forward
model (``fitting.forward``) with a forward-difference Jacobian, Broyden-updated between
its evaluations so that the one compiled ``simulate`` is reused; Gauss-Newton standard
errors s^2 (J^T J)^-1 in natural units at the optimum.
"""
from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from . import effects as fx
from .forward import Forward, fd_jacobian, residuals_at
from .least_squares import levenberg_marquardt
from .traces import Trace

__all__ = ["fit_effects"]


def fit_effects(fwd: Forward, names: Sequence[str], traces: Sequence[Trace], start: Mapping | None = None,
                max_iter: int = 8, fixed: Mapping | None = None, rtol: float = 1e-4, z0=None):
    """Bounded Levenberg-Marquardt (``fitting.least_squares``) over the parameters of the
    effects ``names``, normalised to [0, 1] in lin or log scale, with a forward-difference
    Jacobian at the start and the solution, Broyden-updated between them (so the one
    compiled ``simulate`` is reused); others in ``fixed`` held. Starts from the best of
    the off values, the effects' start values, ``z0`` (e.g. the screening's linearized
    optimum) and the effects' starts read off the traces (``Effect.starts``). At most
    ``max_iter`` evaluations besides the Jacobians'; stops when an accepted step lowers the SSE by less than
    ``rtol`` (relative). Returns (values, stderr, sse, J)."""
    fixed = dict(fixed or {})
    start = dict(start or {})
    plist = fx.param_list(names)
    resid_many = residuals_at(fwd, names, traces, fixed)

    def resid(z):
        return resid_many([z])[0]

    # starts: the off values (the baseline, cached), the effects' start values and z0 when
    # given (the screening's linearized optimum: for a parameter entering nonlinearly, such as a
    # relaxation time, it can lie in another basin); keep the best
    cands = [np.array([p.z_of(start.get(n, {}).get(p.name, getattr(p, src))) for n, p in plist])
             for src in ("off", "start")]
    if z0 is not None:
        cands.append(np.clip(np.asarray(z0, dtype=float), 0.0, 1.0))
    # an effect may read further starts off the traces (a threshold effect, such as a slew
    # limit, has no slope where it does not act: it starts where it begins to act)
    for j, (n, p) in enumerate(plist):
        for st in fx.get(n).starts(traces):
            if p.name in st:
                z = cands[1].copy()
                z[j] = p.z_of(st[p.name])
                cands.append(z)
    best_z, best_sse = None, np.inf
    for z, r in zip(cands, resid_many(cands)):
        if r @ r < best_sse:
            best_z, best_sse = z, float(r @ r)
    res = levenberg_marquardt(resid, best_z, np.zeros(best_z.size), np.ones(best_z.size),
                              jacobian=lambda z, r: fd_jacobian(resid_many, z, r), max_evals=max_iter + 1,
                              ftol=rtol, xtol=1e-7, broyden=True)
    z, sse, J = res.x, res.cost, res.J
    # Gauss-Newton covariance s^2 (J^T J)^-1, from the SVD of the normalized J (not of J^T J,
    # whose condition number is squared), then in natural units: sd_x = |dx/dz| sd_z
    vals = fx.values_at(names, z, fixed)
    stderr = {}
    n, k = res.r.size, z.size
    s2 = sse / max(n - k, 1)
    D = np.array([p.dx_dz(vals[nm][p.name]) for nm, p in plist])
    try:
        C, undetermined = covariance_factor(J, s2)
        # a parameter along a direction the data do not determine (J singular there): unbounded
        var_z = np.where(undetermined, np.inf, np.sum(C ** 2, axis=1))
        sd = np.where(C.shape[1] > 0, np.sqrt(var_z) * np.abs(D), np.nan)
    except np.linalg.LinAlgError:
        sd = np.full(k, np.nan)
    for (nm, p), s_ in zip(plist, sd):
        stderr.setdefault(nm, {})[p.name] = float(s_)
    return vals, stderr, sse, J


def covariance_factor(J: np.ndarray, s2: float) -> tuple[np.ndarray, np.ndarray]:
    """C (k, k') with C C^T = s2 (J^T J)^+, the Gauss-Newton covariance of a least-squares fit
    with Jacobian J (m, k), from the SVD of J (not of J^T J, whose condition number is
    squared), singular values below 1e-12 of the largest left out; and (k,) whether each
    parameter has a share in such an undetermined direction."""
    _, S, Vt = np.linalg.svd(J, full_matrices=False)
    keep = S > S[0] * 1e-12 if S.size and S[0] > 0 else np.zeros(S.shape, bool)
    return Vt[keep].T * (np.sqrt(s2) / S[keep]), np.sum(Vt[~keep] ** 2, axis=0) > 1e-6
