"""Linear constraints by elimination: q = q_p(t) + T z.

T maps each reduced unknown z_j to one coordinate (free) or to a group of
coordinates that share one value (tied: e.g. the axial positions of a face
that must stay planar but may translate). Every row of T has at most one 1.

A constrained coordinate either keeps its reference value (fixed) or follows a
prescribed history ``q_i(t) = q0_i + sum_k u_k(t) d_ki`` (prescribed motion,
channel k). Symmetry planes and clamps of faces perpendicular to a coordinate
axis are such constraints: fixing displacement component c on the face X_a =
const fixes component c of the nodal position and of the two in-face gradients
dr/dX_b (b != a), which makes the whole interpolated face satisfy it exactly.
"""
from __future__ import annotations

import dataclasses

import numpy as np

POSITION = 0
"""Slot index of the nodal position (1, 2, 3 are dr/dX, dr/dY, dr/dZ)."""


def dof_index(nodes, slot, component) -> np.ndarray:
    """Global coordinate index 12 node + 3 slot + component (vectorised over nodes)."""
    return 12 * np.asarray(nodes, dtype=np.int64) + 3 * slot + component


def face_dofs(nodes, normal_axis: int, components) -> np.ndarray:
    """Coordinates that pin displacement ``components`` on a face normal to ``normal_axis``.

    Args:
      nodes: node indices lying on the face X[normal_axis] = const.
      normal_axis: 0, 1, 2 for a face normal to X, Y, Z.
      components: displacement components (0, 1, 2) to pin.
    """
    if normal_axis not in (0, 1, 2):
        raise ValueError(f"normal_axis must be 0, 1 or 2, got {normal_axis!r}")
    tangential = [1 + b for b in range(3) if b != normal_axis]
    out = []
    for c in np.atleast_1d(components):
        if c not in (0, 1, 2):
            raise ValueError(f"displacement component must be 0, 1 or 2, got {c!r}")
        for slot in [POSITION, *tangential]:
            out.append(dof_index(nodes, slot, int(c)))
    return np.unique(np.concatenate(out)) if out else np.zeros(0, np.int64)


@dataclasses.dataclass(frozen=True)
class Constraints:
    """Fixed and prescribed coordinates of a mesh with ``n_dofs`` coordinates.

    Build with ``Constraints(n_dofs).fix(...).prescribe(...)`` (each returns a new object).
    ``prescribed`` holds one (dofs, direction) pair per motion channel k.
    """

    n_dofs: int
    fixed: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0, np.int64))
    prescribed: tuple = ()
    ties: tuple = ()

    def fix(self, dofs) -> "Constraints":
        dofs = np.asarray(dofs, dtype=np.int64).reshape(-1)
        self._check(dofs)
        return dataclasses.replace(self, fixed=np.union1d(self.fixed, dofs))

    def prescribe(self, dofs, direction) -> "Constraints":
        """Add motion channel: q[dofs] = q0[dofs] + u(t) * direction."""
        dofs = np.asarray(dofs, dtype=np.int64).reshape(-1)
        self._check(dofs)
        direction = np.broadcast_to(np.asarray(direction, dtype=float), dofs.shape).copy()
        return dataclasses.replace(self, prescribed=self.prescribed + ((dofs, direction),))

    def tie(self, dofs) -> "Constraints":
        """Make the coordinates ``dofs`` share one value (they must have equal reference
        values, e.g. x-positions of nodes on a face x = const: the face stays planar)."""
        dofs = np.unique(np.asarray(dofs, dtype=np.int64).reshape(-1))
        self._check(dofs)
        if dofs.size < 2:
            return self
        return dataclasses.replace(self, ties=self.ties + (dofs,))

    def _check(self, dofs):
        if dofs.size and (dofs.min() < 0 or dofs.max() >= self.n_dofs):
            raise ValueError(f"constraint refers to coordinate {dofs.max()} outside 0..{self.n_dofs - 1}")

    @property
    def n_channels(self) -> int:
        return len(self.prescribed)

    def split(self):
        """(col, constrained, directions, representatives):

        col (n_dofs,): reduced unknown of each coordinate, -1 if constrained;
        constrained: indices with q[constrained] = q0[constrained] + u(t) @ directions;
        directions (n_channels, n_constrained); representatives (n_reduced,): one
        coordinate per reduced unknown (the first of its group).
        """
        pres = [d for d, _ in self.prescribed]
        constrained = np.union1d(self.fixed, np.concatenate(pres) if pres else np.zeros(0, np.int64))
        col = np.full(self.n_dofs, -2, dtype=np.int64)
        col[constrained] = -1
        n = 0
        for group in self.ties:
            group = group[col[group] == -2]  # constrained or already-tied members keep their role
            if group.size == 0:
                continue
            col[group] = n
            n += 1
        rest = np.nonzero(col == -2)[0]
        col[rest] = n + np.arange(rest.size)
        n += rest.size
        reps = np.zeros(n, dtype=np.int64)
        valid = np.nonzero(col >= 0)[0]
        reps[col[valid[::-1]]] = valid[::-1]  # first member wins
        pos = {int(d): i for i, d in enumerate(constrained)}
        dirs = np.zeros((self.n_channels, constrained.size))
        for k, (dofs, direction) in enumerate(self.prescribed):
            for d, v in zip(dofs, direction):
                dirs[k, pos[int(d)]] = v
        return col, constrained, dirs, reps
