"""Every verb end to end at tiny size, through ``dejax.cli.main`` (issue 14, point 4).

``run`` of a scenario (tests/test_cli.py), ``plot`` (tests/test_plot.py) and ``sweep``
(tests/test_cli_ux.py) are run end to end where their files are tested; here are
``verify``, ``bench``, ``sensitivity``, ``fit``, ``run`` of the fitted experiment and
``diagnose``. The fit and diagnose runs use a synthetic block experiment written here: the
hyperelastic 1 mm block under a sine voltage, its lateral stretch from the closed-form Gent
equilibrium (``dejax.verification.models``, independent of the finite-element code), so the
truth is known: the fit must move mu_inf towards it, the run of its fitted.toml must follow
the closed form at the fitted mu_inf, and the diagnosis must find a sensor offset added to
the data.
"""
import contextlib
import io
import json

import numpy as np
import pytest

from dejax import cli
from dejax.results import read_h5
from dejax.verification import models
from fitting import diagnose as dg
from fitting.data import load_experiment

MU, JM, EPS, L = 67e3, 15.0, 4e-11, 1e-3  # the paper's block (Sec. 4), hyperelastic
FREQ, T_END, N_SAMPLES = 2.0, 0.5, 21  # one voltage cycle, 20 steps of 25 ms
START = 1.5 * MU  # the fit's initial mu_inf (Pa)


def _sine(phi_max, t):
    """The traces' voltage (V) at t (s): docs/experiment-format.md's sine loading."""
    return 0.5 * phi_max * (1.0 + np.sin(2 * np.pi * FREQ * t + 1.5 * np.pi))


def _write_experiment(folder, mu_inf, offset=0.0):
    """A block experiment (TOML + two CSVs) in ``folder`` whose model starts at ``mu_inf`` (Pa);
    the traces are the closed-form stretch of the true mu_inf = 67 kPa (+ ``offset``).
    Returns the TOML path."""
    t = np.linspace(0.0, T_END, N_SAMPLES)
    traces = []
    for name, role, phi_max in (("fit_14kV", "fit", 14e3), ("hold_10kV", "holdout", 10e3)):
        phi = _sine(phi_max, t)
        lam = models.gent_equibiaxial_stretch(phi, L, MU, JM, EPS) + offset
        rows = "\n".join(f"{a:.17g},{b:.17g},{c / 1e3:.17g}" for a, b, c in zip(t, lam, phi))
        (folder / f"{name}.csv").write_text("time_s,stretch,voltage_kV\n" + rows + "\n")
        traces.append(f"""
[[traces]]
file = "{name}.csv"
role = "{role}"
conditions = {{ phi_max = {phi_max}, freq = {FREQ} }}
columns = {{ time = "time_s", stretch = "stretch", voltage = "voltage_kV" }}
units = {{ voltage = "kV" }}
""")
    toml = folder / "tiny.toml"
    toml.write_text(f"""
[experiment]
name = "tiny-block"
scenario = "block"

[geometry]
L = {L}
mesh = [1, 1, 1]

[material]
mu_inf = {mu_inf}
K_inf = 6.7e9
Jm_inf = {JM}
eps = {EPS}
rho = 1100.0

[fit]
free = ["mu_inf"]
max_iter = 2

[fit.bounds]
mu_inf = [1e4, 1e6]

[solver]
rho_inf = 0.8
""" + "".join(traces))
    return toml


def test_verify_writes_its_table_and_exits_1_on_a_failed_check(tmp_path, monkeypatch, capsys):
    from dejax.verification import cases

    real = cases.check_groups
    tiny = lambda quick=False: [real(quick)[0], ("block vs closed-form Gent equilibrium",  # noqa: E731
                                                  lambda: cases.block_vs_closed_form(phis=(8e3,)))]
    monkeypatch.setattr(cases, "check_groups", tiny)
    out = tmp_path / "v.json"
    assert cli.main(["verify", "--quick", "--json", str(out)]) == 0
    rows = json.loads(out.read_text())
    assert [r["reference"] for r in rows] == ["Project Chrono ANCF 3843", "closed-form Gent equilibrium"]
    assert all(r["passed"] and 0 <= r["error"] <= r["tolerance"] for r in rows)
    cap = capsys.readouterr()
    assert "2 passed, 0 failed" in cap.out and "[verify 2/2]" in cap.err
    failing = lambda quick=False: [("a failing check", lambda: [cases.Check("x", "y", 2.0, 1.0)])]  # noqa: E731
    monkeypatch.setattr(cases, "check_groups", failing)
    assert cli.main(["verify", "--json", str(out), "--quiet"]) == 1
    assert [r["passed"] for r in json.loads(out.read_text())] == [False]
    assert "0 passed, 1 failed" in capsys.readouterr().out


def test_bench_one_case_projected_from_a_few_steps(tmp_path, capsys):
    out = tmp_path / "b.json"
    assert cli.main(["bench", "--cases", "B1", "--max-steps", "20", "--json", str(out)]) == 0
    (row,) = json.loads(out.read_text())["rows"]
    assert row["case"].startswith("B1") and row["status"] == 0 and row["projected"]
    assert row["steps_run"] == 20 and row["steps"] == 3000 and row["coordinates"] == 96
    assert 1 <= row["newton_mean"] <= row["newton_max"] <= 25
    assert np.isfinite(row["steps_per_s"]) and row["steps_per_s"] > 0 and row["compile_s"] > 0
    assert "B1 block 1 el" in capsys.readouterr().out


def test_sensitivity_writes_jacobians_that_match_finite_differences(tmp_path):
    from fitting import sensitivity as S

    argv = ["sensitivity", "--params", "mu_inf", "--model", "hyperelastic", "--mesh", "1x4x1", "--freq", "500",
            "--t-end", "0.002", "--dt", "2.5e-4", "--out", str(tmp_path)]
    assert cli.main(argv) == 0
    d = json.loads((tmp_path / "sensitivity.json").read_text())
    assert d["names"] == ["mu_inf"] and len(d["time"]) == 9
    assert {"x_P", "x_max", "x_min", "mean", "loop_area"} <= set(d["jacobian"])  # one whole cycle: no k_c
    x, J = np.asarray(d["values"]["x_P"]), np.asarray(d["jacobian"]["x_P"])
    assert J.shape == (9, 1) and np.all(np.isfinite(J)) and np.max(np.abs(x)) > 1e-6
    # the same compiled forward (same Setup), differenced centrally
    setup = S.Setup(shape=(1, 4, 1), model="hyperelastic", freq=500.0, t_end=0.002, dt=2.5e-4)
    fd = S.finite_differences(S.default_params(setup), ["mu_inf"], setup)
    for key in d["jacobian"]:
        assert S.relative_error(np.asarray(d["jacobian"][key]), fd[key]) < 1e-4, key


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """The tiny experiment fitted once (two evaluations): (its folder, the fit's --out
    folder, what the fit printed)."""
    folder = tmp_path_factory.mktemp("experiment")
    toml = _write_experiment(folder, START)
    out = folder / "fit"
    argv = ["fit", str(toml), "--out", str(out), "--adam-steps", "1", "--lbfgs-steps", "1", "--steps", "20", "--quiet"]
    with contextlib.redirect_stdout(io.StringIO()) as printed:
        assert cli.main(argv) == 0
    return folder, out, printed.getvalue()


def test_fit_moves_the_parameter_towards_the_truth(fitted):
    _, out, printed = fitted
    d = json.loads((out / "fit.json").read_text())
    assert d["free"] == ["mu_inf"] and d["initial"] == {"mu_inf": START} and d["units"]["mu_inf"] == "Pa"
    assert np.isfinite(d["loss"]) and d["loss"] < d["loss0"]
    mu = d["params"]["mu_inf"]
    assert 1e4 < mu < 1e6 and abs(np.log(mu / MU)) < 0.5 * abs(np.log(START / MU))
    assert {k: v["role"] for k, v in d["rms"].items()} == {"fit_14kV": "fit", "hold_10kV": "holdout"}
    assert all(np.isfinite(v["rms"]) and v["n"] == N_SAMPLES for v in d["rms"].values())
    assert np.isfinite(d["stderr"]["mu_inf"]) and d["stderr"]["mu_inf"] > 0
    assert {"trace_fit_14kV.png", "trace_hold_10kV.png"} <= {p.name for p in out.iterdir()}
    assert "mu_inf" in printed
    # every figure with its unit: the numeric entries in key_units, the parameters' in units, each RMS its own
    assert set(d["key_units"]) == set(d) - {"free", "at_bound", "units", "key_units"}
    assert d["key_units"]["seconds"] == "s" and d["key_units"]["stderr"] == "units[name]"
    assert all(v["unit"] == "1" for v in d["rms"].values())  # stretch


def test_fit_writes_the_fitted_experiment(fitted):
    folder, out, printed = fitted
    d = json.loads((out / "fit.json").read_text())
    exp, new = load_experiment(folder / "tiny.toml"), load_experiment(out / "fitted.toml")
    assert new.parameters() == dict(exp.parameters(), mu_inf=d["params"]["mu_inf"])  # the very floats of fit.json
    assert new.fit.result == {"mu_inf": dict(value=d["params"]["mu_inf"], unit="Pa", stderr=d["stderr"]["mu_inf"],
                                             rel_stderr=d["rel_stderr"]["mu_inf"], initial=START)}
    assert (new.name, new.geometry, new.solver, new.fit.free, new.fit.bounds) == (
        exp.name, exp.geometry, exp.solver, exp.fit.free, exp.fit.bounds)
    for a, b in zip(exp.traces, new.traces, strict=True):  # the CSVs found from the fit's folder
        assert a.source.resolve() == b.source.resolve() and np.array_equal(a["stretch"], b["stretch"])
    text = (out / "fitted.toml").read_text()
    assert 'file = "../fit_14kV.csv"' in text and "mu_inf = {!r}  # fitted: +- ".format(d["params"]["mu_inf"]) in text
    assert "fitted.toml" in printed
    dg.forward_from_experiment(new)  # what dejax diagnose reads of it (run end to end below on the original)


def test_run_simulates_the_fitted_experiment(fitted, tmp_path):
    _, out, _ = fitted
    h5 = tmp_path / "sim.h5"
    argv = ["run", str(out / "fitted.toml"), "--trace", "hold_10kV", "--dt", "0.025", "--out", str(h5), "--quiet"]
    assert cli.main(argv) == 0
    res = read_h5(h5)
    a, mu = res["attrs"], json.loads((out / "fit.json").read_text())["params"]["mu_inf"]
    assert (a["scenario"], a["experiment"], a["trace"], a["status"], int(a["steps"])) == (
        "block", "tiny-block", "hold_10kV", "ok", 20)
    assert a["mu_inf"] == mu and a["phi_max"] == pytest.approx(10e3, rel=1e-12)
    t = res["time"]
    np.testing.assert_allclose(t, np.linspace(0.0, T_END, 21), rtol=0, atol=1e-12)
    phi = _sine(10e3, t)
    np.testing.assert_allclose(res["outputs"]["voltage"], phi, rtol=0, atol=1e-6)
    # the closed form at the fitted mu_inf (about 4e-8 off); at the true mu_inf it is ~1e-3 off
    lam = models.gent_equibiaxial_stretch(phi, L, mu, JM, EPS)
    np.testing.assert_allclose(res["outputs"]["lateral_stretch"], lam, rtol=0, atol=1e-6)


@pytest.mark.parametrize("argv, message", [
    (["run", "{dir}/missing.toml"], "missing.toml: experiment file not found"),
    (["run", "experiment", "{dir}/tiny.toml", "--trace", "nope"], "no trace named 'nope'; traces: fit_14kV, hold_10kV"),
])
def test_run_of_a_bad_experiment_exits_2_and_writes_nothing(tmp_path, capsys, argv, message):
    _write_experiment(tmp_path, MU)
    out = tmp_path / "sim.h5"
    assert cli.main([a.format(dir=tmp_path) for a in argv] + ["--out", str(out)]) == 2
    assert message in capsys.readouterr().err and not out.exists()


def test_diagnose_finds_the_sensor_offset(tmp_path, capsys):
    toml = _write_experiment(tmp_path, MU, offset=2e-3)
    out = tmp_path / "report"
    argv = ["diagnose", str(toml), "--out", str(out), "--effects", "sensor_offset", "--noise", "1e-4",
            "--max-iter", "3", "--quiet"]
    assert cli.main(argv) == 0
    d = json.loads((out / "report.json").read_text())
    assert d["best"] == "sensor_offset" and d["n_fit"] == N_SAMPLES
    (top,) = d["ranking"]
    assert top["name"] == "sensor_offset" and top["significant"]
    # the block matches the closed form to ~1e-7 in stretch: the offset is all of the gap
    assert top["values"]["sensor_offset"]["c"] == pytest.approx(2e-3, abs=1e-6)
    assert top["rms_fit"] < 1e-6 and d["baseline"]["rms_fit"] == pytest.approx(2e-3, rel=1e-3)
    assert "gap explained by 'sensor_offset'" in (out / "report.md").read_text()
    assert "verdict: gap explained by 'sensor_offset'" in capsys.readouterr().out
