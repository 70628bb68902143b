"""fitting.screening: the score-type screening at the baseline against a case it must solve
exactly, and the information criteria it ranks by."""
import math

import numpy as np
import pytest

from fitting import effects as fx
from fitting import screening as sc
from helpers import AnalyticForward, analytic_traces  # noqa: E402  (tests/helpers.py)

CANDS = ["voltage_lag", "electrode_stiffness", "sensor_offset", "sensor_drift", "sensor_latency"]


def test_screening_is_exact_for_a_linear_effect():
    """The screening's bounded linear least squares on forward-difference columns: for the
    sensor offset (linear in its parameter) it is the exact fit, c = mean(measured - model),
    with the SSE of the residuals about their mean; every pair is screened too, and the
    offset screens best."""
    tr = analytic_traces({"sensor_offset": {"c": 1e-3}}, seed=6)
    fwd = AnalyticForward()
    fit = [t for t in tr if t.role == "fit"]
    r0 = np.concatenate([fwd.predict({}, t) - t.y for t in fit])
    scr = sc.screen(fwd, CANDS, fit, r0)
    off = scr[("sensor_offset",)]
    c_exact = -float(np.mean(r0))
    c_screen = fx.values_at(["sensor_offset"], off.z)["sensor_offset"]["c"]
    assert c_screen == pytest.approx(c_exact, rel=1e-9)
    assert off.sse == pytest.approx(float(np.sum((r0 - r0.mean()) ** 2)), rel=1e-9)
    n = r0.size
    assert off.d_bic == pytest.approx(n * math.log(off.sse / float(r0 @ r0)) + math.log(n), rel=1e-12)
    assert ("voltage_lag", "sensor_offset") in scr and len(scr) == 5 + 10  # every pair screened too
    assert min(scr, key=lambda g: scr[g].d_bic if len(g) == 1 else np.inf) == ("sensor_offset",)
    assert len(sc.screen(fwd, CANDS, fit, r0, pairs=False)) == 5


def test_criteria_are_the_gaussian_aic_and_bic():
    aic, bic = sc.criteria(20.0, 10, 2)
    assert aic == pytest.approx(10 * math.log(2.0) + 4, rel=1e-14)
    assert bic == pytest.approx(10 * math.log(2.0) + 2 * math.log(10), rel=1e-14)
    aic0, bic0 = sc.criteria(0.0, 10, 0)  # a perfect fit: floored, finite
    assert aic0 == bic0 == pytest.approx(10 * math.log(1e-301), rel=1e-14)


def test_gated_parameters_act_on_nothing_at_off_and_are_not_simulated():
    """At the baseline (every effect off) the relaxation time of a unit of zero modulus, the
    charging time of a leak of zero fraction and the energy scale of a softening of zero
    depth act on nothing: their columns are zero without a simulation; once the gate is on,
    they count again."""
    from fitting.forward import fd_jacobian

    names = ["creep", "voltage_lag", "leakage", "mullins"]
    plist = fx.param_list(names)
    z_off = np.array([p.z_of(p.off) for _, p in plist])
    inert = sc.inert_columns(names, z_off)
    assert [f"{plist[j][0]}.{plist[j][1].name}" for j in inert] == ["creep.tau", "leakage.tau", "mullins.m"]
    z_on = z_off.copy()
    z_on[0] = 0.1  # creep.mu on
    assert [f"{plist[j][0]}.{plist[j][1].name}" for j in sc.inert_columns(names, z_on)] == ["leakage.tau", "mullins.m"]

    asked = []

    def resid_many(points):
        asked.extend(points)
        return [np.array([p.sum(), 2 * p.sum()]) for p in points]

    J = fd_jacobian(resid_many, z_off, resid_many([z_off])[0], zero=inert)
    assert len(asked) == 1 + len(plist) - len(inert)
    assert np.all(J[:, inert] == 0.0)
    np.testing.assert_allclose(np.delete(J, inert, axis=1), [[1.0], [2.0]] * np.ones((1, len(plist) - len(inert))),
                               rtol=1e-9)
