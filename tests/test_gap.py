"""fitting.gap: the noise estimate, the residual breakdown and the gap beyond the noise,
against traces whose noise and offset are known."""
import math

import numpy as np
import pytest

from fitting import gap as G
from helpers import ANALYTIC_SIGMA as SIGMA  # noqa: E402  (tests/helpers.py)
from helpers import AnalyticForward, analytic_traces


def test_noise_estimate():
    s = G.estimate_noise(analytic_traces({}, seed=3))
    assert abs(s / SIGMA - 1) < 0.1


def test_breakdown_localises_offset():
    """Data 2e-3 above the model: a mean gap of -2e-3 in every cycle, no amplitude gap; the
    residual per cycle and per loading direction at the offset's size."""
    tr = analytic_traces({"sensor_offset": {"c": 2e-3}}, seed=4)
    fwd = AnalyticForward()
    b = G.breakdown(tr, fwd.predict_many([({}, t) for t in tr]))
    f = b["features"]
    assert f["mean"]["mean_gap"] == pytest.approx(-2e-3, abs=1e-4)
    assert f["amplitude"]["rms_gap"] < 1e-4
    assert [e["name"] for e in b["traces"]] == ["f1", "f2", "h"] and b["traces"][2]["role"] == "holdout"
    for e in b["traces"]:
        assert e["mean_residual"] == pytest.approx(-2e-3, abs=1e-4)
        assert len(e["per_cycle_rms"]) == 3 and all(r == pytest.approx(2e-3, rel=0.1) for r in e["per_cycle_rms"])
        assert e["loading_rms"] == pytest.approx(2e-3, rel=0.1) and e["unloading_rms"] == pytest.approx(2e-3, rel=0.1)
        assert len(e["features"]["mean"]["gap"]) == 3


def test_rms_and_gap():
    assert G.rms([3.0, -4.0]) == pytest.approx(math.sqrt(12.5), rel=1e-15) and G.rms([]) == 0.0
    assert G.gap(5.0, 3.0) == pytest.approx(4.0, rel=1e-15)
    assert G.gap(1.0, 2.0) == 0.0  # below the noise: no gap
