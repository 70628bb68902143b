"""The paper's scenarios as ready-made problems: mesh + material + constraints + loading + outputs.

Each builder returns a ``Problem``; ``Problem.simulate(t_end, dt)`` runs it. All
builders are differentiable in their float arguments (geometry, material,
voltage) when called inside ``jax.jvp`` / ``jax.grad``.
"""
from __future__ import annotations

import dataclasses
from typing import Callable

import jax.numpy as jnp

from . import constraints as cs
from . import integrate as it
from . import loads
from . import model as mdl
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

    def simulate(self, t_end, dt, rho_inf=0.8, newton=it.NewtonOptions(), solver=None) -> it.Solution:
        """Run from rest to t_end with step dt (s); returns the Solution (not checked)."""
        return it.simulate(
            self.model,
            self.loading,
            it.time_grid(t_end, dt),
            self.output_fn,
            it.GeneralizedAlpha(rho_inf),
            newton,
            solver,
        )


class _NodeMean:
    """Output function: mean of one coordinate over a node set, divided by a length.

    A class (not a closure) so that equal outputs hash equal and reuse compiled code."""

    def __init__(self, outputs: dict):
        # outputs: name -> (node ids tuple, slot, component, scale or None)
        self.outputs = {k: (tuple(int(i) for i in v[0]), *v[1:]) for k, v in outputs.items()}

    def __hash__(self):
        return hash(tuple(sorted(self.outputs.items(), key=lambda kv: kv[0])))

    def __eq__(self, other):
        return isinstance(other, _NodeMean) and other.outputs == self.outputs

    def __call__(self, model, loading, state):
        q = state.q.reshape(-1, 4, 3)
        res = {}
        for name, (nodes, slot, comp, length) in self.outputs.items():
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
    gauss_order: int = 2,
    damping: float = 0.0,
    voltage=None,
) -> Problem:
    """DE block of paper Sec. 4: cube of side L (m) with u1 = 0 on x = 0, u2 = 0 on y = 0,
    u3 = 0 on z = 0, phi = 0 on z = 0 and the Eq. (41) ramp-and-hold to ``phi_max`` (V)
    on z = L (or any ``voltage`` history t -> V).

    Outputs: lateral_stretch (x-extent / L), thickness_stretch (z-extent / L), voltage.
    The homogeneous deformation is represented exactly by any mesh; the default
    2 x 2 x 2 Gauss rule integrates it exactly.
    """
    for name, v in (("L", L), ("t_ramp", t_ramp)):
        if isinstance(v, (int, float)) and not v > 0:
            raise ValueError(f"block: {name} must be > 0, got {v}")
    mesh = block_mesh(L, shape=shape)
    c = cs.Constraints(mesh.n_dofs)
    for face, axis in (("x0", 0), ("y0", 1), ("z0", 2)):
        c = c.fix(cs.face_dofs(mesh.nodes(face), axis, [axis]))
    material = block_material() if material is None else material
    model = mdl.build_model(mesh, material, c, gauss_order=gauss_order, damping=damping)
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
        mu_inf=material.mu_inf,
        K_inf=material.K_inf,
        Jm_inf=material.Jm_inf,
        eps=material.eps,
        rho=material.rho,
        mu=material.mu,
        K=material.K,
        Jm=material.Jm,
        eta=material.eta,
    )
    return Problem("block", model, it.Loading(voltages=(history,)), out, params, {"mesh": mesh})
