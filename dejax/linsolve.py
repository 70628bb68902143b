"""Linear solvers for the Newton iteration matrix, behind one interface.

``solver.solve(model, Ke, rhs)`` solves the assembled free-free system of the
element matrices ``Ke`` (n_el, 96, 96) for ``rhs`` (n_free,). Solvers must be
differentiable in ``Ke`` and ``rhs`` (jvp and transpose), so that the implicit
derivative of each step can reuse them.
"""
from __future__ import annotations

import dataclasses

import jax.numpy as jnp

from . import model as mdl


@dataclasses.dataclass(frozen=True)
class DenseSolver:
    """Dense LU (jnp.linalg.solve) of the assembled matrix: for small and fit-scale meshes
    (up to a few thousand free coordinates). The consistent viscous tangent need not be
    exactly symmetric, so LU rather than Cholesky."""

    def solve(self, model, Ke, rhs):
        K = mdl.assemble_dense(model, Ke)
        return jnp.linalg.solve(K, rhs)
