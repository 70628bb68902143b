"""Helpers shared by several test modules (imported as ``helpers``, like ``svk``)."""
import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

from dejax import integrate as it
from dejax import model as mdl
from dejax import scenarios
from fitting import effects as fx
from fitting import forward as fw
from fitting.schema import DataError


# a hand-made trace file: a comment line, units in the header, a comment between data rows
CSV = """\
# hand-made trace: time in ms, displacement in mm, voltage in kV
t_ms,disp_mm,U_kV,note
0,0.0,0.0,start
1,0.5,1.5,
2,1.0,3.0,x
# a comment between data rows
3,1.5,4.5,
"""


def raises(match_parts, fn, *args, **kw):
    """Call fn, expect DataError whose message contains every part."""
    with pytest.raises(DataError) as info:
        fn(*args, **kw)
    msg = str(info.value)
    for part in match_parts:
        assert part in msg, f"{part!r} not in message: {msg}"
    return info.value


def rest_state(m):
    """The reference state at rest (what integrate.initial_state gives without load)."""
    z = jnp.zeros_like(m.q0)
    return it.State(t=jnp.asarray(0.0), q=m.q0, v=z, qdd=z, a=z, Cv=mdl.initial_viscous_state(m))


class AnalyticForward(fw.Forward):
    """A diagnosis forward model in closed form (no simulation): the quasi-static response
    y = 1 + k u_e(t)^2 / ((1 + rel) f), u_e the command lagged by ``voltage_lag`` (tau), rel
    the ``electrode_stiffness`` and f the baseline's refit factor on mu_inf (``refit:mu_inf``);
    the sensor effects as in ``fitting.forward.Forward``."""

    def __init__(self, k=0.02 / 14e3 ** 2):
        self.pieces0 = fx.Pieces(None, None, fx.Sensor(), {})
        self.k = k
        self._cache = {}
        self.n_sims = 0
        self.transform = None

    def _launch(self, effects, trace):
        tau = effects.get("voltage_lag", {}).get("tau", 0.0)
        rel = effects.get("electrode_stiffness", {}).get("rel", 0.0)
        f = effects.get("refit:mu_inf", {}).get("factor", 1.0)
        u = np.asarray(fx.lowpass(trace.voltage_history, tau, jnp.asarray(trace.time)))
        self.n_sims += 1
        return 1.0 + self.k * u ** 2 / ((1.0 + rel) * f)

    def _finish(self, effects, trace, launched):
        return launched


ANALYTIC_CONDITIONS = [("f1", "fit", 14e3, 2.0), ("f2", "fit", 10e3, 5.0), ("h", "holdout", 12e3, 3.0)]
"""(name, role, phi_max V, freq Hz) of the analytic diagnosis tests' traces."""
ANALYTIC_SIGMA = 1e-4  # their noise


def analytic_traces(truth, seed=0):
    """Three traces (2 fit, 1 holdout; 3 cycles of 40 samples) of ``AnalyticForward`` with
    the effects ``truth`` plus white noise ``ANALYTIC_SIGMA``."""
    return fw.synthetic_traces(AnalyticForward(), ANALYTIC_CONDITIONS, truth, ANALYTIC_SIGMA, seed=seed, n_cycles=3,
                               samples_per_cycle=40)


_element_tangents = eqx.filter_jit(mdl.element_tangents)  # one compiled program per mesh


def tube_system(shape=(4, 4, 1)):
    """(model, element iteration matrices) of a small rolled tube (Model IV) at rest: tangent
    plus a mass term, symmetric positive definite."""
    m = scenarios.rolled("IV", 30.0, 50e3, shape=shape).model
    E = mdl.nominal_field(m, jnp.zeros(m.field_dirs.shape[0]))
    _, Ke, _ = _element_tangents(m, m.q0, E, mdl.initial_viscous_state(m), 1e-3)
    return m, Ke + 1e3 * mdl.mass_elements(m)
