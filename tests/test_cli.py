"""Command-line contract of issue 2: `dejax run block ...` writes /time and
/outputs/lateral_stretch with parameters as attributes; bad input exits 2 and
never leaves a file behind."""
import subprocess
import sys

import h5py
import numpy as np
import pytest

from dejax import cli


def test_run_block_writes_h5(tmp_path, capsys):
    out = tmp_path / "block.h5"
    rc = cli.main(["run", "block", "--phi-max", "12e3", "--t-end", "0.5", "--dt", "5e-3", "--out", str(out), "--quiet"])
    assert rc == 0
    line = capsys.readouterr().out.strip().splitlines()[-1]
    assert "block" in line and "Newton" in line and str(out) in line
    with h5py.File(out) as f:
        t = f["time"][()]
        lam = f["outputs/lateral_stretch"][()]
        assert t.shape == lam.shape == (101,)
        assert t[0] == 0.0 and abs(t[-1] - 0.5) < 1e-12
        assert lam[0] == pytest.approx(1.0, abs=1e-12)
        assert np.all(np.isfinite(lam)) and lam[-1] > 1.0
        assert f.attrs["phi_max"] == 12e3
        assert f.attrs["mu_inf"] == 67e3
        assert f.attrs["scenario"] == "block"
    assert [p.name for p in tmp_path.iterdir()] == ["block.h5"]  # no temporary left


@pytest.mark.parametrize(
    "args, message",
    [
        (["--phi-max", "-1"], "--phi-max must be >= 0"),
        (["--t-end", "abc"], "--t-end must be a number"),
        (["--mesh", "2x2"], "mesh must look like"),
        (["--dt", "0"], "--dt must be > 0"),
        (["--rho-inf", "1.5"], "--rho-inf must lie in [0, 1]"),
        (["--step-tol", "0"], "--step-tol must be > 0"),
    ],
)
def test_bad_arguments_exit_2(tmp_path, capsys, args, message):
    out = tmp_path / "x.h5"
    with pytest.raises(SystemExit) as e:
        cli.main(["run", "block", "--out", str(out), *args])
    assert e.value.code == 2
    assert message in capsys.readouterr().err
    assert not out.exists()


def test_step_tol_refines_a_coarse_output_grid(tmp_path, capsys):
    """--step-tol: the --dt grid is the output grid, the steps follow the error estimate
    (the block under 12 kV ramped in 0.2 ms rings at about 1 kHz, which 0.4 ms steps do not
    resolve); quasi-static runs refuse it."""
    out = tmp_path / "block.h5"
    rc = cli.main(["run", "block", "--phi-max", "12e3", "--t-end", "4e-3", "--t-ramp", "2e-4", "--dt", "4e-4",
                   "--step-tol", "1e-4", "--out", str(out), "--quiet"])
    assert rc == 0
    with h5py.File(out) as f:
        assert f["time"].shape == (11,)
        assert f.attrs["step_tol"] == 1e-4
        assert f.attrs["dt_smallest"] < 4e-4 / 8
    capsys.readouterr()
    rc = cli.main(["run", "block", "--t-end", "0.2", "--dt", "2e-2", "--step-tol", "1e-4", "--quasi-static",
                   "--out", str(tmp_path / "qs.h5"), "--quiet"])
    assert rc == 2
    assert "--step-tol (error control) needs inertia" in capsys.readouterr().err
    assert not (tmp_path / "qs.h5").exists()


def test_unwritable_path_exit_2(tmp_path, capsys):
    out = tmp_path / "missing-folder" / "x.h5"
    rc = cli.main(["run", "block", "--t-end", "0.1", "--out", str(out)])
    assert rc == 2
    assert "does not exist" in capsys.readouterr().err
    assert not out.parent.exists()


def test_directory_as_output_exit_2(tmp_path, capsys):
    rc = cli.main(["run", "block", "--t-end", "0.1", "--out", str(tmp_path)])
    assert rc == 2
    assert "is a directory" in capsys.readouterr().err


# a failed run: tests/test_cli_ux.py::test_failed_run_keeps_its_trajectory_and_progress_stays_honest


@pytest.mark.parametrize("argv, expanded", [
    (["run", "fit/fitted.toml", "--out", "a.h5"], ["run", "experiment", "fit/fitted.toml", "--out", "a.h5"]),
    (["--no-compile-cache", "run", "E.TOML"], ["--no-compile-cache", "run", "experiment", "E.TOML"]),
    (["run", "experiment", "e.toml"], None),
    (["run", "block", "--out", "x.toml"], None),
    (["fit", "e.toml"], None),
    (["run"], None),
    ([], None),
])
def test_run_of_a_toml_file_is_short_for_run_experiment(argv, expanded):
    assert cli.expand_run_shorthand(argv) == (argv if expanded is None else expanded)


def test_run_experiment_options_default_to_the_file():
    """--dt, --rho-inf, ... left out are None: the experiment's [solver] decides (its run: tests/test_cli_e2e.py)."""
    args = cli.build_parser().parse_args(cli.expand_run_shorthand(["run", "f.toml", "--trace", "t", "--out", "o.h5"]))
    assert (args.scenario, args.experiment, args.trace, args.dt, args.rho_inf) == ("experiment", "f.toml", "t", None, None)


def test_console_script_help():
    r = subprocess.run([sys.executable, "-m", "dejax.cli", "--help"], capture_output=True, text=True)
    assert r.returncode == 0 and "run" in r.stdout and "verify" in r.stdout


def test_compile_cache_folder_and_switches(tmp_path, monkeypatch):
    import jax

    from dejax import compile_cache

    before = jax.config.jax_compilation_cache_dir
    try:
        folder = compile_cache.enable(tmp_path / "cache")
        assert folder == tmp_path / "cache" and folder.is_dir()
        assert jax.config.jax_compilation_cache_dir == str(folder)
    finally:
        jax.config.update("jax_compilation_cache_dir", before)
    monkeypatch.setenv("DEJAX_COMPILE_CACHE", "0")
    assert compile_cache.disabled_by_env()
    monkeypatch.setenv("DEJAX_COMPILE_CACHE", "1")
    assert not compile_cache.disabled_by_env()
    monkeypatch.setenv("DEJAX_CACHE_DIR", str(tmp_path / "elsewhere"))
    assert compile_cache.default_dir() == tmp_path / "elsewhere"
    assert cli.build_parser().parse_args(["--no-compile-cache", "verify"]).no_compile_cache


def test_flow_update_option_reaches_the_time_scheme():
    """``dejax run ... --flow-update backward-euler`` selects the paper's Eq. 39 update in the
    scheme the run uses (default bdf2), for the inertial and the quasi-static stepper."""
    from dejax import integrate as it
    from dejax import scenarios

    p = scenarios.block()
    for argv, want in ((["run", "block", "--out", "x.h5"], "bdf2"),
                       (["run", "block", "--out", "x.h5", "--flow-update", "backward-euler"], "backward-euler")):
        a = cli.build_parser().parse_args(argv)
        assert a.flow_update == want
        for qs in (None, True):
            s = p.scheme(a.rho_inf, qs, a.flow_update)
            assert s.flow_update == want and isinstance(s, it.QuasiStatic if qs else it.GeneralizedAlpha)
    with pytest.raises(SystemExit):
        cli.build_parser().parse_args(["run", "block", "--out", "x.h5", "--flow-update", "trapezoid"])


def test_run_rolled_voltage_file_drives_the_tube(tmp_path, capsys):
    """A CSV voltage history sampled finely from the Eq. (42) sine gives the sine run's x_P
    (to the interpolation error), and the run ends at the file's last time."""
    t = np.linspace(0.0, 0.5 / 30.0, 401)
    csv = tmp_path / "v.csv"
    np.savetxt(csv, np.c_[t, 0.5 * 50e3 * (1.0 + np.sin(2 * np.pi * 30.0 * t + 1.5 * np.pi))], delimiter=",",
               header="time_s,voltage_V", comments="")
    common = ["run", "rolled", "--mesh", "1x4x1", "--dt", "1e-3", "--quiet"]
    assert cli.main([*common, "--cycles", "0.5", "--out", str(tmp_path / "sine.h5")]) == 0
    assert cli.main([*common, "--voltage", str(csv), "--out", str(tmp_path / "csv.h5")]) == 0
    with h5py.File(tmp_path / "sine.h5") as a, h5py.File(tmp_path / "csv.h5") as b:
        assert b["time"][-1] == pytest.approx(t[-1], rel=1e-12)
        np.testing.assert_allclose(b["outputs/voltage"][()], a["outputs/voltage"][()], rtol=0, atol=50e3 * 2e-4)
        xa, xb = a["outputs/x_P"][()], b["outputs/x_P"][()]
        assert np.max(np.abs(xa - xb)) < 1e-3 * np.max(np.abs(xa))
        assert b.attrs["voltage_file"] == str(csv)


def test_run_rolled_bad_voltage_file_exits_2(tmp_path, capsys):
    csv = tmp_path / "v.csv"
    csv.write_text("time_s,voltage_V\n0,0\n0.01,x\n")
    out = tmp_path / "r.h5"
    rc = cli.main(["run", "rolled", "--mesh", "1x4x1", "--voltage", str(csv), "--out", str(out)])
    assert rc == 2
    assert "row 3, column 2" in capsys.readouterr().err
    assert not out.exists()
