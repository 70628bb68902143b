"""The DE block of paper Sec. 4 (a cube under a ramp-and-hold voltage)."""
from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp

from .. import constraints as cs
from .. import integrate as it
from .. import loads
from .. import model as mdl
from .. import parameters
from ..material import Material
from ..mesh import block_mesh
from .materials import block_material
from .problem import Problem, mesh_shape, node_ids

# Output functions are equinox Modules whose fields are all static (node ids, lengths): equal
# outputs compare and hash equal, so rebuilt problems reuse the compiled stepper.


class _NodeMean(eqx.Module):
    """Output function: mean of one coordinate over a node set, divided by a length."""

    outputs: tuple = eqx.field(static=True)  # ((name, node ids, slot, component, length or None), ...)

    def __init__(self, outputs: dict):
        # outputs: name -> (node ids, slot, component, length or None)
        self.outputs = tuple((k, node_ids(v[0]), *v[1:]) for k, v in outputs.items())

    def __call__(self, model, loading, state):
        q = state.q.reshape(-1, 4, 3)
        res = {}
        for name, nodes, slot, comp, length in self.outputs:
            val = jnp.mean(q[jnp.asarray(nodes), slot, comp])
            res[name] = val / length if length else val
        res["voltage"] = loading.phi(state.t)[0] if loading.voltages else jnp.asarray(0.0)
        return res


def block(
    phi_max: float = 12e3,
    L: float = 1e-3,
    shape=(1, 1, 1),
    material: Material | None = None,
    t_ramp: float = 1.0,
    gauss_order: int = 3,
    damping: float = 0.0,
    voltage=None,
    volumetric: str = "mixed",
) -> Problem:
    """DE block of paper Sec. 4: cube of side L (m) with u1 = 0 on x = 0, u2 = 0 on y = 0,
    u3 = 0 on z = 0, phi = 0 on z = 0 and the Eq. (41) ramp-and-hold to ``phi_max`` (V)
    on z = L (or any ``voltage`` history t -> V).

    Outputs: lateral_stretch (x-extent / L), thickness_stretch (z-extent / L), voltage.
    The homogeneous deformation is represented exactly by any mesh. The default Gauss
    rule is 3 x 3 x 3: with 2 x 2 x 2 the ANCF element has spurious zero-energy modes.
    """
    for name, v in (("L", L), ("t_ramp", t_ramp)):
        if isinstance(v, (int, float)) and not v > 0:
            raise ValueError(f"block: {name} must be > 0, got {v}")
    mesh = block_mesh(L, shape=shape)
    c = cs.Constraints(mesh.n_dofs)
    for face, axis in (("x0", 0), ("y0", 1), ("z0", 2)):
        c = c.fix(cs.face_dofs(mesh.nodes(face), axis, [axis]))
    material = block_material() if material is None else material
    model = mdl.build_model(mesh, material, c, gauss_order=gauss_order, damping=damping, volumetric=volumetric)
    history = loads.RampHold(phi_max, t_ramp) if voltage is None else voltage
    out = _NodeMean(
        {
            "lateral_stretch": (mesh.nodes("x1"), 0, 0, float(L) if isinstance(L, (int, float)) else None),
            "thickness_stretch": (mesh.nodes("z1"), 0, 2, float(L) if isinstance(L, (int, float)) else None),
        }
    )
    params = dict(
        scenario="block",
        phi_max=phi_max,
        L=L,
        mesh=list(shape),
        t_ramp=t_ramp,
        gauss_order=gauss_order,
        damping=damping,
        volumetric=volumetric,
        **parameters.fields(material),
    )
    return Problem("block", model, it.Loading(voltages=(history,)), out, params, {"mesh": mesh})


def mesh_from_params(params):
    """The reference mesh of a block from its ``Problem.params`` (a results file's attributes)."""
    return block_mesh(float(params["L"]), shape=mesh_shape(params))
