"""The paper's scenarios as ready-made problems: mesh + material + constraints + loading + outputs.

Each builder returns a ``Problem``; ``Problem.simulate(t_end, dt)`` runs it. All
builders are differentiable in their float arguments (geometry, material,
voltage) when called inside ``jax.jvp`` / ``jax.grad``.
"""
from __future__ import annotations

import dataclasses
from typing import Callable

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from . import constraints as cs
from . import integrate as it
from . import loads
from . import model as mdl
from . import parameters, stability
from .material import Material
from .mesh import block_mesh

# ----------------------------------------------------------------------------- materials


def block_material(**overrides) -> Material:
    """Paper Sec. 4 block: mu_inf = mu_1 = 67 kPa, K = 6.7 GPa, eta_1 = 3000 Pa s, Jm_1 = 5,
    Jm_inf = 15, rho = 1.1 g/cm^3, eps = 4e-11 F/m."""
    p = dict(mu_inf=67e3, K_inf=6.7e9, Jm_inf=15.0, eps=4e-11, rho=1100.0, mu=[67e3], K=[6.7e9], Jm=[5.0], eta=[3000.0])
    p.update(overrides)
    return Material(**p)


TABLE2 = {
    # model: (mu_inf, [mu_s], [eta_s]) in Pa and Pa s (paper Table 2)
    "hyperelastic": (72e3, [], []),
    "I": (81e3, [80e3], [400.0]),
    "II": (78e3, [30e3, 80e3], [300.0, 200.0]),
    "III": (75e3, [10e3, 40e3, 80e3], [5000.0, 300.0, 100.0]),
    "IV": (72e3, [10e3, 10e3, 80e3, 80e3], [5000.0, 2000.0, 300.0, 100.0]),
}


def rolled_material(model: str = "IV", **overrides) -> Material:
    """Paper Sec. 6 / Table 2 material: K_inf = 3 GPa, Jm_inf = 15, K_s = 7.5 GPa, Jm_s = 5,
    rho = 1.5 g/cm^3, eps = 3.4e-11 F/m; mu and eta of the named model (I..IV, or
    "hyperelastic" = Model IV's mu_inf without viscous units)."""
    if model not in TABLE2:
        raise ValueError(f"unknown material model {model!r}; choose from {sorted(TABLE2)}")
    mu_inf, mu, eta = TABLE2[model]
    n = len(mu)
    p = dict(mu_inf=mu_inf, K_inf=3e9, Jm_inf=15.0, eps=3.4e-11, rho=1500.0, mu=mu, K=[7.5e9] * n, Jm=[5.0] * n, eta=eta)
    p.update(overrides)
    return Material(**p)


# ----------------------------------------------------------------------------- problems


@dataclasses.dataclass
class Problem:
    """A ready-to-run simulation.

    name: scenario name; model: the discrete Model; loading: voltages and motions;
    output_fn: ``(model, loading, state) -> dict`` recorded every step; params: the
    scenario's parameters (written as HDF5 attributes); extras: scenario data (meshes,
    node ids) for post-processing.
    """

    name: str
    model: mdl.Model
    loading: it.Loading
    output_fn: Callable
    params: dict
    extras: dict = dataclasses.field(default_factory=dict)
    rho_inf: float = 0.8
    quasi_static: bool = False

    def scheme(self, rho_inf=None, quasi_static=None):
        """The time scheme: QuasiStatic if asked (default: the scenario's choice, True for
        material tests), else generalized-alpha with rho_inf (default the scenario's)."""
        qs = self.quasi_static if quasi_static is None else quasi_static
        return it.QuasiStatic() if qs else it.GeneralizedAlpha(self.rho_inf if rho_inf is None else rho_inf)

    def simulate(self, t_end, dt, rho_inf=None, newton=it.NewtonOptions(), solver=None, quasi_static=None,
                 control=it.StepControl()) -> it.Solution:
        """Run from rest to t_end with step dt (s); returns the Solution (not checked).
        rho_inf defaults to the scenario's (0.8, the paper's); quasi_static to the scenario's
        (True for ``uniaxial``); control: step cut-back (None = off). A Newton failure at the
        smallest step is classified (``stability.classify_failure``): an instability is
        reported as Status.INSTABILITY."""
        sol = it.simulate(self.model, self.loading, it.time_grid(t_end, dt), self.output_fn,
                          self.scheme(rho_inf, quasi_static), newton, solver, control=control)
        return stability.classify_failure(self.model, self.loading, sol, control.dt_min if control else dt)


# Output functions are equinox Modules whose fields are all static (node ids, lengths): equal
# outputs compare and hash equal, so rebuilt problems reuse the compiled stepper.


def _node_ids(ids) -> tuple:
    return tuple(int(i) for i in ids)


class _NodeMean(eqx.Module):
    """Output function: mean of one coordinate over a node set, divided by a length."""

    outputs: tuple = eqx.field(static=True)  # ((name, node ids, slot, component, length or None), ...)

    def __init__(self, outputs: dict):
        # outputs: name -> (node ids, slot, component, length or None)
        self.outputs = tuple((k, _node_ids(v[0]), *v[1:]) for k, v in outputs.items())

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


def rolled(
    model: str | Material = "IV",
    freq: float = 30.0,
    phi_max: float = 50e3,
    h: float = 2e-3,
    r: float = 2e-3,
    L: float = 8e-3,
    shape=(12, 20, 4),
    gauss_order: int = 3,
    damping: float = 0.0,
    point: str = "P",
    voltage=None,
    volumetric: str = "mixed",
) -> Problem:
    """Rolled (tubular) DEA of paper Sec. 6.

    Hollow cylinder along x in [-L, 0] (m), inner radius r, wall h; voltage across the
    wall (radial field), Eq. (42) sine with frequency ``freq`` (Hz) and peak ``phi_max``
    (V) unless ``voltage`` (t -> V) is given. Top face x = 0: u2 = u3 = 0; bottom face
    x = -L clamped. Output x_P, v_P: axial displacement (m) and velocity (m/s) of the
    node set ``point`` ("P": top face, inner edge; "P_outer": outer edge).
    ``model``: a Table 2 name ("I".."IV", "hyperelastic") or a Material.
    """
    from .mesh import rolled_tube_mesh

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


class _TwistOutputs(eqx.Module):
    """twist_angle: least-squares rotation (rad) about x of the x = L face's nodes relative to
    their reference positions (positive counter-clockwise seen from +x); voltage."""

    nodes: tuple = eqx.field(static=True, converter=_node_ids)

    def __call__(self, model, loading, state):
        idx = 12 * jnp.asarray(self.nodes)
        Y = jnp.stack([model.q0[idx + 1], model.q0[idx + 2]], axis=1)
        y = jnp.stack([state.q[idx + 1], state.q[idx + 2]], axis=1)
        Y = Y - Y.mean(0)
        y = y - y.mean(0)
        angle = jnp.arctan2(jnp.sum(Y[:, 0] * y[:, 1] - Y[:, 1] * y[:, 0]), jnp.sum(Y[:, 0] * y[:, 0] + Y[:, 1] * y[:, 1]))
        return {"twist_angle": angle, "voltage": loading.phi(state.t)[0],
                "x_end": jnp.mean(state.q[idx] - model.q0[idx])}


def torsional_material(viscous: bool = False, **overrides) -> Material:
    """Paper Sec. 5: rho = 1.5 g/cm^3, eps = 3.4e-11, mu_inf = 12 kPa, K_inf = 5 GPa, Jm_inf = 15;
    viscous case adds mu_1 = 80 kPa, K_1 = 7.5 GPa, Jm_1 = 5, eta_1 = 400 Pa s."""
    p = dict(mu_inf=12e3, K_inf=5e9, Jm_inf=15.0, eps=3.4e-11, rho=1500.0)
    if viscous:
        p.update(mu=[80e3], K=[7.5e9], Jm=[5.0], eta=[400.0])
    p.update(overrides)
    return Material(**p)


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
    from .mesh import twisted_strip_mesh

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


class _UniaxialOutputs(eqx.Module):
    """stretch (-), nominal stress P11 (Pa) = axial reaction on the moving face / (ly lz),
    voltage (V) and thickness stretch (-)."""

    face: tuple = eqx.field(static=True, converter=_node_ids)
    top: tuple = eqx.field(static=True, converter=_node_ids)
    lx: float = eqx.field(static=True, converter=float)
    area: float = eqx.field(static=True, converter=float)
    lz: float = eqx.field(static=True, converter=float)

    def __call__(self, model, loading, state):
        phi = loading.phi(state.t) if loading.voltages else jnp.zeros(model.field_dirs.shape[0])
        E = mdl.nominal_field(model, phi)
        R = (mdl.mass_apply(model, state.qdd + model.damping * state.v) + mdl.internal_force_at(model, state.q, E, state.Cv, state.p)
             - mdl.gravity_force(model))
        idx = 12 * jnp.asarray(self.face)
        top = 12 * jnp.asarray(self.top) + 2
        return {
            "stretch": jnp.mean(state.q[idx]) / self.lx,
            "stress": jnp.sum(R[idx]) / self.area,
            "voltage": phi[0] if phi.shape[0] else jnp.asarray(0.0),
            "thickness_stretch": jnp.mean(state.q[top]) / self.lz,
        }


def uniaxial(
    stretch,
    material: Material,
    voltage=None,
    lx: float = 1e-3,
    ly: float = 1e-3,
    lz: float = 1e-3,
    shape=(1, 1, 1),
    gauss_order: int = 3,
    damping: float = 0.0,
    volumetric: str = "mixed",
) -> Problem:
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


# ----------------------------------------------------------------------------- registry


@dataclasses.dataclass(frozen=True)
class Scenario:
    """A scenario of the registry: ``build(**params) -> Problem`` and, where a results file's
    parameters (``Problem.params``, HDF5 attributes) determine it, ``mesh(params) -> Mesh``."""

    name: str
    build: Callable
    mesh: Callable | None = None


def _mesh_shape(params) -> tuple:
    return tuple(int(s) for s in np.asarray(params["mesh"]).ravel())


def _block_mesh(params):
    return block_mesh(float(params["L"]), shape=_mesh_shape(params))


def _rolled_mesh(params):
    from .mesh import rolled_tube_mesh

    return rolled_tube_mesh(float(params["h"]), float(params["r"]), float(params["L"]), shape=_mesh_shape(params))


def _torsional_mesh(params):
    from .mesh import twisted_strip_mesh

    return twisted_strip_mesh(float(params["length"]), float(params["width"]), float(params["thickness"]),
                              float(params.get("turns", 1.0)), shape=_mesh_shape(params))


REGISTRY = {s.name: s for s in (Scenario("block", block, _block_mesh), Scenario("rolled", rolled, _rolled_mesh),
                                Scenario("torsional", torsional, _torsional_mesh), Scenario("uniaxial", uniaxial))}
"""Scenario name -> Scenario: the one list of scenarios (experiment files, results files, CLI)."""
NAMES = tuple(REGISTRY)
"""The scenario names, in order."""


def get(name: str) -> Scenario:
    """The registered scenario ``name``; ValueError listing the known ones otherwise."""
    if name not in REGISTRY:
        raise ValueError(f"unknown scenario {name!r}; known: {', '.join(NAMES)}")
    return REGISTRY[name]
