"""fitting.effect_fit: fits of candidate effects, the baseline held, against synthetic truth
(``helpers.AnalyticForward``: no simulation) and the closed-form least squares of a constant
offset."""
import math

import numpy as np
import pytest

from fitting.effect_fit import fit_effects
from helpers import AnalyticForward, analytic_traces  # noqa: E402  (tests/helpers.py)


def _fit_traces(truth, seed):
    return [t for t in analytic_traces(truth, seed=seed) if t.role == "fit"]


def test_offset_fit_is_the_mean_with_its_standard_error():
    """A constant offset is linear: its fit is the mean of measured - model, and its
    Gauss-Newton standard error the standard error of that mean, s / sqrt(n)."""
    fwd = AnalyticForward()
    fit = _fit_traces({"sensor_offset": {"c": 1e-3}}, seed=7)
    d = np.concatenate([t.y - fwd.predict({}, t) for t in fit])
    vals, sd, sse, J = fit_effects(fwd, ["sensor_offset"], fit)
    n = d.size
    sse_exact = float(np.sum((d - d.mean()) ** 2))
    assert vals == {"sensor_offset": {"c": pytest.approx(d.mean(), rel=1e-6)}}
    assert sse == pytest.approx(sse_exact, rel=1e-9) and J.shape == (n, 1)
    assert sd["sensor_offset"]["c"] == pytest.approx(math.sqrt(sse_exact / (n - 1) / n), rel=1e-4)


@pytest.mark.parametrize("truth,name,param", [
    ({"electrode_stiffness": {"rel": 0.2}}, "electrode_stiffness", "rel"),
    ({"voltage_lag": {"tau": 0.02}}, "voltage_lag", "tau"),
])
def test_recovers_a_model_effect_within_its_standard_error(truth, name, param):
    fit = _fit_traces(truth, seed=8)
    vals, sd, _, _ = fit_effects(AnalyticForward(), [name], fit)
    value = truth[name][param]
    assert 0 < sd[name][param] < 0.1 * value
    assert abs(vals[name][param] - value) < 5 * sd[name][param], (vals, sd)


def test_fixed_effects_are_held():
    """An effect in ``fixed`` keeps its values (here the true offset), the fitted one is
    found beside it."""
    fwd = AnalyticForward()
    truth = {"sensor_offset": {"c": 1e-3}, "electrode_stiffness": {"rel": 0.2}}
    fit = _fit_traces(truth, seed=9)
    vals, sd, _, _ = fit_effects(fwd, ["electrode_stiffness"], fit, fixed={"sensor_offset": {"c": 1e-3}})
    assert vals["sensor_offset"] == {"c": 1e-3} and set(sd) == {"electrode_stiffness"}
    assert abs(vals["electrode_stiffness"]["rel"] - 0.2) < 5 * sd["electrode_stiffness"]["rel"]
