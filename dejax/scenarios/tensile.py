"""The stretch-controlled uniaxial tension test of a film (a material test)."""
from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .. import constraints as cs
from .. import integrate as it
from .. import model as mdl
from .. import parameters
from ..material import Material
from ..mesh import block_mesh
from .problem import Problem, node_ids


class _UniaxialOutputs(eqx.Module):
    """stretch (-), nominal stress P11 (Pa) = axial reaction on the moving face / (ly lz),
    voltage (V) and thickness stretch (-)."""

    face: tuple = eqx.field(static=True, converter=node_ids)
    top: tuple = eqx.field(static=True, converter=node_ids)
    lx: float = eqx.field(static=True, converter=float)
    area: float = eqx.field(static=True, converter=float)
    lz: float = eqx.field(static=True, converter=float)

    def __call__(self, model, loading, state):
        phi = loading.phi(state.t) if loading.voltages else jnp.zeros(model.field_dirs.shape[0])
        E = mdl.nominal_field(model, phi)
        R = (mdl.mass_apply(model, state.qdd + model.damping * state.v)
             + mdl.internal_force_at(model, state.q, E, state.Cv, state.p, state.wmax) - mdl.external_force(model))
        idx = 12 * jnp.asarray(self.face)
        top = 12 * jnp.asarray(self.top) + 2
        return {
            "stretch": jnp.mean(state.q[idx]) / self.lx,
            "stress": jnp.sum(R[idx]) / self.area,
            "voltage": phi[0] if phi.shape[0] else jnp.asarray(0.0),
            "thickness_stretch": jnp.mean(state.q[top]) / self.lz,
        }


def uniaxial(stretch, material: Material, voltage=None, lx: float = 1e-3, ly: float = 1e-3, lz: float = 1e-3,
             shape=(1, 1, 1), gauss_order: int = 3, damping: float = 0.0, volumetric: str = "mixed") -> Problem:
    """Stretch-controlled uniaxial tension of a film (a material test).

    Block [0, lx] x [0, ly] x [0, lz] (m) with symmetry planes x = 0, y = 0, z = 0; the
    face x = lx moves rigidly (planar) so that its stretch follows ``stretch`` (t -> -);
    faces y = ly and z = lz are traction free. Optional ``voltage`` (t -> V) across the
    thickness z (electrodes on z = 0 and z = lz). Outputs: stretch, nominal stress
    P11 (Pa, axial reaction force over the reference cross-section ly lz), voltage,
    thickness_stretch.
    """
    mesh = block_mesh(lx, ly, lz, shape=shape)
    c = cs.Constraints(mesh.n_dofs)
    for face, axis in (("x0", 0), ("y0", 1), ("z0", 2)):
        c = c.fix(cs.face_dofs(mesh.nodes(face), axis, [axis]))
    x1 = mesh.nodes("x1")
    c = c.fix(np.concatenate([cs.dof_index(x1, 2, 0), cs.dof_index(x1, 3, 0)]))  # face stays normal to x
    c = c.prescribe(cs.dof_index(x1, 0, 0), lx)  # x = lx + u(t) lx with u = stretch - 1
    model = mdl.build_model(mesh, material, c, gauss_order=gauss_order, damping=damping, volumetric=volumetric)
    loading = it.Loading(voltages=(voltage,) if voltage is not None else (), motions=(_MinusOne(stretch),))
    params = dict(scenario="uniaxial", lx=lx, ly=ly, lz=lz, mesh=list(shape), gauss_order=gauss_order,
                  damping=damping, volumetric=volumetric, **parameters.fields(material))
    return Problem("uniaxial", model, loading, _UniaxialOutputs(x1, mesh.nodes("z1"), lx, ly * lz, lz), params,
                   {"mesh": mesh}, rho_inf=0.0, quasi_static=True)


class _MinusOne(eqx.Module):
    """u(t) = stretch(t) - 1."""

    stretch: eqx.Module

    def __call__(self, t):
        return self.stretch(t) - 1.0
