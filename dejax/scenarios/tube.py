"""The rolled (tubular) DEA of paper Sec. 6 under the Eq. (42) sine voltage."""
from __future__ import annotations

import equinox as eqx

from .. import constraints as cs
from .. import integrate as it
from .. import loads
from .. import model as mdl
from .. import parameters
from ..material import Material
from ..mesh import rolled_tube_mesh
from .materials import rolled_material
from .problem import Problem, mesh_shape


class _TubeOutputs(eqx.Module):
    """x_P, v_P (axial displacement and velocity of node P), voltage and nominal field phi/h."""

    node: int = eqx.field(static=True, converter=int)
    h: float = eqx.field(static=True, converter=float)

    def __call__(self, model, loading, state):
        i = 12 * self.node
        phi = loading.phi(state.t)[0]
        return {
            "x_P": state.q[i] - model.q0[i],
            "v_P": state.v[i],
            "voltage": phi,
            "field": phi / self.h,
        }


def rolled(model: str | Material = "IV", freq: float = 30.0, phi_max: float = 50e3, h: float = 2e-3, r: float = 2e-3,
           L: float = 8e-3, shape=(12, 20, 4), gauss_order: int = 3, damping: float = 0.0, point: str = "P",
           voltage=None, volumetric: str = "mixed") -> Problem:
    """Rolled (tubular) DEA of paper Sec. 6.

    Hollow cylinder along x in [-L, 0] (m), inner radius r, wall h; voltage across the
    wall (radial field), Eq. (42) sine with frequency ``freq`` (Hz) and peak ``phi_max``
    (V) unless ``voltage`` (t -> V) is given. Top face x = 0: u2 = u3 = 0; bottom face
    x = -L clamped. Output x_P, v_P: axial displacement (m) and velocity (m/s) of the
    node set ``point`` ("P": top face, inner edge; "P_outer": outer edge).
    ``model``: a Table 2 name ("I".."IV", "hyperelastic") or a Material.
    """
    material = rolled_material(model) if isinstance(model, str) else model
    mesh = rolled_tube_mesh(h, r, L, shape=shape)
    c = cs.Constraints(mesh.n_dofs)
    c = c.fix(cs.face_dofs(mesh.nodes("top"), 0, [1, 2]))
    c = c.fix(cs.face_dofs(mesh.nodes("bottom"), 0, [0, 1, 2]))
    m = mdl.build_model(mesh, material, c, gauss_order=gauss_order, damping=damping, volumetric=volumetric)
    nodes = mesh.nodes(point)
    if len(nodes) != 1:
        raise ValueError(f"output point set {point!r} must hold one node, it holds {len(nodes)}")
    history = loads.Sine(phi_max, freq) if voltage is None else voltage
    hh = float(h) if isinstance(h, (int, float)) else 1.0
    params = dict(
        scenario="rolled", model=model if isinstance(model, str) else "custom", freq=freq, phi_max=phi_max,
        h=h, r=r, L=L, mesh=list(shape), gauss_order=gauss_order, damping=damping, point=point, volumetric=volumetric,
        **parameters.fields(material),
    )
    return Problem("rolled", m, it.Loading(voltages=(history,)), _TubeOutputs(nodes[0], hh), params,
                   {"mesh": mesh, "P": int(nodes[0])})


def mesh_from_params(params):
    """The reference mesh of a tube from its ``Problem.params`` (a results file's attributes)."""
    return rolled_tube_mesh(float(params["h"]), float(params["r"]), float(params["L"]), shape=mesh_shape(params))
