"""fitting.diagnose: ranking, verdict, uncertainties and shrinkage against known synthetic truth.

Fast tests use an analytic forward model (``helpers.AnalyticForward``: closed-form
quasi-static response y = 1 + k u_e(t)^2 / (1 + rel), u_e the lagged command), so the
diagnosis logic is checked in seconds; the block-simulation checks (voltage lag, amplifier slew)
are in the slow tier, ``pytest --runslow`` (each compiles the block simulation: ~1 min from a
cold compilation cache); the uniaxial example runs in the default tier."""
import argparse

import pytest

from fitting import cli as fitting_cli
from fitting import diagnose as dg
from helpers import ANALYTIC_SIGMA as SIGMA  # noqa: E402  (tests/helpers.py)
from helpers import AnalyticForward, analytic_traces

CANDS = ["voltage_lag", "electrode_stiffness", "sensor_offset", "sensor_drift", "sensor_latency"]


def test_control_no_false_alarm():
    d = dg.diagnose(AnalyticForward(), analytic_traces({}, seed=1), CANDS)
    assert d.verdict == "no significant gap" and d.best is None
    assert d.chi2_ratio < d.chi2_limit


@pytest.mark.parametrize("truth,name,param,value", [
    ({"sensor_offset": {"c": 1e-3}}, "sensor_offset", "c", 1e-3),
    ({"electrode_stiffness": {"rel": 0.2}}, "electrode_stiffness", "rel", 0.2),
    ({"voltage_lag": {"tau": 0.02}}, "voltage_lag", "tau", 0.02),
])
def test_identifies_true_effect(truth, name, param, value):
    tr = analytic_traces(truth, seed=2)
    d = dg.diagnose(AnalyticForward(), tr, CANDS)
    assert d.best == name, d.table()
    top = d.ranking[0]
    est, sd = top["values"][name][param], top["stderr"][name][param]
    assert sd > 0 and abs(est - value) < 5 * sd + 1e-3 * abs(value), (est, sd)
    assert d.shrinkage["holdout"]["gap_shrinkage"] > 0.7
    assert d.shrinkage["holdout"]["rms_after"] < 1.3 * SIGMA
    assert d.verdict == f"gap explained by '{name}'"


def test_offset_shows_in_the_breakdown_before_and_not_after():
    # an offset shows up as a mean gap, not as amplitude/phase gaps; the best effect closes it
    d = dg.diagnose(AnalyticForward(), analytic_traces({"sensor_offset": {"c": 2e-3}}, seed=4), ["sensor_offset"])
    f = d.breakdown_before["features"]
    assert f["mean"]["mean_gap"] == pytest.approx(-2e-3, abs=1e-4)
    assert f["amplitude"]["rms_gap"] < 1e-4
    for e in d.breakdown_before["traces"]:
        assert e["mean_residual"] == pytest.approx(-2e-3, abs=1e-4)
    assert abs(d.breakdown_after["features"]["mean"]["mean_gap"]) < 1e-4
    assert d.shrinkage["features"]["mean"]["shrinkage"] > 0.9
    # its uncertainty: the gap before spreads by the noise alone (about sigma / sqrt(n) for a gap
    # of 20 sigma), the shrinkage is well determined
    sp = d.shrinkage["holdout"]["spread"]
    n_hold = 120
    assert 0.7 < sp["gap_before"]["sd"] / (SIGMA / n_hold ** 0.5) < 1.5
    assert sp["shrinkage"]["sd"] < 0.1 and sp["shrinkage"]["lo"] > 0.7
    assert d.shrinkage["features"]["mean"]["spread"]["shrinkage"]["sd"] < 0.1


def test_refit_keeps_a_misfitted_baseline_from_masquerading_as_an_effect():
    # the data's mu_inf is 10 % above the baseline's: without a refit the electrode stiffness
    # (a factor on mu_inf) is named; refitting the baseline's mu_inf leaves no gap, and the
    # stiffness, collinear with it, is no longer significant
    tr = analytic_traces({"refit:mu_inf": {"factor": 1.1}}, seed=6)
    assert dg.diagnose(AnalyticForward(), tr, CANDS).best == "electrode_stiffness"
    d = dg.diagnose(AnalyticForward(), tr, CANDS, refit=["mu_inf"])
    assert d.verdict == "no significant gap" and d.best is None, d.table()
    ref = d.baseline["refit"]
    assert abs(ref["values"]["refit:mu_inf"] - 1.1) < 5 * ref["stderr"]["refit:mu_inf"] + 1e-3
    assert d.baseline["rms_fit"] < 1.3 * SIGMA < ref["before"]["rms_fit"]


def test_refit_fits_the_baseline_jointly_with_the_true_effect():
    tr = analytic_traces({"voltage_lag": {"tau": 0.02}, "refit:mu_inf": {"factor": 0.9}}, seed=7)
    d = dg.diagnose(AnalyticForward(), tr, CANDS, refit=["mu_inf"])
    assert d.best == "voltage_lag", d.table()
    top = d.ranking[0]
    for name, param, true in (("voltage_lag", "tau", 0.02), ("refit:mu_inf", "factor", 0.9)):
        est, sd = top["values"][name][param], top["stderr"][name][param]
        assert sd > 0 and abs(est - true) < 5 * sd + 1e-3 * true, (name, est, sd)
    assert top["k"] == 1  # the baseline's own parameter is not the effect's
    assert d.shrinkage["holdout"]["rms_after"] < 1.3 * SIGMA


def test_refit_rejects_what_is_no_material_parameter():
    with pytest.raises(KeyError, match="not a material parameter"):
        dg.diagnose(AnalyticForward(), analytic_traces({}, seed=1), CANDS, refit=["tau_1"])


def test_cli_registration():
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
    tr = analytic_traces({"voltage_lag": {"tau": 0.02}})
    dg.diagnose(AnalyticForward(), tr, ["voltage_lag", "sensor_offset"], noise=SIGMA, verbose=True)
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("[diagnose] baseline: simulating 3 trace(s)")
    assert out[1].startswith("[diagnose] baseline done in") and "2 candidate effect(s)" in out[1]
    assert out[2].split()[:2] == ["[1/2]", "voltage_lag"] and out[3].split()[:2] == ["[2/2]", "sensor_offset"]
    dg.diagnose(AnalyticForward(), tr, ["voltage_lag"], noise=SIGMA, verbose=False)
    assert capsys.readouterr().out == ""


def test_fit_top_fits_only_the_best_screened_candidate():
    """With fit_top = 1 only the best screened candidate is fitted, the others are reported
    as screened out and never chosen."""
    d = dg.diagnose(AnalyticForward(), analytic_traces({"sensor_offset": {"c": 1e-3}}, seed=6), CANDS, fit_top=1)
    assert d.best == "sensor_offset" and d.ranking[0]["fitted"]
    assert [c["fitted"] for c in d.ranking].count(True) == 1
    assert all(not c["significant"] for c in d.ranking if not c["fitted"])


def test_equivalent_lists_candidates_the_withheld_data_do_not_separate():
    """n_hold = 200: an MSE has relative sd sqrt(2/200) = 0.1, so within 2 sd means MSE
    below 1.2 x the best's; insignificant or screened-out candidates never count."""
    def cand(name, rms_hold, significant=True, fitted=True):
        return dg.CandidateResult(name, {}, {}, 1, 1.0, 1.0, rms_hold, 0.0, 0.0, 0.0, -50.0, 0, 0.0,
                                  significant=significant, fitted=fitted)

    best = cand("a", 1.0)
    others = [cand("b", 1.09), cand("c", 1.1), cand("d", 1.0, significant=False), cand("e", 1.0, fitted=False)]
    assert dg.equivalent(best, [best] + others, n_hold=200) == ["b"]  # 1.09^2 = 1.19 < 1.2 < 1.21 = 1.1^2



def test_uniaxial_example_names_the_missing_slow_unit():
    """The shipped uniaxial example end to end (``data/examples/uniaxial_diagnose.toml``: its
    traces simulated with a slow unit of 8 kPa, 10 s the model lacks, 0.1 kPa noise): a
    stretch-driven, quasi-static diagnosis names creep and recovers its parameters within
    three standard errors; the holdout rate's gap shrinks by more than 90 %. (The traces come
    from the same forward code: this checks the uniaxial pipeline, the block validation of
    bench/diagnose_validation.py checks against an independent model.)"""
    from pathlib import Path

    from fitting.data import load_experiment
    from fitting.forward import forward_from_experiment

    exp = load_experiment(Path(__file__).resolve().parents[1] / "data" / "examples" / "uniaxial_diagnose.toml")
    fwd, traces = forward_from_experiment(exp)
    d = dg.diagnose(fwd, traces, ["creep", "electrode_stiffness", "sensor_offset"], pairs=False, fit_top=2)
    assert d.best == "creep", d.table()
    top = d.ranking[0]
    for k, true in (("mu", 8e3), ("tau", 10.0)):
        assert abs(top["values"]["creep"][k] - true) < 3 * top["stderr"]["creep"][k], d.table()
    assert d.shrinkage["holdout"]["gap_shrinkage"] > 0.9
    loop = [b["features"]["loop_area"]["rms_gap"] for b in (d.breakdown_before, d.breakdown_after)]
    assert loop[0] > 10 * loop[1]  # the hysteresis loop in the (stretch, stress) plane


@pytest.mark.slow
def test_block_simulation_identifies_an_amplifier_slew_limit():
    """A threshold effect: traces of the block whose amplifier slews at most 2e5 V/s (the 16 kV,
    8 Hz command needs 4e5 V/s). It has no slope at off, so screening takes the secant to
    where it begins to act and the fit starts there (``Effect.starts``); it is named, its
    rate recovered within three standard errors, and effects that improve the fit traces
    but worsen the withheld one are not significant."""
    fwd = dg.block_forward(pad_to=160)
    conds = [("f1", "fit", 14e3, 4.0), ("f2", "fit", 16e3, 8.0), ("h", "holdout", 12e3, 6.0)]
    tr = dg.synthetic_traces(fwd, conds, {"amplifier_slew": {"rate": 2e5}}, 2e-4, seed=0, n_cycles=2,
                             samples_per_cycle=40)
    d = dg.diagnose(fwd, tr, ["amplifier_slew", "voltage_lag", "sensor_offset"], pairs=False)
    assert d.best == "amplifier_slew", d.table()
    top = d.ranking[0]
    assert abs(top["values"]["amplifier_slew"]["rate"] - 2e5) < 3 * top["stderr"]["amplifier_slew"]["rate"]
    lag = next(c for c in d.ranking if c["name"] == "voltage_lag")
    assert lag["d_bic"] < -10 and lag["worse_on_holdout"] and not lag["significant"]


def test_the_cli_reads_the_refit_parameters_from_the_fit_table():
    class Exp:
        path = "exp.toml"
        fit = type("Fit", (), {"free": ("mu_inf", "mu_1", "c_d")})

    assert fitting_cli.refit_params(None, Exp) == []
    assert fitting_cli.refit_params("", Exp) == ["mu_inf", "mu_1"]
    assert fitting_cli.refit_params("Jm_inf, eta_1", Exp) == ["Jm_inf", "eta_1"]
    Exp.fit.free = ()
    with pytest.raises(ValueError, match="no \\[fit\\] free"):
        fitting_cli.refit_params("", Exp)


def test_at_bounds_names_parameters_on_a_bound_but_not_at_their_off_value():
    assert dg.at_bounds({"creep": {"mu": 2e5, "tau": 5.0}}) == ["creep.mu"]  # mu's upper bound
    assert dg.at_bounds({"creep": {"mu": 0.0, "tau": 50.0}}) == ["creep.tau"]  # mu = 0 is off
    assert dg.at_bounds({"refit:mu_1": {"factor": 10.0}, "voltage_lag": {"tau": 0.01}}) == ["refit:mu_1.factor"]


def test_a_candidate_that_cannot_compete_is_not_fitted_once_one_reaches_the_noise():
    """An offset of 20 sigma: the offset, screened first, leaves residuals at the noise level;
    the other screened candidates, whose linearized BIC is far above it, are reported with
    their screened figures instead of being fitted (the diagnosis's cost), the verdict alike."""
    tr = analytic_traces({"sensor_offset": {"c": 2e-3}}, seed=6)
    d = dg.diagnose(AnalyticForward(), tr, CANDS, fit_top=3)
    assert d.best == "sensor_offset"
    assert [c["name"] for c in d.ranking if c["fitted"]] == ["sensor_offset"]
    others = [c for c in d.ranking if not c["fitted"]]
    assert len(others) == len(CANDS) - 1 and all(c["bic"] > d.ranking[0]["bic"] + 10 for c in others)
