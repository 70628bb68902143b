"""``Problem``: a ready-to-run simulation (model, loading, outputs, parameters), and helpers
the scenario modules share."""
from __future__ import annotations

import dataclasses
from typing import Callable

import numpy as np

from .. import integrate as it
from .. import model as mdl
from .. import stability


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

    def scheme(self, rho_inf=None, quasi_static=None, flow_update="bdf2"):
        """The time scheme: QuasiStatic if asked (default: the scenario's choice, True for
        material tests), else generalized-alpha with rho_inf (default the scenario's);
        flow_update: the viscous update, "bdf2" or "backward-euler" (the paper's Eq. 39)."""
        qs = self.quasi_static if quasi_static is None else quasi_static
        if qs:
            return it.QuasiStatic(flow_update=flow_update)
        return it.GeneralizedAlpha(self.rho_inf if rho_inf is None else rho_inf, flow_update=flow_update)

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


def node_ids(ids) -> tuple:
    """Node ids as a tuple of ints: a static field of an output function."""
    return tuple(int(i) for i in ids)


def mesh_shape(params) -> tuple:
    """The element grid of ``Problem.params["mesh"]`` as a tuple."""
    return tuple(int(s) for s in np.asarray(params["mesh"]).ravel())


