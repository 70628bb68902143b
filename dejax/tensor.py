"""3 x 3 tensor algebra of the material law, written for batching over Gauss points.

Every function takes (3, 3) arrays in any units (``jax.vmap`` them over points). ``mm3``
and ``gram3`` are elementwise products and sums, which XLA fuses into the surrounding
loop; ``det3`` and ``inv3`` go through the adjugate (entry by entry) and carry their
derivatives in closed form (``jax.custom_jvp``, see the note above ``det3``).

* ``mm3(A, B)``: A @ B;
* ``gram3(F)``: C = F^T F;
* ``adj3(A)``: the adjugate, A adj(A) = det(A) I;
* ``det3(A)``, ``inv3(A)``: determinant and inverse by the adjugate.
"""
from __future__ import annotations

import jax
import jax.numpy as jnp

__all__ = ["mm3", "gram3", "adj3", "det3", "inv3"]


def mm3(A, B):
    """A @ B for 3 x 3 matrices as elementwise products and sums: batched over Gauss points,
    XLA fuses these into the surrounding loop, where a 3 x 3 dot is a call of its own."""
    return jnp.sum(A[:, :, None] * B[None, :, :], axis=1)


def gram3(F):
    """C = F^T F (3 x 3) elementwise (see ``mm3``)."""
    return jnp.sum(F[:, :, None] * F[:, None, :], axis=0)


# The adjugate entry by entry: elementwise products that XLA fuses into the surrounding
# loop. (A gather from the flattened matrix, used before, materialized a (4, 9) array per
# matrix where XLA could not fuse it: 28 ms per step on the paper's tube's 25,920 points x 4
# units, 15 % of the step; cyclic shifts with jnp.roll materialized every shift and a
# transposed copy.)


def adj3(A):
    """Adjugate (transposed cofactor matrix) of a 3 x 3 matrix: A adj(A) = det(A) I."""
    (a, b, c), (d, e, f), (g, h, i) = A[0], A[1], A[2]
    return jnp.stack([e * i - f * h, c * h - b * i, b * f - c * e,
                      f * g - d * i, a * i - c * g, c * d - a * f,
                      d * h - e * g, b * g - a * h, a * e - b * d]).reshape(3, 3)


# det3 and inv3 carry their derivatives in closed form (d det A = tr(adj(A) dA),
# d A^-1 = -A^-1 dA A^-1): the tangents are then elementwise products, where the
# derivative of the entry-by-entry formulas would pad every entry's cotangent back into a
# 3 x 3 array of its own (a separate XLA loop per entry in reverse mode: the stress of
# Model IV at 864 points compiled to 78 loops before, 30 after).


@jax.custom_jvp
def det3(A):
    """Determinant of a 3 x 3 matrix by cofactors (vectorises far better than LAPACK on CPU)."""
    return jnp.sum(A[0] * adj3(A)[:, 0])


@det3.defjvp
def _det3_jvp(primals, tangents):
    (A,), (dA,) = primals, tangents
    adj = adj3(A)
    return jnp.sum(A[0] * adj[:, 0]), jnp.sum(adj.T * dA)


@jax.custom_jvp
def inv3(A):
    """Inverse of a 3 x 3 matrix by the adjugate."""
    return adj3(A) / det3(A)


@inv3.defjvp
def _inv3_jvp(primals, tangents):
    (A,), (dA,) = primals, tangents
    Ai = inv3(A)
    return Ai, -mm3(mm3(Ai, dA), Ai)
