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


def test_shrinkage_spread_against_closed_forms():
    """Traces 2e-3 above the model (20 sigma); the model after overshoots by 1e-3, with one
    parameter of sd 5e-4 moving every prediction one for one. The gap before spreads only by
    the noise: sd(sqrt(mean(r^2) - 2 sigma^2)) = sqrt(4 sigma^2 (d^2 + sigma^2) + 2 sigma^4) /
    (2 d sqrt(n)) for a replicate r = d + e + e' (about sigma / sqrt(n)); the gap after by the
    parameter: |1e-3 + 5e-4 xi| has sd 5e-4 (the noise's share is 1 % of it), so the
    shrinkage 1 - g_after / g_before has sd 5e-4 / 2e-3; the per-cycle mean feature alike."""
    tr = analytic_traces({"sensor_offset": {"c": 2e-3}}, seed=5)
    fwd = AnalyticForward()
    before = fwd.predict_many([({}, t) for t in tr])
    after = fwd.predict_many([({"sensor_offset": {"c": 3e-3}}, t) for t in tr])
    jac = [np.ones((len(t), 1)) for t in tr]
    sp = G.shrinkage_spread(tr, before, after, SIGMA, jac, np.array([[5e-4]]), draws=400, seed=1)
    d = 2e-3
    for role in ("fit", "holdout"):
        n = sum(len(t) for t in tr if (t.role == "fit") == (role == "fit"))
        sd_before = math.sqrt(4 * SIGMA ** 2 * (d ** 2 + SIGMA ** 2) + 2 * SIGMA ** 4) / (2 * d * math.sqrt(n))
        assert sp[role]["gap_before"]["sd"] == pytest.approx(sd_before, rel=0.15)
        assert sp[role]["gap_after"]["sd"] == pytest.approx(5e-4, rel=0.15)
        assert sp[role]["shrinkage"]["sd"] == pytest.approx(5e-4 / d, rel=0.15)
        assert sp[role]["shrinkage"]["lo"] < 0.5 < sp[role]["shrinkage"]["hi"]  # 1 - 1e-3 / 2e-3
    mean = sp["features"]["mean"]
    assert mean["gap_after"]["sd"] == pytest.approx(5e-4, rel=0.15)
    assert mean["gap_before"]["sd"] < 0.05 * mean["gap_after"]["sd"]  # the noise's share only
    # without the parameter's covariance only the noise spreads the gap after
    quiet = G.shrinkage_spread(tr, before, after, SIGMA, draws=100, seed=2)
    assert quiet["holdout"]["gap_after"]["sd"] < 0.05 * sp["holdout"]["gap_after"]["sd"]
