"""The pre-twisted torsional strip of paper Sec. 5 under a phibar ramp."""
from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .. import constraints as cs
from .. import integrate as it
from .. import loads
from .. import model as mdl
from .. import parameters
from ..material import Material
from ..mesh import twisted_strip_mesh
from .materials import torsional_material
from .problem import Problem, mesh_shape, node_ids


class _TwistOutputs(eqx.Module):
    """twist_angle: least-squares rotation (rad) about x of the x = L face's nodes relative to
    their reference positions (positive counter-clockwise seen from +x); voltage."""

    nodes: tuple = eqx.field(static=True, converter=node_ids)

    def __call__(self, model, loading, state):
        idx = 12 * jnp.asarray(self.nodes)
        Y = jnp.stack([model.q0[idx + 1], model.q0[idx + 2]], axis=1)
        y = jnp.stack([state.q[idx + 1], state.q[idx + 2]], axis=1)
        Y = Y - Y.mean(0)
        y = y - y.mean(0)
        angle = jnp.arctan2(jnp.sum(Y[:, 0] * y[:, 1] - Y[:, 1] * y[:, 0]), jnp.sum(Y[:, 0] * y[:, 0] + Y[:, 1] * y[:, 1]))
        return {"twist_angle": angle, "voltage": loading.phi(state.t)[0],
                "x_end": jnp.mean(state.q[idx] - model.q0[idx])}


def torsional(
    phibar_max: float = 0.5,
    t_ramp: float = 1.0,
    viscous: bool = False,
    material: Material | None = None,
    thickness: float = 1e-3,
    length_ratio: float = 60.0,
    width_ratio: float = 10.0,
    turns: float = 1.0,
    shape=(48, 8, 2),
    gauss_order: int = 3,
    damping: float = 0.0,
    volumetric: str = "mixed",
) -> Problem:
    """Torsional DEA of paper Sec. 5: pre-twisted strip (length 60 h, width 10 h, one turn).

    Voltage phi = phibar h sqrt(mu_inf/eps) on the top surface, 0 on the bottom, phibar
    ramped linearly from 0 to ``phibar_max`` over ``t_ramp`` (s). The x = 0 face stays
    planar (u1 = 0) and does not rotate (its mid-thickness line keeps u3 = 0, its centre
    u2 = 0); the x = L face stays planar (common axial position, no tilt) and is free to
    translate and rotate. Outputs: twist_angle (rad) of the x = L face, voltage, x_end.
    """
    n = tuple(int(s) for s in shape)
    if n[1] % 2 or n[2] % 2:
        raise ValueError(f"torsional: width and thickness element counts must be even (centre node needed), got {shape}")
    material = torsional_material(viscous) if material is None else material
    mesh = twisted_strip_mesh(length_ratio * thickness, width_ratio * thickness, thickness, turns, shape=n)
    X = np.asarray(mesh.X)
    x0 = mesh.nodes("x0")
    x1 = mesh.nodes("x1")
    mid = x0[np.abs(X[x0, 2]) < 1e-9 * thickness]
    centre = mid[np.abs(X[mid, 1]) < 1e-9 * thickness]
    c = cs.Constraints(mesh.n_dofs)
    c = c.fix(cs.face_dofs(x0, 0, [0]))
    c = c.fix(np.concatenate([cs.dof_index(mid, 0, 2), cs.dof_index(mid, 2, 2)]))  # mid-line: z and dz/dY
    c = c.fix(cs.dof_index(centre, 0, 1))
    c = c.fix(np.concatenate([cs.dof_index(x1, 2, 0), cs.dof_index(x1, 3, 0)]))  # x = L face: no tilt
    c = c.tie(cs.dof_index(x1, 0, 0))  # x = L face: common axial position
    m = mdl.build_model(mesh, material, c, gauss_order=gauss_order, damping=damping, volumetric=volumetric)
    scale = thickness * jnp.sqrt(material.mu_inf / material.eps)
    history = loads.Scaled(loads.PiecewiseLinear([0.0, t_ramp], [0.0, phibar_max]), scale)
    params = dict(scenario="torsional", phibar_max=phibar_max, t_ramp=t_ramp, thickness=thickness,
                  length=length_ratio * thickness, width=width_ratio * thickness, turns=turns, mesh=list(n),
                  gauss_order=gauss_order, damping=damping, volumetric=volumetric, **parameters.fields(material))
    return Problem("torsional", m, it.Loading(voltages=(history,)), _TwistOutputs(x1), params,
                   {"mesh": mesh, "phibar_scale": scale})


def mesh_from_params(params):
    """The reference mesh of a strip from its ``Problem.params`` (a results file's attributes)."""
    return twisted_strip_mesh(float(params["length"]), float(params["width"]), float(params["thickness"]),
                              float(params.get("turns", 1.0)), shape=mesh_shape(params))
