"""fitting.diagnose: ranking, verdict, uncertainties and breakdowns against known synthetic truth.

Fast tests use an analytic forward model (closed-form quasi-static response
y = 1 + k u_e(t)^2 / (1 + rel), u_e the lagged command), so the diagnosis logic is
checked in seconds; the simulation-based end-to-end check is in the slow tier, ``pytest --runslow``
(it compiles the block simulation: ~1-2 min on a shared CPU)."""
import argparse
import json
import os

import jax.numpy as jnp
import numpy as np
import pytest

from fitting import cli as fitting_cli
from fitting import diagnose as dg
from fitting import effects as fx
from fitting import report


class AnalyticForward(dg.Forward):
    def __init__(self, k=0.02 / 14e3 ** 2):
        self.pieces0 = fx.Pieces(None, None, fx.Sensor(), {})
        self.k = k
        self._cache = {}
        self.n_sims = 0
        self.transform = None

    def _launch(self, effects, trace):
        tau = effects.get("voltage_lag", {}).get("tau", 0.0)
        rel = effects.get("electrode_stiffness", {}).get("rel", 0.0)
        u = np.asarray(fx.lowpass(trace.voltage_history, tau, jnp.asarray(trace.time)))
        self.n_sims += 1
        return 1.0 + self.k * u ** 2 / (1.0 + rel)

    def _finish(self, effects, trace, launched):
        return launched


CONDS = [("f1", "fit", 14e3, 2.0), ("f2", "fit", 10e3, 5.0), ("h", "holdout", 12e3, 3.0)]
CANDS = ["voltage_lag", "electrode_stiffness", "sensor_offset", "sensor_drift", "sensor_latency"]
SIGMA = 1e-4


def _traces(truth, seed=0):
    return dg.synthetic_traces(AnalyticForward(), CONDS, truth, SIGMA, seed=seed, n_cycles=3, samples_per_cycle=40)


def test_noise_estimate():
    tr = _traces({}, seed=3)
    s = dg.estimate_noise(tr)
    assert abs(s / SIGMA - 1) < 0.1


def test_control_no_false_alarm():
    d = dg.diagnose(AnalyticForward(), _traces({}, seed=1), CANDS)
    assert d.verdict == "no significant gap" and d.best is None
    assert d.chi2_ratio < d.chi2_limit


@pytest.mark.parametrize("truth,name,param,value", [
    ({"sensor_offset": {"c": 1e-3}}, "sensor_offset", "c", 1e-3),
    ({"electrode_stiffness": {"rel": 0.2}}, "electrode_stiffness", "rel", 0.2),
    ({"voltage_lag": {"tau": 0.02}}, "voltage_lag", "tau", 0.02),
])
def test_identifies_true_effect(truth, name, param, value):
    tr = _traces(truth, seed=2)
    d = dg.diagnose(AnalyticForward(), tr, CANDS)
    assert d.best == name, d.table()
    top = d.ranking[0]
    est, sd = top["values"][name][param], top["stderr"][name][param]
    assert sd > 0 and abs(est - value) < 5 * sd + 1e-3 * abs(value), (est, sd)
    assert d.shrinkage["holdout"]["gap_shrinkage"] > 0.7
    assert d.shrinkage["holdout"]["rms_after"] < 1.3 * SIGMA
    assert d.verdict == f"gap explained by '{name}'"


def test_breakdown_localises_offset():
    # an offset shows up as a mean gap, not as amplitude/phase gaps
    d = dg.diagnose(AnalyticForward(), _traces({"sensor_offset": {"c": 2e-3}}, seed=4), ["sensor_offset"])
    f = d.breakdown_before["features"]
    assert f["mean"]["mean_gap"] == pytest.approx(-2e-3, abs=1e-4)
    assert f["amplitude"]["rms_gap"] < 1e-4
    for e in d.breakdown_before["traces"]:
        assert e["mean_residual"] == pytest.approx(-2e-3, abs=1e-4)


def test_report_and_cli_registration(tmp_path):
    tr = _traces({"sensor_offset": {"c": 1e-3}}, seed=5)
    d = dg.diagnose(AnalyticForward(), tr, ["sensor_offset", "voltage_lag"])
    files = report.write_report(d, tr, tmp_path)
    js = json.loads((tmp_path / "report.json").read_text())
    assert js["best"] == "sensor_offset" and js["ranking"][0]["name"] == "sensor_offset"
    assert "gap explained by 'sensor_offset'" in (tmp_path / "report.md").read_text()
    for f in files["figures"]:
        assert os.path.getsize(f) > 1000
    ap = argparse.ArgumentParser()
    sub = ap.add_subparsers(dest="command")
    fitting_cli.register_diagnose(sub)
    a = ap.parse_args(["diagnose", "exp.toml", "--out", "rep"])
    assert a.func is fitting_cli.diagnose_handler and a.experiment == "exp.toml" and a.out == "rep"


@pytest.mark.slow
def test_block_simulation_identifies_voltage_lag():
    fwd = dg.block_forward(pad_to=80)
    conds = [("f", "fit", 14e3, 2.0), ("h", "holdout", 12e3, 4.0)]
    tr = dg.synthetic_traces(fwd, conds, {"voltage_lag": {"tau": 0.02}}, SIGMA, seed=0, n_cycles=2,
                             samples_per_cycle=40)
    d = dg.diagnose(fwd, tr, ["voltage_lag", "sensor_offset", "electrode_stiffness"])
    assert d.best == "voltage_lag", d.table()
    assert abs(d.ranking[0]["values"]["voltage_lag"]["tau"] - 0.02) < 2e-3
    assert d.shrinkage["holdout"]["gap_shrinkage"] > 0.7


def test_diagnose_reports_progress_per_candidate(capsys):
    tr = _traces({"voltage_lag": {"tau": 0.02}})
    dg.diagnose(AnalyticForward(), tr, ["voltage_lag", "sensor_offset"], noise=SIGMA, verbose=True)
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("[diagnose] baseline: simulating 3 trace(s)")
    assert out[1].startswith("[diagnose] baseline done in") and "2 candidate effect(s)" in out[1]
    assert out[2].split()[:2] == ["[1/2]", "voltage_lag"] and out[3].split()[:2] == ["[2/2]", "sensor_offset"]
    dg.diagnose(AnalyticForward(), tr, ["voltage_lag"], noise=SIGMA, verbose=False)
    assert capsys.readouterr().out == ""


def test_screening_is_exact_for_a_linear_effect_and_fits_only_the_best():
    """The screening's bounded linear least squares on forward-difference columns: for the
    sensor offset (linear in its parameter) it is the exact fit, c = mean(measured - model);
    with fit_top = 1 only the best screened candidate is fitted, the others are reported as
    screened out and never chosen."""
    tr = _traces({"sensor_offset": {"c": 1e-3}}, seed=6)
    fwd = AnalyticForward()
    fit = [t for t in tr if t.role == "fit"]
    r0 = np.concatenate([fwd.predict({}, t) - t.y for t in fit])
    scr = dg.screen(fwd, CANDS, fit, r0)
    off = scr[("sensor_offset",)]
    c_exact = -float(np.mean(r0))
    c_screen = dg._values_of(dg._plist(["sensor_offset"]), off.z, ["sensor_offset"], {})["sensor_offset"]["c"]
    assert c_screen == pytest.approx(c_exact, rel=1e-9)
    assert off.sse == pytest.approx(float(np.sum((r0 - r0.mean()) ** 2)), rel=1e-9)
    assert ("voltage_lag", "sensor_offset") in scr and len(scr) == 5 + 10  # every pair screened too
    assert min(scr, key=lambda g: scr[g].d_bic if len(g) == 1 else np.inf) == ("sensor_offset",)
    d = dg.diagnose(fwd, tr, CANDS, fit_top=1)
    assert d.best == "sensor_offset" and d.ranking[0]["fitted"]
    assert [c["fitted"] for c in d.ranking].count(True) == 1
    assert all(not c["significant"] for c in d.ranking if not c["fitted"])
