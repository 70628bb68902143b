"""Linear solvers for the Newton iteration matrix, behind one interface.

A solver provides

* ``factor(model, Ke) -> fac``: factorize the assembled reduced matrix T^T K T of
  the element matrices ``Ke`` (n_el, 96, 96) (a pytree that can be carried
  through ``lax.scan`` and reused over Newton iterations and steps);
* ``empty(model) -> fac``: a placeholder of the same structure;
* ``solve_factored(fac, rhs)``: solve with a (possibly stale) factorization;
* ``solve(model, Ke, rhs)``: an exact, differentiable solve (jvp and transpose),
  used by the implicit derivative of each step.
"""
from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from . import model as mdl


@dataclasses.dataclass(frozen=True)
class DenseSolver:
    """Dense LU of the assembled matrix: for small and fit-scale meshes (up to a few
    thousand unknowns). The consistent viscous tangent need not be exactly symmetric,
    so LU rather than Cholesky."""

    def factor(self, model, Ke):
        return jax.scipy.linalg.lu_factor(mdl.assemble_dense(model, Ke))

    def empty(self, model):
        n = model.structure.n_free
        return jnp.eye(n), jnp.arange(n, dtype=jnp.int32)

    def solve_factored(self, fac, rhs):
        return jax.scipy.linalg.lu_solve(fac, rhs)

    def solve(self, model, Ke, rhs):
        return jnp.linalg.solve(mdl.assemble_dense(model, Ke), rhs)
