"""Issue 15: from a lab CSV to a fitted, diagnosed model. Output files readable by
colleagues (umask), output paths checked before any work (exit 2), a failed run keeps its
trajectory, units / actual dt / version / command line in HDF5, a VTU time series,
consistent errors, help with defaults, honest progress."""
import json
import os

import h5py
import numpy as np
import pytest

from dejax import cli
from dejax import progress as pg
from dejax.results import check_output_dir, check_output_path, OutputPathError, write_h5


def _blocked(tmp_path):
    """A regular file: no path under it can be written by anyone, root included."""
    f = tmp_path / "a-file"
    f.write_text("x")
    return f


# ----------------------------------------------------------------------------- files


@pytest.mark.parametrize("mask, mode", [(0o022, 0o644), (0o002, 0o664), (0o077, 0o600)])
def test_results_file_mode_follows_umask(tmp_path, mask, mode):
    old = os.umask(mask)
    try:
        p = write_h5(tmp_path / "r.h5", np.linspace(0, 1, 3), {"x_P": np.zeros(3)})
    finally:
        os.umask(old)
    assert os.stat(p).st_mode & 0o777 == mode


def test_output_checks_name_the_path(tmp_path):
    bad = _blocked(tmp_path)
    with pytest.raises(OutputPathError, match="is a file, not a folder"):
        check_output_path(bad / "x.h5")
    with pytest.raises(OutputPathError, match="a-file"):
        check_output_dir(bad / "sub")
    assert check_output_dir(tmp_path / "new" / "deeper") == tmp_path / "new" / "deeper"
    assert not (tmp_path / "new").exists()  # checking creates nothing


def _forbid(monkeypatch, target):
    def boom(*a, **k):
        raise AssertionError(f"{target} was called")

    monkeypatch.setattr(target, boom)


@pytest.mark.parametrize(
    "argv, compute",
    [
        (["run", "block", "--t-end", "0.01", "--dt", "0.01", "--out", "{bad}/x.h5"], "dejax.integrate.run_chunked"),
        (["run", "block", "--t-end", "0.01", "--dt", "0.01", "--out", "{ok}/x.h5", "--vtu", "{bad}/vtu"],
         "dejax.integrate.run_chunked"),
        (["verify", "--quick", "--json", "{bad}/v.json"], "dejax.verification.cases.main"),
        (["sweep", "--freq", "10", "--json", "{bad}/s.json"], "dejax.sweep.run_sweep"),
        (["bench", "--cases", "B1", "--json", "{bad}/b.json"], "dejax.bench.main"),
        (["fit", "data/examples/vhb4910_uniaxial.toml", "--out", "{bad}/fit"], "fitting.experiment.run_experiment"),
        (["diagnose", "data/examples/block_example.toml", "--out", "{bad}/rep"], "fitting.diagnose.diagnose"),
    ],
)
def test_unwritable_output_exits_2_before_any_work(tmp_path, capsys, monkeypatch, argv, compute):
    bad = _blocked(tmp_path)
    _forbid(monkeypatch, compute)
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    monkeypatch.chdir(root)
    argv = [a.format(bad=bad, ok=tmp_path) for a in argv]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert str(bad) in err and "error" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a-file"]


# ----------------------------------------------------------------------------- runs


def test_h5_units_actual_dt_version_command_line_and_vtu_series(tmp_path, capsys):
    import meshio

    out, vtu = tmp_path / "b.h5", tmp_path / "vtu"
    argv = ["run", "block", "--t-end", "0.05", "--dt", "0.03", "--out", str(out), "--vtu", str(vtu),
            "--vtu-frames", "2", "--quiet"]
    assert cli.main(argv) == 0
    assert "dt = 0.025 s (requested 0.03 s" in capsys.readouterr().out
    with h5py.File(out) as f:
        assert f.attrs["dt"] == pytest.approx(0.025) and f.attrs["dt_requested"] == 0.03
        assert np.allclose(np.diff(f["time"][()]), f.attrs["dt"])
        assert f.attrs["dejax_version"] and f.attrs["command_line"] == "dejax " + " ".join(argv)
        datasets = []
        f.visititems(lambda name, obj: datasets.append(obj) if isinstance(obj, h5py.Dataset) else None)
        assert len(datasets) >= 5
        for d in datasets:
            assert d.attrs["units"] not in ("", "unknown"), d.name
        assert f["outputs/voltage"].attrs["units"] == "V" and f["time"].attrs["units"] == "s"
        units = json.loads(f.attrs["units"])
        numeric = [k for k, v in f.attrs.items() if np.asarray(v).dtype.kind in "iuf"]
        assert set(numeric) <= set(units) and "unknown" not in units.values()
        assert units["phi_max"] == "V" and units["mu_inf"] == "Pa" and units["eta"] == "Pa s"
        volt = f["outputs/voltage"][()]
    pvd = (vtu / "b.pvd").read_text()
    files = sorted(p.name for p in vtu.glob("*.vtu"))
    assert len(files) == 3 and all(name in pvd for name in files)  # t = 0, 0.025, 0.05
    last = meshio.read(vtu / files[-1])
    for key in ("displacement", "potential", "nominal_field", "strain_norm"):
        assert key in last.point_data, key
    assert np.max(last.point_data["potential"]) == pytest.approx(volt[-1], rel=1e-9)
    assert np.max(np.abs(last.point_data["nominal_field"][:, 2])) == pytest.approx(volt[-1] / 1e-3, rel=1e-6)
    first = meshio.read(vtu / files[0])
    assert np.max(np.abs(first.point_data["displacement"])) == 0.0
    from dejax.outputs import vtu_from_h5  # the Python export of the file's snapshot has the field too

    (again,) = vtu_from_h5(out, tmp_path / "again")
    snap = meshio.read(again).point_data
    assert np.max(snap["potential"]) == pytest.approx(volt[-1], rel=1e-9)
    np.testing.assert_allclose(snap["displacement"], last.point_data["displacement"], atol=1e-15)


def test_failed_run_keeps_its_trajectory_and_progress_stays_honest(tmp_path, capsys, monkeypatch):
    """Far above pull-in the block fails; the file holds the run up to the last converged
    step, the bar never reads 100 %, and the command exits 1 saying where the data went."""
    seen = []
    call = pg.ProgressBar.__call__
    monkeypatch.setattr(pg.ProgressBar, "__call__", lambda self, k, n, t, w: (seen.append(k), call(self, k, n, t, w)))
    out = tmp_path / "fail.h5"
    rc = cli.main(["run", "block", "--hyperelastic", "--phi-max", "200e3", "--t-end", "1", "--dt", "1e-2",
                   "--out", str(out)])
    assert rc == 1
    err = capsys.readouterr().err
    assert "simulation failed at t = " in err and f"written to {out}" in err
    assert "compiling the block stepper" in err and "failed after step" in err and "100%" not in err
    with h5py.File(out) as f:
        assert f.attrs["status"] == "failed"
        fail_t, step = float(f.attrs["fail_time"]), int(f.attrs["fail_step"])
        assert "instability" in f.attrs["fail_reason"] and f.attrs["fail_status"] == "instability"
        t = f["time"][()]
        lam = f["outputs/lateral_stretch"][()]
        assert 0 < t[-1] < fail_t and t[-1] == pytest.approx(fail_t - 1e-2)
        assert t.size == step and np.all(np.isfinite(lam)) and lam[-1] > lam[0]
        assert f["newton_iterations"].shape == (t.size - 1,)
        (snap,) = f["snapshots"].values()  # the converged sub-step nearest the failure
        assert t[-1] <= snap.attrs["t"] < fail_t
    assert max(seen) == t.size - 1 < 100  # progress counted converged steps, not the chunk end
    assert [p.name for p in tmp_path.iterdir()] == ["fail.h5"]


def test_long_run_announces_its_projected_wall_time(tmp_path, capsys, monkeypatch):
    _forbid(monkeypatch, "dejax.integrate.run_chunked")
    with pytest.raises(AssertionError, match="run_chunked was called"):
        cli.main(["run", "rolled", "--out", str(tmp_path / "r.h5"), "--quiet"])
    err = capsys.readouterr().err
    assert "projected to take about" in err and " h (" in err and "960 elements x 3334 steps" in err


# ----------------------------------------------------------------------------- arguments and help


@pytest.mark.parametrize(
    "argv, message",
    [
        (["sweep", "--freq", "a,b"], "--freq must be comma-separated numbers, got 'a,b'"),
        (["sweep", "--freq", "10", "--mesh", "abc"], "mesh must look like 12x20x4"),
        (["sweep", "--freq", "10", "--cycles", "0"], "--cycles must be >= 1"),
        (["run", "block", "--out", "x.h5", "--vtu-frames", "0"], "--vtu-frames must be >= 1"),
        (["fit", "x.toml", "--steps", "0"], "--steps must be >= 1"),
        (["fit", "x.toml", "--adam-steps", "two"], "--adam-steps must be a whole number, got 'two'"),
        (["diagnose", "x.toml", "--max-iter", "0"], "--max-iter must be >= 1"),
        (["diagnose", "x.toml", "--noise", "-1"], "--noise must be > 0"),
        (["sensitivity", "--dt", "0"], "--dt must be > 0"),
    ],
)
def test_bad_values_are_argparse_errors_exit_2(capsys, argv, message):
    with pytest.raises(SystemExit) as e:
        cli.main(argv)
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert message in err and "invalid literal" not in err


def test_diagnose_errors_go_to_stderr(tmp_path, capsys):
    rc = cli.main(["diagnose", str(tmp_path / "missing.toml"), "--out", str(tmp_path / "rep")])
    assert rc == 2
    cap = capsys.readouterr()
    assert "missing.toml" in cap.err and "error" not in cap.out


def _verbs(parser):
    """(name, parser) of every verb and run scenario."""
    import argparse

    for a in parser._actions:
        if isinstance(a, argparse._SubParsersAction):
            for name, sub in a.choices.items():
                yield name, sub
                yield from ((f"{name} {n}", p) for n, p in _verbs(sub))


def test_every_help_shows_defaults():
    verbs = dict(_verbs(cli.build_parser()))
    assert {"run block", "run rolled", "run torsional", "verify", "bench", "sweep", "fit", "diagnose"} <= set(verbs)
    for name, p in verbs.items():
        text = " ".join(p.format_help().split())
        for a in p._actions:
            if a.option_strings and a.default is not None and a.default is not False and a.default != "" \
                    and a.dest != "help":
                help_text = " ".join((a.help or "").split())
                assert "default" in help_text.lower() or "(default: " in text, (name, a.dest)
                shown = " ".join(p._get_formatter()._get_help_string(a).split())
                assert "default" in shown.lower(), (name, a.dest)
    block = " ".join(verbs["run block"].format_help().split())
    assert "peak voltage phi_m (V) (default: 12000.0)" in block and "(default: 1x1x1)" in block
    assert "structural damping c_d (1/s), C = c_d M (default: 0.0)" in block and "(default: 0.001)" in block


# ----------------------------------------------------------------------------- progress


def test_sweep_reports_progress_per_case(capsys):
    rc = cli.main(["sweep", "--freq", "10,20", "--cycles", "2", "--steps-per-cycle", "10", "--mesh", "1x4x1"])
    out, err = capsys.readouterr()
    assert rc == 0, out + err
    assert "compiling the tube stepper (1x4x1 elements" in err
    lines = [line.split() for line in err.splitlines() if line.strip().startswith("case ")]
    assert [w[1] for w in lines] == ["1/2", "2/2"] and lines[-1][-1] == "0:00:00"
    quiet = cli.main(["sweep", "--freq", "10,20", "--cycles", "2", "--steps-per-cycle", "10", "--mesh", "1x4x1",
                      "--quiet"])
    assert quiet == rc and "case 1/2" not in capsys.readouterr().err


def test_verify_announces_each_check_group(capsys):
    from dejax.verification import cases as verify

    labels = [label for label, _ in verify.check_groups(quick=True)]
    assert len(labels) == 5 and labels[0] == "element vs Project Chrono"
    rows = verify.run_all(groups=verify.check_groups()[:1], progress=verify.stderr_progress)
    err = capsys.readouterr().err.splitlines()
    assert err[0].startswith("[verify 1/1] element vs Project Chrono ...") and err[-1].startswith("[verify] 1 groups")
    assert all(r.passed for r in rows)


def test_readme_example_experiment_builds_for_fit_and_diagnose():
    """The README's 'your own data' example: the files exist, load, and build a fit and a
    diagnosis problem (the runs themselves compile for minutes; see the README)."""
    from pathlib import Path

    from fitting import diagnose as dg
    from fitting.data import load_experiment
    from fitting.experiment import from_experiment

    root = Path(__file__).resolve().parents[1]
    readme = (root / "README.md").read_text()
    assert "dejax fit data/examples/block_example.toml" in readme and "docs/experiment-format.md" in readme
    exp = load_experiment(root / "data/examples/block_example.toml")
    fwd, params0, free, bounds, targets, holdout, opts = from_experiment(exp)
    assert free == ["mu_inf", "eta_1"] and [t.name for t in targets] == ["block_14kV_2Hz"]
    assert [t.name for t in holdout] == ["block_12kV_4Hz"] and targets[0].unit == "1"
    assert targets[0].data["times"].shape == (81,)  # [solver] dt = 0.0125 s over the 1 s trace
    _, traces = dg.forward_from_experiment(exp)
    assert [t.role for t in traces] == ["fit", "holdout"] and np.ptp(traces[0].y) > 0.01
    doc = (root / "docs/experiment-format.md").read_text()
    from fitting import schema as fs
    from fitting.units import CHANNELS

    for key in (*fs.EXPERIMENT_KEYS, *fs.MATERIAL_SCALARS, *fs.UNIT_KEYS, *fs.FIT_KEYS, *fs.SOLVER_KEYS,
                *fs.TRACE_KEYS, *CHANNELS, *fs.LOADING_KINDS, *sum(fs.GEOMETRY_KEYS.values(), ())):
        assert f"`{key}`" in doc, key


def test_too_coarse_cycles_give_a_clear_error():
    """A sweep with 4 steps per cycle used to end in 'Singular matrix'."""
    from dejax.outputs import cycle_table

    t = np.linspace(0.0, 0.1, 5)
    x = np.sin(2 * np.pi * 10 * t) ** 2
    with pytest.raises(ValueError, match="need at least 8 samples over the whole cycles.*got 5"):
        cycle_table(t, x, x, 10.0)
    t = np.linspace(0.0, 0.1, 41)  # 40 samples per cycle: fine
    assert cycle_table(t, np.sin(2 * np.pi * 10 * t) ** 2, None, 10.0)["x_max"].size == 1


def test_every_scenario_output_and_parameter_has_a_unit():
    """The results-file units table covers what the scenarios record (their output
    functions, traced abstractly: no compilation) and store."""
    import jax

    from dejax import integrate as it
    from dejax import scenarios
    from dejax.results import _attr_units, unit_of

    problems = [scenarios.block(), scenarios.rolled("IV", shape=(1, 4, 1)), scenarios.torsional(shape=(4, 2, 2)),
                scenarios.uniaxial(lambda t: 1.0 + t, scenarios.block_material())]
    for prob in problems:
        units = _attr_units(prob.params)
        assert "unknown" not in units.values(), (prob.name, units)
        names = jax.eval_shape(lambda p=prob: p.output_fn(p.model, p.loading, it.initial_state(p.model, p.loading)))
        assert len(names) >= 3 and all(unit_of(k) != "unknown" for k in names), (prob.name, list(names))


@pytest.mark.slow
def test_readme_diagnose_command_names_the_lag(tmp_path, capsys):
    """The README's step 2 on the shipped block example (about a minute: it compiles)."""
    from pathlib import Path

    toml = Path(__file__).resolve().parents[1] / "data/examples/block_example.toml"
    rc = cli.main(["diagnose", str(toml), "--out", str(tmp_path / "report"), "--effects", "voltage_lag,sensor_offset"])
    assert rc == 0
    out = capsys.readouterr().out
    assert "verdict: gap explained by 'voltage_lag'" in out
    tau = float(out.split("voltage_lag.tau=")[1].split("+-")[0])
    assert abs(tau - 0.02) < 2e-3  # the traces were made with tau = 20 ms
    assert (tmp_path / "report" / "report.md").exists()
