"""Meshes of ANCF solid elements: reference geometry, electrodes and node sets.

A ``Mesh`` holds everything the model needs to know about a body's reference
configuration (see ``dejax.element`` for the coordinate conventions):

* ``X`` (n_nodes, 3): reference nodal positions (m). The reference nodal
  gradient coordinates ``dr/dX`` are the identity at every node.
* ``dXdxi`` (n_el, 8, 3, 3): for each element and each of its nodes, the
  derivative ``dX/dxi`` of the element's map from its parametric cube (m). For
  a mesh built from a smooth map ``X(u, v, w)`` with element extents
  ``(du, dv, dw)`` this is ``dX/du * du/2`` etc., exact.
* ``potential`` (n_channels, n_nodes, 4): for each electrode channel the unit
  electric potential field (value at 1 V on that channel, 0 V elsewhere) with
  its Cartesian gradient at each node: ``[phi, dphi/dX, dphi/dY, dphi/dZ]``.
  The nominal field is ``E = -sum_c V_c(t) Grad phi_c``.
* ``conn`` (n_el, 8) and ``node_sets`` (name -> node indices): static integers.

Array fields are JAX arrays and may depend on geometric parameters (h, L, r)
under ``jax.jvp``; integer topology is static (``Static``) so that jit caches
one compiled program per topology.
"""
from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .element import NODE_CORNERS


class Static:
    """Hashable-by-identity holder for static (numpy) data inside pytrees."""

    __slots__ = ("value",)

    def __init__(self, value: Any):
        self.value = value

    def __hash__(self):
        return id(self.value)

    def __eq__(self, other):
        return isinstance(other, Static) and other.value is self.value

    def __repr__(self):
        return f"Static({type(self.value).__name__})"


class Mesh(eqx.Module):
    """Reference configuration of an ANCF solid mesh (see module docstring)."""

    X: jax.Array
    dXdxi: jax.Array
    potential: jax.Array
    _conn: Static = eqx.field(static=True)
    _node_sets: Static = eqx.field(static=True)

    def __init__(self, X, dXdxi, conn, potential=None, node_sets=None):
        conn = np.asarray(conn, dtype=np.int64)
        X = jnp.asarray(X, dtype=float)
        if conn.ndim != 2 or conn.shape[1] != 8:
            raise ValueError(f"Mesh: connectivity must have shape (n_el, 8), got {conn.shape}")
        if X.ndim != 2 or X.shape[1] != 3:
            raise ValueError(f"Mesh: X must have shape (n_nodes, 3), got {X.shape}")
        if conn.min() < 0 or conn.max() >= X.shape[0]:
            raise ValueError(f"Mesh: connectivity refers to node {conn.max()} but there are {X.shape[0]} nodes")
        dXdxi = jnp.asarray(dXdxi, dtype=float)
        if dXdxi.shape != (conn.shape[0], 8, 3, 3):
            raise ValueError(f"Mesh: dXdxi must have shape {(conn.shape[0], 8, 3, 3)}, got {dXdxi.shape}")
        if potential is None:
            potential = jnp.zeros((0, X.shape[0], 4))
        potential = jnp.asarray(potential, dtype=float)
        if potential.ndim == 2:
            potential = potential[None]
        if potential.shape[1:] != (X.shape[0], 4):
            raise ValueError(f"Mesh: potential must have shape (n_channels, {X.shape[0]}, 4), got {potential.shape}")
        self.X = X
        self.dXdxi = dXdxi
        self.potential = potential
        self._conn = Static(conn)
        self._node_sets = Static({k: np.asarray(v, dtype=np.int64) for k, v in (node_sets or {}).items()})

    @property
    def conn(self) -> np.ndarray:
        return self._conn.value

    @property
    def node_sets(self) -> dict[str, np.ndarray]:
        return self._node_sets.value

    @property
    def n_nodes(self) -> int:
        return int(self.X.shape[0])

    @property
    def n_elements(self) -> int:
        return int(self.conn.shape[0])

    @property
    def n_dofs(self) -> int:
        return 12 * self.n_nodes

    @property
    def n_channels(self) -> int:
        return int(self.potential.shape[0])

    def nodes(self, name: str) -> np.ndarray:
        """Node indices of a named set; KeyError lists the available names."""
        try:
            return self.node_sets[name]
        except KeyError:
            raise KeyError(f"mesh has no node set {name!r}; available: {sorted(self.node_sets)}") from None

    def reference_coordinates(self) -> jax.Array:
        """(n_dofs,) reference coordinate vector q0: positions and identity gradients."""
        eye = jnp.broadcast_to(jnp.eye(3), (self.n_nodes, 3, 3))
        return jnp.concatenate([self.X[:, None, :], eye], axis=1).reshape(-1)


def structured_mesh(node_map, shape, lengths, potential_map=None, periodic=(False, False, False), extra_sets=None):
    """Mesh of n1 x n2 x n3 elements on the box [0, l1] x [0, l2] x [0, l3] of parameters
    (u, v, w), mapped by a smooth ``node_map(u, v, w) -> X (3,)``.

    Args:
      node_map: JAX-traceable smooth map from parameters to reference positions (m).
      shape: (n1, n2, n3) elements per parameter direction.
      lengths: (l1, l2, l3) parameter extents (may be traced).
      potential_map: optional list of functions X (3,) -> unit potential (V per V).
      periodic: per direction, whether the last node layer is identified with the
        first (closed rings, e.g. a tube's circumference).
      extra_sets: optional dict of extra node sets, name -> function (i, j, k,
        n1, n2, n3) -> bool on node grid indices.
    Returns:
      Mesh with node sets "u0", "u1", "v0", "v1", "w0", "w1" (faces of the
      parameter box; absent for periodic directions) and "all".
    """
    n = tuple(int(s) for s in shape)
    if any(s < 1 for s in n):
        raise ValueError(f"mesh shape must be positive integers, got {shape}")
    lengths = tuple(jnp.asarray(l, dtype=float) for l in lengths)
    nn = tuple(n[d] + (0 if periodic[d] else 1) for d in range(3))
    grid = np.stack(np.meshgrid(*[np.arange(nn[d]) for d in range(3)], indexing="ij"), axis=-1).reshape(-1, 3)
    node_id = np.arange(len(grid)).reshape(nn)
    params = jnp.stack([grid[:, d] * (lengths[d] / n[d]) for d in range(3)], axis=1)
    X = jax.vmap(lambda p: node_map(*p))(params)

    # elements
    ei = np.stack(np.meshgrid(*[np.arange(n[d]) for d in range(3)], indexing="ij"), axis=-1).reshape(-1, 3)
    corners01 = ((NODE_CORNERS + 1) / 2).astype(np.int64)  # (8, 3) in {0, 1}
    idx = ei[:, None, :] + corners01[None, :, :]  # (n_el, 8, 3) grid index (unwrapped)
    wrapped = np.stack([idx[..., d] % nn[d] if periodic[d] else idx[..., d] for d in range(3)], axis=-1)
    conn = node_id[wrapped[..., 0], wrapped[..., 1], wrapped[..., 2]]
    # dX/dxi at each element node, from the map at unwrapped parameters (exact)
    elem_params = jnp.stack([idx[..., d] * (lengths[d] / n[d]) for d in range(3)], axis=-1)  # (n_el, 8, 3)
    half = jnp.stack([lengths[d] / n[d] / 2.0 for d in range(3)])
    jac = jax.vmap(jax.vmap(lambda p: jax.jacfwd(lambda q: node_map(*q))(p)))(elem_params)  # (n_el, 8, 3, 3)
    dXdxi = jac * half[None, None, None, :]

    potential = None
    if potential_map is not None:
        chans = []
        for pm in potential_map:
            val = jax.vmap(pm)(X)
            grad = jax.vmap(jax.grad(pm))(X)
            chans.append(jnp.concatenate([val[:, None], grad], axis=1))
        potential = jnp.stack(chans)

    sets = {"all": np.arange(len(grid))}
    for d, name in enumerate("uvw"):
        if not periodic[d]:
            sets[f"{name}0"] = node_id.take(0, axis=d).reshape(-1)
            sets[f"{name}1"] = node_id.take(nn[d] - 1, axis=d).reshape(-1)
    for name, pred in (extra_sets or {}).items():
        mask = np.array([pred(i, j, k, *n) for i, j, k in grid])
        sets[name] = np.nonzero(mask)[0]
    return Mesh(X, dXdxi, conn, potential, sets)


def block_mesh(lx, ly=None, lz=None, shape=(1, 1, 1)):
    """Rectangular block [0, lx] x [0, ly] x [0, lz] (m) with an electrode pair on
    z = 0 (ground) and z = lz (channel 0). Node sets x0, x1, y0, y1, z0, z1."""
    ly = lx if ly is None else ly
    lz = lx if lz is None else lz
    lz_ = jnp.asarray(lz, dtype=float)
    m = structured_mesh(
        lambda u, v, w: jnp.stack([u, v, w]),
        shape,
        (lx, ly, lz),
        potential_map=[lambda X: X[2] / lz_],
    )
    sets = dict(m.node_sets)
    for a, b in zip("uvw", "xyz"):
        sets[f"{b}0"] = sets.pop(f"{a}0")
        sets[f"{b}1"] = sets.pop(f"{a}1")
    return Mesh(m.X, m.dXdxi, m.conn, m.potential, sets)
