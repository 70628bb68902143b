"""Stability of an equilibrium: the smallest eigenvalue of the static tangent, and the
classification of a failed run as an instability (electromechanical pull-in, snap-through)
rather than a Newton failure.

Under voltage control a DE passes a limit point (pull-in) where the static tangent
K = d Q_int / dq (pressures condensed, viscous units at the step's consistent tangent)
becomes singular: past it no nearby equilibrium exists, so Newton fails at every step
size. A run whose Newton fails at dt_min is classified as an instability when the
smallest eigenvalue of K at the last converged sub-step has fallen to
``INSTABILITY_RATIO`` of its value in the unloaded reference state, or below zero.
Eigenvalues are of D K D with D the dofs' length scales (``model.dof_scale``), so that
position and gradient coordinates weigh alike.
"""
from __future__ import annotations

import dataclasses

import jax
import numpy as np

from . import integrate as it
from . import linsolve
from . import model as mdl

INSTABILITY_RATIO = 0.02
"""lambda_min(K) / lambda_min(K at rest) at or below which a failure at dt_min is an instability."""

DENSE_LIMIT = 3000
"""Reduced unknowns up to which the eigenvalue is computed densely (scipy eigsh above)."""


@jax.jit
def _tangents(model, q, E, Cv, dt, p, wmax=None):
    return mdl.element_tangents(model, q, E, Cv, dt, p, wmax)[1]


def smallest_eigenvalue(model: mdl.Model, Ke) -> float:
    """Smallest eigenvalue of D T^T K T D for element matrices Ke (n_el, 96, 96)."""
    d = np.asarray(mdl.dof_scale(model))
    if model.structure.n_free <= DENSE_LIMIT:
        K = np.asarray(mdl.assemble_dense(model, Ke))
        K = 0.5 * (K + K.T) * d[:, None] * d[None, :]
        return float(np.linalg.eigvalsh(K)[0])
    import scipy.sparse as sp
    from scipy.sparse.linalg import eigsh

    D = sp.diags(d)
    K = D @ linsolve.assemble_scipy(model, Ke) @ D
    K = 0.5 * (K + K.T)
    shift = -1e-3 * abs(K.diagonal()).mean()  # just below zero: the eigenvalue nearest it is the smallest
    return float(eigsh(K.tocsc(), k=1, sigma=shift, which="LM", return_eigenvectors=False)[0])


def _eigenvalue_at(model: mdl.Model, q, phi, Cv, p, dt, wmax=None) -> float:
    return smallest_eigenvalue(model, _tangents(model, q, mdl.nominal_field(model, phi), Cv, dt, p, wmax))


def static_eigenvalue(model: mdl.Model, loading: it.Loading, state: it.State, dt: float) -> float:
    """Smallest eigenvalue of the dof-scaled static tangent at ``state`` (voltages of
    ``loading`` at state.t; viscous units through a backward-Euler step of ``dt`` s)."""
    phi = loading.phi(state.t) if model.field_dirs.shape[0] else np.zeros(0)
    return _eigenvalue_at(model, state.q, phi, state.Cv, state.p, dt, state.wmax)


def reference_eigenvalue(model: mdl.Model, dt: float) -> float:
    """The same at rest: reference coordinates, no voltage, Cv = I, p = 0."""
    return _eigenvalue_at(model, model.q0, np.zeros(model.field_dirs.shape[0]), mdl.initial_viscous_state(model),
                          mdl.initial_pressure(model), dt)


def classify_failure(model: mdl.Model, loading: it.Loading, sol: it.Solution, dt_min: float) -> it.Solution:
    """``sol`` with a Newton failure at dt_min reclassified as Status.INSTABILITY where the
    static tangent at the last converged sub-step has (nearly) lost positive definiteness;
    the detail names the eigenvalue ratio and the time. Other runs are returned as they are."""
    if isinstance(sol.status, jax.core.Tracer) or sol.last_converged is None or sol.ok:
        return sol  # (inside jax transformations the status is not known: nothing to classify)
    if it.Status(int(sol.status)) != it.Status.NEWTON_FAILED:
        return sol
    last = sol.last_converged
    lam = static_eigenvalue(model, loading, last, dt_min)
    lam0 = reference_eigenvalue(model, dt_min)
    ratio = lam / lam0
    t = float(last.t)
    if ratio <= INSTABILITY_RATIO:
        detail = (f"the smallest eigenvalue of the static tangent fell to {ratio:.3g} of its value at rest by "
                  f"t = {t:.6g} s, the last converged state")
        return dataclasses.replace(sol, status=np.asarray(int(it.Status.INSTABILITY)), detail=detail)
    detail = (f"the static tangent at the last converged state (t = {t:.6g} s) is still positive definite "
              f"(smallest eigenvalue {ratio:.3g} of its value at rest): not an instability")
    return dataclasses.replace(sol, detail=detail)
