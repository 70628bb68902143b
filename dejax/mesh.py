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

Builders: ``structured_mesh`` (smooth map of a parameter box), ``block_mesh``,
``rolled_tube_mesh`` (paper Sec. 6), ``twisted_strip_mesh`` (paper Sec. 5) and
``mesh_from_meshio`` (any all-hexahedral mesh); ``face_nodes`` selects nodes on
a coordinate plane.

Array fields are JAX arrays and may depend on geometric parameters (h, L, r)
under ``jax.jvp``; integer topology is static (``Static``) so that jit caches
one compiled program per topology.
"""
from __future__ import annotations

import functools
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .element import NODE_CORNERS


def content_key(value):
    """A hashable key describing ``value`` by content: numpy arrays by shape, dtype and bytes,
    dicts, lists, tuples and dataclasses by their items; equal contents give equal keys
    (what ``Static`` compares, and what caches of per-topology data are keyed by)."""
    import dataclasses
    import hashlib

    if isinstance(value, np.ndarray):
        return ("nd", value.shape, str(value.dtype), hashlib.sha1(np.ascontiguousarray(value).tobytes()).hexdigest())
    if isinstance(value, dict):
        return ("dict", tuple(sorted((k, content_key(v)) for k, v in value.items())))
    if isinstance(value, (list, tuple)):
        return (type(value).__name__, tuple(content_key(v) for v in value))
    if dataclasses.is_dataclass(value):
        return (type(value).__name__, tuple((f.name, content_key(getattr(value, f.name))) for f in dataclasses.fields(value)))
    try:
        hash(value)
        return value
    except TypeError:
        return ("id", id(value))


class Static:
    """Hashable holder for static (numpy) data inside pytrees, compared by content, so that
    equal topologies built twice share one compiled program."""

    __slots__ = ("value", "_key")

    def __init__(self, value: Any):
        self.value = value
        self._key = content_key(value)

    def __hash__(self):
        return hash(self._key)

    def __eq__(self, other):
        return isinstance(other, Static) and other._key == self._key

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
        return reference_coordinates(self.X)


def reference_coordinates(X) -> jax.Array:
    """(12 n_nodes,) reference coordinates of the nodes X (n_nodes, 3): each node's position
    followed by identity position gradients."""
    eye = jnp.broadcast_to(jnp.eye(3), (X.shape[0], 3, 3))
    return jnp.concatenate([X[:, None, :], eye], axis=1).reshape(-1)


def structured_mesh(node_map, shape, lengths, potential_map=None, periodic=(False, False, False), extra_sets=None,
                    params=()):
    """Mesh of n1 x n2 x n3 elements on the box [0, l1] x [0, l2] x [0, l3] of parameters
    (u, v, w), mapped by a smooth ``node_map(u, v, w) -> X (3,)``.

    Args:
      node_map: JAX-traceable smooth map ``node_map(u, v, w, *params)`` from parameters to
        reference positions (m).
      shape: (n1, n2, n3) elements per parameter direction.
      lengths: (l1, l2, l3) parameter extents (may be traced).
      potential_map: optional list of functions ``(X (3,), *params)`` -> unit potential (V per V).
      periodic: per direction, whether the last node layer is identified with the
        first (closed rings, e.g. a tube's circumference).
      extra_sets: optional dict of extra node sets, name -> function (i, j, k,
        n1, n2, n3) -> bool on node grid indices.
      params: the maps' numeric parameters (may be traced). Module-level maps with their
        numbers passed here share one compiled program for every mesh of the same shape
        (a closure is compiled afresh at each call).
    Returns:
      Mesh with node sets "u0", "u1", "v0", "v1", "w0", "w1" (faces of the
      parameter box; absent for periodic directions) and "all".
    """
    n = tuple(int(s) for s in shape)
    if any(s < 1 for s in n):
        raise ValueError(f"mesh shape must be positive integers, got {shape}")
    lengths = tuple(jnp.asarray(l, dtype=float) for l in lengths)
    periodic = tuple(bool(x) for x in periodic)
    nn, grid, idx = _grid_indices(n, periodic)
    node_id = np.arange(len(grid)).reshape(nn)
    wrapped = np.stack([idx[..., d] % nn[d] if periodic[d] else idx[..., d] for d in range(3)], axis=-1)
    conn = node_id[wrapped[..., 0], wrapped[..., 1], wrapped[..., 2]]

    maps = None if potential_map is None else tuple(potential_map)
    params = tuple(jnp.asarray(x, dtype=float) for x in params)
    X, dXdxi, potential = _mapped_nodes(node_map, maps, n, periodic, lengths, params)

    sets = {"all": np.arange(len(grid))}
    for d, name in enumerate("uvw"):
        if not periodic[d]:
            sets[f"{name}0"] = node_id.take(0, axis=d).reshape(-1)
            sets[f"{name}1"] = node_id.take(nn[d] - 1, axis=d).reshape(-1)
    for name, pred in (extra_sets or {}).items():
        mask = np.array([pred(i, j, k, *n) for i, j, k in grid])
        sets[name] = np.nonzero(mask)[0]
    return Mesh(X, dXdxi, conn, potential, sets)


def _grid_indices(n, periodic):
    """The parameter grid of ``structured_mesh``: nodes per direction nn (3,), every node's
    grid index (n_nodes, 3) and every element's corner grid indices (n_el, 8, 3), unwrapped
    (a periodic direction's last layer not yet mapped onto its first)."""
    nn = tuple(n[d] + (0 if periodic[d] else 1) for d in range(3))
    grid = np.stack(np.meshgrid(*[np.arange(nn[d]) for d in range(3)], indexing="ij"), axis=-1).reshape(-1, 3)
    ei = np.stack(np.meshgrid(*[np.arange(n[d]) for d in range(3)], indexing="ij"), axis=-1).reshape(-1, 3)
    corners01 = ((NODE_CORNERS + 1) / 2).astype(np.int64)  # (8, 3) in {0, 1}
    return nn, grid, ei[:, None, :] + corners01[None, :, :]


@functools.partial(jax.jit, static_argnums=(0, 1, 2, 3))
def _mapped_nodes(node_map, potential_map, n, periodic, lengths, params):
    """(X (n_nodes, 3), dXdxi (n_el, 8, 3, 3), potential) of ``structured_mesh``: one
    compiled program (not dozens of eagerly compiled operations), cached per map and shape."""
    _, grid, idx = _grid_indices(n, periodic)
    at = jnp.stack([grid[:, d] * (lengths[d] / n[d]) for d in range(3)], axis=1)
    X = jax.vmap(lambda p: node_map(*p, *params))(at)
    # dX/dxi at each element node, from the map at unwrapped parameters (exact)
    elem_at = jnp.stack([idx[..., d] * (lengths[d] / n[d]) for d in range(3)], axis=-1)  # (n_el, 8, 3)
    half = jnp.stack([lengths[d] / n[d] / 2.0 for d in range(3)])
    jac = jax.vmap(jax.vmap(lambda p: jax.jacfwd(lambda q: node_map(*q, *params))(p)))(elem_at)  # (n_el, 8, 3, 3)
    dXdxi = jac * half[None, None, None, :]
    potential = None if potential_map is None else _potential_from_maps(
        X, [functools.partial(_with_params, pm, params) for pm in potential_map])
    return X, dXdxi, potential


def _with_params(pm, params, X):
    return pm(X, *params)


def _box_map(u, v, w, *_):
    return jnp.stack([u, v, w])


def _box_potential(X, lz):
    return X[2] / lz


def block_mesh(lx, ly=None, lz=None, shape=(1, 1, 1)):
    """Rectangular block [0, lx] x [0, ly] x [0, lz] (m) with an electrode pair on
    z = 0 (ground) and z = lz (channel 0). Node sets x0, x1, y0, y1, z0, z1."""
    ly = lx if ly is None else ly
    lz = lx if lz is None else lz
    m = structured_mesh(_box_map, shape, (lx, ly, lz), potential_map=[_box_potential], params=(lz,))
    sets = dict(m.node_sets)
    for a, b in zip("uvw", "xyz"):
        sets[f"{b}0"] = sets.pop(f"{a}0")
        sets[f"{b}1"] = sets.pop(f"{a}1")
    return Mesh(m.X, m.dXdxi, m.conn, m.potential, sets)


# ---------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------


def _potential_from_maps(X, maps):
    """(n_channels, n_nodes, 4) unit potentials and Cartesian gradients at nodes X.

    Args:
      X: (n_nodes, 3) reference positions (m).
      maps: sequence of JAX-traceable functions X (3,) -> unit potential (V/V);
        gradients (1/m) are taken with ``jax.grad``.
    Returns:
      (n_channels, n_nodes, 4) array ``[phi, dphi/dX, dphi/dY, dphi/dZ]``, or
      None for an empty sequence.
    """
    maps = list(maps)
    if not maps:
        return None
    chans = []
    for pm in maps:
        val = jax.vmap(pm)(X)
        grad = jax.vmap(jax.grad(pm))(X)
        chans.append(jnp.concatenate([val[:, None], grad], axis=1))
    return jnp.stack(chans)


def _strip_map(u, v, w, rate, width, thickness):
    th = rate * u
    s = v - 0.5 * width
    t = w - 0.5 * thickness
    c, sn = jnp.cos(th), jnp.sin(th)
    return jnp.stack([u, s * c - t * sn, s * sn + t * c])


def _strip_potential(X, rate, width, thickness):
    th = rate * X[0]
    t = -X[1] * jnp.sin(th) + X[2] * jnp.cos(th)  # inverse rotation
    return t / thickness + 0.5


def _concrete_float(x):
    """float(x) when x is a concrete number, None when it is a JAX tracer."""
    try:
        return float(x)
    except Exception:  # tracers raise ConcretizationTypeError & co.
        return None


def _check_positive(name, value, hint=""):
    v = _concrete_float(value)
    if v is not None and not v > 0.0:
        raise ValueError(f"{name} must be > 0, got {v!r}{hint}")


def face_nodes(mesh: Mesh, axis, value, tol=None) -> np.ndarray:
    """Indices of the nodes whose reference coordinate ``X[:, axis]`` equals ``value``.

    Args:
      mesh: a ``Mesh`` (its X must be concrete, i.e. not a tracer).
      axis: 0, 1, 2 or "x", "y", "z".
      value: coordinate of the face (m).
      tol: absolute tolerance (m); default 1e-9 times the bounding-box diagonal
        (at least 1e-15 m).
    Returns:
      (n,) int64 node indices, sorted. Raises ValueError when no node matches
      (a silent empty set would drop a boundary condition), quoting the
      closest coordinate found.
    """
    if isinstance(axis, str):
        if axis.lower() not in ("x", "y", "z"):
            raise ValueError(f"axis must be 0, 1, 2 or 'x', 'y', 'z', got {axis!r}")
        axis = "xyz".index(axis.lower())
    if axis not in (0, 1, 2):
        raise ValueError(f"axis must be 0, 1, 2 or 'x', 'y', 'z', got {axis!r}")
    X = np.asarray(mesh.X)
    if tol is None:
        diag = float(np.linalg.norm(X.max(axis=0) - X.min(axis=0))) if len(X) else 0.0
        tol = max(1e-9 * diag, 1e-15)
    d = np.abs(X[:, axis] - float(value))
    idx = np.nonzero(d <= tol)[0].astype(np.int64)
    if idx.size == 0:
        closest = X[int(np.argmin(d)), axis] if len(X) else None
        raise ValueError(
            f"face_nodes: no node with X[:, {axis}] = {value} within tol = {tol:g}; "
            f"closest coordinate is {closest}"
        )
    return idx


# ---------------------------------------------------------------------------
# paper geometries
# ---------------------------------------------------------------------------


def rolled_tube_mesh(h, r, L, shape=(12, 20, 4)) -> Mesh:
    """Rolled DEA (paper Sec. 6): hollow cylinder with its axis along X.

    Occupies ``x in [-L, 0]`` (top face x = 0, bottom face x = -L) and
    ``r <= rho <= r + h`` with ``rho = sqrt(y^2 + z^2)``. Built by
    ``structured_mesh`` from the smooth map of parameters (u, v, w) in
    [0, L] x [0, 2 pi) x [0, h]

        X(u, v, w) = (-u, (r + w) cos v, (r + w) sin v),

    which is right-handed (det dX/d(u, v, w) = r + w > 0), so nodal positions
    and map derivatives are exact; the circumferential direction is periodic
    (no duplicated nodes). All arrays are differentiable in h, r, L (they may be
    JAX tracers, e.g. under ``jax.jvp``).

    Args:
      h: wall thickness (m), > 0.
      r: inner radius (m), > 0. r = 0 is a degenerate map (the inner nodes
        collapse onto the axis and dX/dv = 0 there); for a nearly solid
        cylinder use a small positive value such as r = 1e-3 h.
      L: length (m), > 0.
      shape: (n_l axial, n_s circumferential, n_r radial) elements; n_s >= 3.
    Returns:
      Mesh with (n_l + 1) n_s (n_r + 1) nodes and one electrode channel: the
      unit potential ``(rho - r) / h`` (0 on the inner, 1 on the outer
      surface; gradient radial with magnitude 1/h (1/m)). Node sets: "top"
      (x = 0), "bottom" (x = -L), "inner" (rho = r), "outer" (rho = r + h),
      "P" (the top-face node on the inner edge at angle 0: (0, r, 0)),
      "P_outer" (top face, outer edge, angle 0: (0, r + h, 0)), "all", and
      structured_mesh's "u0" (= top), "u1" (= bottom), "w0" (= inner),
      "w1" (= outer).
    """
    _check_positive("r", r, " (r = 0 is a degenerate map: use a small positive value, "
                    "e.g. r = 1e-3 * h, for a nearly solid cylinder)")
    _check_positive("h", h)
    _check_positive("L", L)
    n = tuple(int(s) for s in shape)
    if len(n) != 3 or any(s < 1 for s in n):
        raise ValueError(f"shape must be 3 positive integers (n_l, n_s, n_r), got {shape}")
    if n[1] < 3:
        raise ValueError(f"rolled_tube_mesh needs at least 3 circumferential elements, got n_s = {n[1]}")
    extra = {
        "top": lambda i, j, k, n1, n2, n3: i == 0,
        "bottom": lambda i, j, k, n1, n2, n3: i == n1,
        "inner": lambda i, j, k, n1, n2, n3: k == 0,
        "outer": lambda i, j, k, n1, n2, n3: k == n3,
        "P": lambda i, j, k, n1, n2, n3: i == 0 and j == 0 and k == 0,
        "P_outer": lambda i, j, k, n1, n2, n3: i == 0 and j == 0 and k == n3,
    }
    return structured_mesh(_tube_map, n, (L, 2.0 * np.pi, h), potential_map=[_tube_potential],
                           periodic=(False, True, False), extra_sets=extra, params=(r, h))


def _tube_map(u, v, w, r, h):
    rho = r + w
    return jnp.stack([-u, rho * jnp.cos(v), rho * jnp.sin(v)])


def _tube_potential(X, r, h):
    return (jnp.sqrt(X[1] ** 2 + X[2] ** 2) - r) / h


def twisted_strip_mesh(length=60e-3, width=10e-3, thickness=1e-3, turns=1.0, shape=(48, 8, 2)) -> Mesh:
    """Torsional DEA (paper Sec. 5): pre-twisted strip along X.

    Cross-section ``width x thickness`` centred on the x axis, rotated about it
    by ``theta(x) = 2 pi turns x / length``. Map of parameters (u, v, w) in
    [0, length] x [0, width] x [0, thickness], with s = v - width/2 and
    t = w - thickness/2:

        X = (u, s cos theta - t sin theta, s sin theta + t cos theta),

    whose Jacobian determinant is exactly 1 (the twist preserves volume, so the
    volume is length * width * thickness). Differentiable in length, width,
    thickness (and turns).

    Args:
      length, width, thickness: strip dimensions (m), > 0. Defaults: the
        paper's L_t = 60 h_t, W_t = 10 h_t, h_t = 1 mm.
      turns: number of full twists over the length (1 in the paper).
      shape: (n_x, n_width, n_thickness) elements; default 48 x 8 x 2 = 768.
    Returns:
      Mesh with one electrode channel: the unit potential
      ``t(X)/thickness + 1/2`` with ``t(X) = -y sin theta(x) + z cos theta(x)``
      (0 V on the bottom surface, 1 V on the top one). Its gradient (1/m) is
      normal to the level surfaces (helicoids, e.g. the mid-surface); its
      cross-sectional (y, z) part has magnitude exactly 1/thickness and the
      full magnitude is ``sqrt(1 + (s theta')^2) / thickness`` (= 1/thickness
      on the axis), because a twisted strip is thinner, measured normal to the
      helicoid, off its axis. Node sets: "x0" (x = 0), "x1" (x = length),
      "bottom" (t = -thickness/2), "top" (t = +thickness/2), "all", and
      structured_mesh's u0/u1/v0/v1/w0/w1.
    """
    _check_positive("length", length)
    _check_positive("width", width)
    _check_positive("thickness", thickness)
    n = tuple(int(s) for s in shape)
    if len(n) != 3 or any(s < 1 for s in n):
        raise ValueError(f"shape must be 3 positive integers (n_x, n_width, n_thickness), got {shape}")
    rate = 2.0 * jnp.pi * jnp.asarray(turns, dtype=float) / jnp.asarray(length, dtype=float)  # dtheta/dx (rad/m)
    m = structured_mesh(_strip_map, n, (length, width, thickness), potential_map=[_strip_potential],
                        params=(rate, width, thickness))
    sets = dict(m.node_sets)
    sets["x0"] = sets["u0"]
    sets["x1"] = sets["u1"]
    sets["bottom"] = sets["w0"]
    sets["top"] = sets["w1"]
    return Mesh(m.X, m.dXdxi, m.conn, m.potential, sets)


# ---------------------------------------------------------------------------
# import of general hexahedral meshes
# ---------------------------------------------------------------------------

# derivative of the 8 trilinear functions (VTK / A..H order) at the 8 corners:
# _TRILINEAR_CORNER_GRAD[i, j, k] = dN_j/dxi_k at corner i.
_TRILINEAR_CORNER_GRAD = np.stack(
    [
        np.stack(
            [
                NODE_CORNERS[:, k]
                / 8.0
                * np.prod(
                    [1.0 + NODE_CORNERS[:, l] * NODE_CORNERS[i, l] for l in range(3) if l != k],
                    axis=0,
                )
                for k in range(3)
            ],
            axis=1,
        )
        for i in range(8)
    ]
)
_FLIP_ZETA = np.array([4, 5, 6, 7, 0, 1, 2, 3])  # mirror the node order in zeta


def mesh_from_meshio(mesh_or_path, potential_maps=(), node_sets=None) -> Mesh:
    """Mesh from a hexahedral meshio mesh or mesh file (any shape).

    Only 8-node "hexahedron" cells are used (VTK node order: bottom face
    0-1-2-3 counter-clockwise seen from the top face 4-5-6-7, which is the
    element order A..H); other cell blocks (e.g. boundary quads) are ignored.
    Each element's geometry is its trilinear map: ``dXdxi`` at an element node
    is that map's derivative at the corner. Cells whose trilinear Jacobian is
    negative at all 8 corners are reordered (top and bottom faces swapped);
    cells with corner Jacobians of mixed sign or zero (tangled/degenerate)
    raise ValueError. Points not used by any hexahedron are dropped (they would
    carry no stiffness) and indices renumbered.

    Args:
      mesh_or_path: a ``meshio.Mesh`` or a path to any file meshio reads
        (.vtu, .vtk, .msh, .inp, ...). Coordinates in m.
      potential_maps: sequence of JAX-traceable callables X (3,) -> unit
        potential (V per V), one per electrode channel; nodal gradients by
        ``jax.grad``.
      node_sets: optional dict name -> either an index array (numbering of
        the input points) or a callable X (n_nodes, 3) numpy -> boolean mask
        or index array (on the returned mesh's nodes). Added to (and
        overriding) the meshio ``point_sets`` of the input, plus "all".
    Returns:
      Mesh (X (n_nodes, 3), dXdxi (n_el, 8, 3, 3), potential (n_channels,
      n_nodes, 4)).
    """
    import os

    import meshio

    if isinstance(mesh_or_path, meshio.Mesh):
        mio = mesh_or_path
        source = "meshio.Mesh"
    else:
        path = os.fspath(mesh_or_path)
        source = repr(path)
        if not os.path.exists(path):
            raise FileNotFoundError(f"mesh_from_meshio: no such mesh file {path!r}")
        try:
            mio = meshio.read(path)
        except (Exception, SystemExit) as err:  # meshio raises ReadError, ValueError... or even sys.exit
            raise ValueError(f"mesh_from_meshio: could not read mesh file {path!r}: {type(err).__name__}: {err}") from err

    points = np.asarray(mio.points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"mesh_from_meshio: points of {source} must be 3-D, got shape {points.shape}")
    blocks = [np.asarray(c.data, dtype=np.int64) for c in mio.cells if c.type == "hexahedron"]
    if not blocks:
        found = sorted({c.type for c in mio.cells})
        raise ValueError(
            f"mesh_from_meshio: {source} has no 8-node 'hexahedron' cells (found cell types: {found}); "
            "ANCF solid elements need an all-hexahedral mesh"
        )
    conn = np.concatenate(blocks, axis=0)
    if conn.min() < 0 or conn.max() >= len(points):
        raise ValueError(f"mesh_from_meshio: hexahedron connectivity refers to missing points in {source}")

    # orientation: trilinear Jacobian determinant at the 8 corners of each cell
    Xe = points[conn]  # (n_el, 8, 3)
    J = np.einsum("ejm,ijk->eimk", Xe, _TRILINEAR_CORNER_GRAD)
    det = np.linalg.det(J)  # (n_el, 8)
    scale = np.max(np.abs(det), axis=1, keepdims=True)
    tiny = 1e-12 * np.where(scale > 0, scale, 1.0)
    pos = np.all(det > tiny, axis=1)
    neg = np.all(det < -tiny, axis=1)
    bad = np.nonzero(~(pos | neg))[0]
    if bad.size:
        raise ValueError(
            f"mesh_from_meshio: {bad.size} hexahedra of {source} are tangled or degenerate "
            f"(corner Jacobians of mixed sign or zero), e.g. cells {bad[:5].tolist()}; "
            "check the VTK node order (bottom face 0-3, then top face 4-7 above 0-3)"
        )
    conn = np.where(neg[:, None], conn[:, _FLIP_ZETA], conn)

    # drop unused points, renumber
    used = np.unique(conn)
    old_to_new = -np.ones(len(points), dtype=np.int64)
    old_to_new[used] = np.arange(len(used))
    conn = old_to_new[conn]
    Xn = points[used]
    dXdxi = np.einsum("ejm,ijk->eimk", Xn[conn], _TRILINEAR_CORNER_GRAD)

    def renumber(name, idx):
        idx = np.asarray(idx, dtype=np.int64).reshape(-1)
        if idx.size and (idx.min() < 0 or idx.max() >= len(points)):
            raise ValueError(f"mesh_from_meshio: node set {name!r} refers to points outside the mesh")
        new = old_to_new[idx]
        return np.unique(new[new >= 0])

    sets = {"all": np.arange(len(used))}
    for name, idx in (getattr(mio, "point_sets", None) or {}).items():
        sets[name] = renumber(name, idx)
    for name, spec in (node_sets or {}).items():
        if callable(spec):
            sel = np.asarray(spec(Xn))
            if sel.dtype == bool:
                if sel.shape != (len(Xn),):
                    raise ValueError(f"mesh_from_meshio: node set {name!r}: mask shape {sel.shape} != ({len(Xn)},)")
                sel = np.nonzero(sel)[0]
            sets[name] = np.unique(np.asarray(sel, dtype=np.int64))
        else:
            sets[name] = renumber(name, spec)

    X = jnp.asarray(Xn)
    potential = jax.jit(lambda X: _potential_from_maps(X, potential_maps))(X)
    return Mesh(X, dXdxi, conn, potential, sets)
