"""Linear constraints by elimination: q = q_p(t) + T z with T a selection of free coordinates.

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

    def _check(self, dofs):
        if dofs.size and (dofs.min() < 0 or dofs.max() >= self.n_dofs):
            raise ValueError(f"constraint refers to coordinate {dofs.max()} outside 0..{self.n_dofs - 1}")

    @property
    def n_channels(self) -> int:
        return len(self.prescribed)

    def split(self):
        """(free, constrained, directions): index arrays and the (n_channels, n_constrained)
        direction matrix with q[constrained] = q0[constrained] + u(t) @ directions."""
        pres = [d for d, _ in self.prescribed]
        constrained = np.union1d(self.fixed, np.concatenate(pres) if pres else np.zeros(0, np.int64))
        free = np.setdiff1d(np.arange(self.n_dofs), constrained)
        pos = {int(d): i for i, d in enumerate(constrained)}
        dirs = np.zeros((self.n_channels, constrained.size))
        for k, (dofs, direction) in enumerate(self.prescribed):
            for d, v in zip(dofs, direction):
                dirs[k, pos[int(d)]] = v
        return free, constrained, dirs
