"""ANCF 8-node solid element (paper Sec. 2.1, Appendix 1; Chrono's ANCF 3843).

Conventions
-----------
* Parametric coordinates ``xi = (xi, eta, zeta)`` in [-1, 1]^3. Node order A..H:
  A(-1,-1,-1) B(+1,-1,-1) C(+1,+1,-1) D(-1,+1,-1) E(-1,-1,+1) F(+1,-1,+1)
  G(+1,+1,+1) H(-1,+1,+1) (bottom face counter-clockwise seen from +z, then top).
* Each node carries 12 global coordinates: position ``r`` and the Cartesian
  gradients ``dr/dX, dr/dY, dr/dZ`` (each a 3-vector). In the reference
  configuration they are the nodal position ``X`` and the identity. The index of
  component ``c`` of slot ``k`` (0 = r, 1..3 = gradients) of node ``n`` is
  ``12 n + 3 k + c``; "slot" ``4 n + k`` numbers the 4 vectors per node.
* An element maps its parametric cube onto the reference body; ``dXdxi[i]``
  (3 x 3, ``[m, k] = dX_m/dxi_k``) is that map's derivative at its node ``i``.
  The shape functions interpolate the *parametric* gradients ``dr/dxi_k =
  (dr/dX) dXdxi[:, k]``, so curved and distorted elements keep Cartesian nodal
  coordinates that neighbouring elements share.

The 32 shape functions (paper Eq. 43 with the misprint of the gradient functions
corrected, see docs/paper-notes.md) for node i with corner (xi_i, eta_i, zeta_i) and
P_i = (1 + xi_i xi)(1 + eta_i eta)(1 + zeta_i zeta) are, with edge lengths
a = b = c = 2 in parametric units,

    s_i1 = P_i (2 + xi_i xi + eta_i eta + zeta_i zeta - xi^2 - eta^2 - zeta^2) / 16
    s_i2 = a/32 xi_i (xi^2 - 1) P_i,  s_i3 = b/32 eta_i (eta^2 - 1) P_i,
    s_i4 = c/32 zeta_i (zeta^2 - 1) P_i.

The deformation gradient is linear in the element coordinates ``e`` (32 x 3):
``F = e^T G`` with ``G`` (32 x 3) the physical shape-function gradients, so the
internal force and tangent need the free energy only as a function of F.
"""
from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

NODE_CORNERS = np.array(
    [
        [-1, -1, -1],
        [+1, -1, -1],
        [+1, +1, -1],
        [-1, +1, -1],
        [-1, -1, +1],
        [+1, -1, +1],
        [+1, +1, +1],
        [-1, +1, +1],
    ],
    dtype=np.float64,
)
"""(8, 3) parametric corner of each node, in the order A..H."""

N_NODES = 8
N_SLOTS = 32  # 4 vectors (r, r_x, r_y, r_z) per node
N_COORDS = 96


def parametric_shape_functions(xi: jax.Array) -> jax.Array:
    """The 32 shape functions at one parametric point.

    Args:
      xi: (3,) parametric point in [-1, 1]^3.
    Returns:
      (32,) values, slot ``4 i + k``: k = 0 position, k = 1..3 the parametric
      gradient ``dr/dxi_k`` of node i (edge length 2 in parametric units).
    """
    c = jnp.asarray(NODE_CORNERS)
    x, y, z = xi[0], xi[1], xi[2]
    px = 1.0 + c[:, 0] * x
    py = 1.0 + c[:, 1] * y
    pz = 1.0 + c[:, 2] * z
    p = px * py * pz
    s1 = p * (2.0 + c[:, 0] * x + c[:, 1] * y + c[:, 2] * z - x * x - y * y - z * z) / 16.0
    # a/32 with a = 2 (parametric edge length)
    s2 = (2.0 / 32.0) * c[:, 0] * (x * x - 1.0) * p
    s3 = (2.0 / 32.0) * c[:, 1] * (y * y - 1.0) * p
    s4 = (2.0 / 32.0) * c[:, 2] * (z * z - 1.0) * p
    return jnp.stack([s1, s2, s3, s4], axis=1).reshape(N_SLOTS)


def parametric_shape_gradients(xi: jax.Array) -> jax.Array:
    """(32, 3) derivatives of the shape functions with respect to (xi, eta, zeta)."""
    return jax.jacfwd(parametric_shape_functions)(xi)


def gauss_rule(order: int) -> tuple[np.ndarray, np.ndarray]:
    """Tensor-product Gauss-Legendre rule on [-1, 1]^3.

    Args:
      order: points per direction (``order`` points integrate degree 2 order - 1
        exactly in each direction).
    Returns:
      points (order**3, 3) and weights (order**3,).
    """
    if not isinstance(order, (int, np.integer)) or order < 1:
        raise ValueError(f"gauss order must be a positive integer, got {order!r}")
    p, w = np.polynomial.legendre.leggauss(int(order))
    P = np.stack(np.meshgrid(p, p, p, indexing="ij"), axis=-1).reshape(-1, 3)
    W = np.einsum("i,j,k->ijk", w, w, w).reshape(-1)
    return P, W


def slot_transform(dXdxi: jax.Array) -> jax.Array:
    """(32, 32) matrix A with ``e_parametric = A @ e_cartesian`` for one element.

    Args:
      dXdxi: (8, 3, 3) map derivative ``[node, m, k] = dX_m / dxi_k`` at the nodes.
    """
    eye1 = jnp.ones((N_NODES, 1, 1))
    blocks = jnp.zeros((N_NODES, 4, 4))
    blocks = blocks.at[:, :1, :1].set(eye1)
    blocks = blocks.at[:, 1:, 1:].set(jnp.swapaxes(dXdxi, -1, -2))
    return jax.scipy.linalg.block_diag(*[blocks[i] for i in range(N_NODES)])


@jax.jit  # one compiled program per rule size when called eagerly (tests, verification)
def element_reference_data(
    X_e: jax.Array, dXdxi_e: jax.Array, points: np.ndarray, weights: np.ndarray
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Per-Gauss-point data of one element in its reference configuration.

    Args:
      X_e: (8, 3) reference nodal positions (m).
      dXdxi_e: (8, 3, 3) nodal map derivatives ``dX/dxi`` (m).
      points, weights: a Gauss rule from ``gauss_rule``.
    Returns:
      N: (n_gp, 32) shape functions acting on Cartesian slots,
      G: (n_gp, 32, 3) physical gradients ``dN/dX`` (1/m), so that F = e^T G,
      dV: (n_gp,) quadrature weight times reference volume Jacobian (m^3).
    """
    N, Jinv, dV = element_reference_factors(X_e, dXdxi_e, points, weights)
    return N, gradients_from_factors(jax.vmap(parametric_shape_gradients)(jnp.asarray(points)), Jinv, dXdxi_e), dV


@jax.jit
def element_reference_factors(
    X_e: jax.Array, dXdxi_e: jax.Array, points: np.ndarray, weights: np.ndarray
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """``element_reference_data`` with G left in its factors: G_g = A^T dNdxi_g Jinv_g, A
    the element's slot transform (``slot_transform``, from ``dXdxi_e``), dNdxi_g the
    parametric shape gradients at the point (the same in every element) and Jinv_g =
    (dX/dxi)^-1 at the point. A mesh's contractions then run on the shared dNdxi
    (``dejax.model``: F, element forces and stiffness).

    Returns:
      N (n_gp, 32), Jinv (n_gp, 3, 3) in 1/m, dV (n_gp,) in m^3.
    """
    A = slot_transform(dXdxi_e)
    e0 = reference_element_coordinates(X_e)  # (32, 3)
    pts = jnp.asarray(points)

    def at_point(xi):
        N = A.T @ parametric_shape_functions(xi)
        J0 = e0.T @ (A.T @ parametric_shape_gradients(xi))  # (3, 3) dX/dxi
        return N, jnp.linalg.inv(J0), jnp.linalg.det(J0)

    N, Jinv, detJ = jax.vmap(at_point)(pts)
    return N, Jinv, detJ * jnp.asarray(weights)


def parametric_slots(e: jax.Array, dXdxi: jax.Array) -> jax.Array:
    """A e: Cartesian element coordinates (..., 32, 3) to parametric ones (the gradient
    slots of node n mixed by its dXdxi (..., 8, 3, 3): dr/dxi_k = sum_m dr/dX_m dX_m/dxi_k)."""
    q = e.reshape(e.shape[:-2] + (N_NODES, 4, e.shape[-1]))
    grads = jnp.einsum("...nmk,...nmi->...nki", dXdxi, q[..., 1:, :])
    return jnp.concatenate([q[..., :1, :], grads], axis=-2).reshape(e.shape)


def gradients_from_factors(dNdxi: jax.Array, Jinv: jax.Array, dXdxi: jax.Array) -> jax.Array:
    """G = A^T dNdxi Jinv (..., n_gp, 32, 3) from its factors: dNdxi (n_gp, 32, 3), Jinv
    (..., n_gp, 3, 3), dXdxi (..., 8, 3, 3) (``element_reference_factors``)."""
    return cartesian_slots(jnp.einsum("gak,...gkj->...gaj", dNdxi, Jinv), dXdxi[..., None, :, :, :])


def cartesian_slots(f: jax.Array, dXdxi: jax.Array) -> jax.Array:
    """A^T f: slot vectors (..., 32, c) conjugate to parametric coordinates (forces, a
    matrix's rows) to those conjugate to the Cartesian ones; dXdxi (..., 8, 3, 3)."""
    q = f.reshape(f.shape[:-2] + (N_NODES, 4, f.shape[-1]))
    grads = jnp.einsum("...nmk,...nkc->...nmc", dXdxi, q[..., 1:, :])
    return jnp.concatenate([q[..., :1, :], grads], axis=-2).reshape(f.shape)


def face_load(X_e: jax.Array, dXdxi_e: jax.Array, axis: int, side: int, traction, order: int = 3) -> jax.Array:
    """(32, 3) consistent nodal load ``int_face N t^T dA`` of a uniform dead traction.

    Args:
      X_e, dXdxi_e: the element's reference nodes (8, 3) and map derivatives (8, 3, 3) (m).
      axis, side: the face xi_axis = side (side = -1 or +1).
      traction: (3,) nominal traction (force per reference area, Pa), constant.
      order: Gauss points per in-face direction.
    """
    xi, weights, tangents = face_rule(axis, side, order)
    return face_load_at(X_e, dXdxi_e, xi, weights, tangents, traction)


def face_rule(axis: int, side: int, order: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gauss rule on the face xi_axis = side: points (order^2, 3), weights (order^2,) and
    the two in-face parametric directions (2,) (int)."""
    p, w = np.polynomial.legendre.leggauss(int(order))
    a, b = [k for k in range(3) if k != axis]
    xi = np.zeros((p.size, p.size, 3))
    xi[..., axis] = side
    xi[..., a], xi[..., b] = np.meshgrid(p, p, indexing="ij")
    return xi.reshape(-1, 3), np.outer(w, w).reshape(-1), np.array([a, b])


def face_load_at(X_e: jax.Array, dXdxi_e: jax.Array, xi, weights, tangents, traction) -> jax.Array:
    """``face_load`` from a face rule (``face_rule``; arrays, so that every face shares one
    traced program): (32, 3) N."""
    A = slot_transform(dXdxi_e)
    e0 = reference_element_coordinates(X_e)
    xi = jnp.asarray(xi, dtype=float)
    N = jax.vmap(parametric_shape_functions)(xi) @ A  # (n_points, 32): A^T N_parametric per point
    J0 = jnp.einsum("ai,ba,pbk->pik", e0, A, jax.vmap(parametric_shape_gradients)(xi))  # (n_points, 3, 3) dX/dxi
    J0t = jnp.take(J0, jnp.asarray(tangents), axis=2)  # (n_points, 3, 2) the in-face directions
    dA = jnp.linalg.norm(jnp.cross(J0t[:, :, 0], J0t[:, :, 1]), axis=-1)
    return jnp.einsum("p,pa,i->ai", jnp.asarray(weights) * dA, N, jnp.asarray(traction, dtype=float))


def reference_element_coordinates(X_e: jax.Array) -> jax.Array:
    """(32, 3) reference coordinates of one element: positions and identity gradients."""
    eye = jnp.broadcast_to(jnp.eye(3), (X_e.shape[0], 3, 3))
    return jnp.concatenate([X_e[:, None, :], eye], axis=1).reshape(-1, 3)


def deformation_gradient(e: jax.Array, G: jax.Array) -> jax.Array:
    """F = e^T G (paper Eq. 36). e: (32, 3) element coordinates; G: (..., 32, 3)."""
    return jnp.einsum("ai,...aj->...ij", e, G)


def element_mass(N: jax.Array, dV: jax.Array, rho) -> jax.Array:
    """(32, 32) compact consistent mass ``int rho N N^T dV``; full mass = Mc (x) I3."""
    return rho * jnp.einsum("g,ga,gb->ab", dV, N, N)


def element_gravity(N: jax.Array, dV: jax.Array, rho, g) -> jax.Array:
    """(32, 3) generalized gravity force ``int rho N g^T dV`` (N)."""
    return rho * jnp.einsum("g,ga,i->ai", dV, N, jnp.asarray(g))


@functools.partial(jax.jit, static_argnames=("order",))
def mesh_reference_data(X: jax.Array, conn: jax.Array, dXdxi: jax.Array, order: int):
    """Vectorised ``element_reference_data`` over a mesh.

    Args:
      X: (n_nodes, 3) reference nodal positions.
      conn: (n_el, 8) node indices per element.
      dXdxi: (n_el, 8, 3, 3) nodal map derivatives per element.
      order: Gauss points per direction.
    Returns:
      N (n_el, n_gp, 32), G (n_el, n_gp, 32, 3), dV (n_el, n_gp).
    """
    points, weights = gauss_rule(order)
    return jax.vmap(lambda Xe, J: element_reference_data(Xe, J, points, weights))(X[conn], dXdxi)


def mesh_reference_factors(X: jax.Array, conn: jax.Array, dXdxi: jax.Array, order: int):
    """Vectorised ``element_reference_factors`` over a mesh (arguments as
    ``mesh_reference_data``): N (n_el, n_gp, 32), dNdxi (n_gp, 32, 3) the parametric shape
    gradients at the points (shared), Jinv (n_el, n_gp, 3, 3) in 1/m, dV (n_el, n_gp) in m^3."""
    points, weights = gauss_rule(order)
    N, Jinv, dV = jax.vmap(lambda Xe, J: element_reference_factors(Xe, J, points, weights))(X[conn], dXdxi)
    return N, jax.vmap(parametric_shape_gradients)(jnp.asarray(points)), Jinv, dV
