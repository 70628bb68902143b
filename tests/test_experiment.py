"""Forward models of fits from experiment files (fitting.experiment.from_experiment): which
forward each scenario gets, its targets, one number of steps per forward (one compiled
simulation), the errors for what dejax fit cannot do, and the one problem builder of run, fit
and diagnose. Nothing is simulated here."""
import dataclasses
from pathlib import Path

import numpy as np
import pytest

from fitting import experiment as E
from fitting.data import load_experiment

EXAMPLES = Path(__file__).resolve().parents[1] / "data" / "examples"


def test_uniaxial_example():
    exp = load_experiment(EXAMPLES / "vhb4910_uniaxial.toml")
    fwd, params0, free, bounds, targets, holdout, opts = E.from_experiment(exp, max_points=20)
    assert fwd == E.UniaxialForward(1, voltage=False, lz=1e-3)
    assert free == ["mu_inf", "mu_1", "eta_1"] and bounds["eta_1"] == (1e2, 1e8)
    assert params0["mu_1"] == 30e3 and params0["c_d"] == 0.0 and "geometry.h" not in params0
    assert [t.name for t in targets] == ["vhb4910_1.5_0.05", "vhb4910_1.5_0.01"]
    assert [t.name for t in holdout] == ["vhb4910_1.5_0.03"]
    n = {t.data["times"].shape for t in targets + holdout}
    assert len(n) == 1  # one number of steps for every trace
    for t in targets + holdout:
        assert t.y.shape == (20,) and t.unit == "Pa" and np.all(np.diff(t.data["knots_t"]) > 0)
    assert (targets[0].label(targets[0].response), targets[0].label(targets[0].against)) == (
        "nominal stress (Pa)", "stretch")
    assert opts["max_iter"] == 30
    for t in targets + holdout:  # the loading's turning point (peak stretch) is a grid node
        kt, kl = np.asarray(t.data["knots_t"]), np.asarray(t.data["knots_lam"])
        assert np.min(np.abs(np.asarray(t.data["times"]) - kt[np.argmax(kl)])) < 1e-12


def test_turning_points_of_a_history():
    """Reversals of a piecewise-linear history, jitter below 1e-3 of the range ignored."""
    assert list(E.turning_points([0, 1, 2, 3, 4], [1, 1.5, 2, 1.5, 1])) == [2.0]
    assert list(E.turning_points([0, 1, 2, 3], [1, 2, 1, 2])) == [1.0, 2.0]
    assert list(E.turning_points([0, 1, 2, 3, 4], [1, 2, 1.9999, 2.5, 1])) == [3.0]  # a dip inside the jitter
    assert list(E.turning_points([0, 1, 2, 3], [1, 1, 2, 2])) == []  # holds are not reversals
    assert E.turning_points([0, 1], [1, 2]).size == 0


def test_step_grid_passes_through_its_nodes():
    g = E.step_grid(10.0, 7, [3.3])
    assert g.shape == (8,) and g[0] == 0.0 and g[-1] == 10.0 and 3.3 in g
    d = np.diff(g)
    np.testing.assert_allclose(d[:2], 1.65)  # uniform between nodes, steps shared by length
    np.testing.assert_allclose(d[2:], 6.7 / 5)
    g = E.step_grid(10.0, 4, [0.1, 9.9, 12.0])  # short segments get one step; nodes outside ignored
    np.testing.assert_allclose(g, [0.0, 0.1, 5.0, 9.9, 10.0])
    np.testing.assert_allclose(E.step_grid(2.0, 4), np.linspace(0, 2, 5))


def test_block_and_rolled_examples_get_their_forwards():
    exp = load_experiment(EXAMPLES / "block_example.toml")
    fwd, *_, targets, holdout, _ = E.from_experiment(exp, n_steps=7)
    assert isinstance(fwd, E.BlockForward) and fwd.output == "lateral_stretch"
    assert all(t.data["times"].shape == (8,) for t in targets + holdout)
    for t, tr in zip(targets + holdout, exp.traces):  # each the experiment's trace at its samples, against V
        assert (t.name, t.role, t.conditions, t.source) == (tr.name, tr.role, tr.conditions, tr.source)
        np.testing.assert_array_equal(t.y, tr["stretch"])
        np.testing.assert_array_equal(t.x, tr.voltage())
        assert t.unit == "1" and (t.label(t.response), t.label(t.against)) == ("stretch (-)", "voltage (V)")
    tube = load_experiment(EXAMPLES / "tube_example.toml")
    fwd, *_ = E.from_experiment(tube, n_steps=5)
    assert isinstance(fwd, E.RolledForward) and fwd.output == "x_P" and fwd.h == 2e-3
    assert set(E.FIT_TARGETS) == {"uniaxial", "block", "rolled"}


def test_what_dejax_fit_cannot_do():
    exp = load_experiment(EXAMPLES / "block_example.toml")
    with pytest.raises(ValueError, match="scenario 'torsional' is not supported"):
        E.from_experiment(dataclasses.replace(exp, scenario="torsional"))
    no_fit = tuple(dataclasses.replace(tr, role="holdout") for tr in exp.traces)
    with pytest.raises(ValueError, match="no trace with role = 'fit'"):
        E.from_experiment(dataclasses.replace(exp, traces=no_fit))
    bad = dataclasses.replace(exp, fit=dataclasses.replace(exp.fit, free=("geometry.L",)))
    with pytest.raises(ValueError, match="free parameter 'geometry.L' is not supported"):
        E.from_experiment(bad)
    mullins = dataclasses.replace(exp, material={**exp.material, "mullins_d": 0.3})
    with pytest.raises(ValueError, match="does not model Mullins softening"):
        E.from_experiment(mullins)
    # dejax run of the experiment builds its material with the softening
    setup = E.experiment_run(mullins)
    assert float(setup.problem.model.material.mullins_d) == 0.3


# ----------------------------------------------------------------------------- dejax run of an experiment


def _phi(setup, times):
    """The run's voltage (V) at ``times`` (s)."""
    return np.asarray(setup.problem.loading.voltages[0](np.asarray(times, dtype=float)))


def test_run_of_the_tube_follows_the_chosen_trace():
    tube = load_experiment(EXAMPLES / "tube_example.toml")
    s = E.experiment_run(tube)  # the first trace: a loading table (sine, 25 kV, 30 Hz), no voltage column
    p = s.problem
    assert (p.name, s.trace, s.output) == ("rolled", "trace_30Hz", "x_P")
    assert p.params["mesh"] == [4, 8, 1] and p.params["h"] == 2e-3 and p.params["mu_inf"] == 81e3
    assert p.params["trace"] == "trace_30Hz" and p.params["experiment"] == "tube-example" and p.params["freq"] == 30.0
    assert s.t_end == tube.trace("trace_30Hz").time[-1]
    assert s.settings == {"dt": 1e-4, "dt_min": 1e-6, "rho_inf": 0.8, "newton_tol": 1e-6}  # [solver] dt, rho_inf
    t = np.linspace(0.0, s.t_end, 7)
    np.testing.assert_allclose(_phi(s, t), 12.5e3 * (1 + np.sin(2 * np.pi * 30.0 * t + 1.5 * np.pi)), atol=1e-6)
    # the second trace has a voltage column (kV in the CSV): the run follows the samples; options win over [solver]
    s = E.experiment_run(tube, "trace_10Hz", dt=1e-3, rho_inf=0.5, damping=2.0, gauss_order=2)
    tr = tube.trace("trace_10Hz")
    np.testing.assert_allclose(_phi(s, tr.time[::25]), tr["voltage"][::25], rtol=1e-12, atol=1e-9)
    assert s.settings["dt"] == 1e-3 and s.settings["rho_inf"] == 0.5
    assert s.problem.params["damping"] == 2.0 and s.problem.params["gauss_order"] == 2
    assert s.problem.params["phi_max"] == pytest.approx(np.max(np.abs(tr["voltage"])), rel=1e-12)


def test_run_of_the_uniaxial_example_follows_the_stretch():
    exp = load_experiment(EXAMPLES / "vhb4910_uniaxial.toml")
    s = E.experiment_run(exp)
    tr = exp.traces[0]
    assert (s.problem.name, s.trace, s.output) == ("uniaxial", tr.name, "stress") and s.problem.quasi_static
    steps = max(int(np.ceil(np.sum(np.abs(np.diff(tr["stretch"]))) / 5e-3)), 50)  # 5e-3 of stretch per step
    assert s.t_end == tr.time[-1] and s.settings["dt"] == pytest.approx(tr.time[-1] / steps, rel=1e-12)
    u = np.asarray(s.problem.loading.motions[0](tr.time[::10]))
    np.testing.assert_allclose(u, tr["stretch"][::10] - 1.0, rtol=0, atol=1e-12)


TORSIONAL = """
[experiment]
name = "strip"
scenario = "torsional"

[geometry]
L = 6e-3
W = 2e-3
h = 1e-3
twist = 0.5
mesh = [2, 2, 2]

[material]
mu_inf = 50e3
K_inf = 5e8
Jm_inf = 20.0
eps = 4e-11
rho = 1000.0

[[traces]]
file = "ramp.csv"
columns = { time = "t", angle = "a", voltage = "v" }

[[traces]]
file = "ramp.csv"
name = "longer"
conditions = { L = 8e-3 }
columns = { time = "t", angle = "a", voltage = "v" }
"""


def test_run_of_a_torsional_strip_takes_the_trace_voltage_and_geometry(tmp_path):
    (tmp_path / "ramp.csv").write_text("t,a,v\n0,0,0\n0.5,0.1,300\n1,0.2,600\n")
    (tmp_path / "strip.toml").write_text(TORSIONAL)
    exp = load_experiment(tmp_path / "strip.toml")
    s = E.experiment_run(exp)
    p = s.problem.params
    assert (s.problem.name, s.output, s.t_end, s.settings["dt"]) == ("torsional", "twist_angle", 1.0, 1.0 / 200)
    assert (p["length"], p["width"], p["thickness"], p["turns"], p["mesh"]) == (6e-3, 2e-3, 1e-3, 0.5, [2, 2, 2])
    assert "phibar_max" not in p and "t_ramp" not in p and p["phi_max"] == 600.0
    np.testing.assert_allclose(_phi(s, [0.0, 0.25, 0.5, 1.0, 2.0]), [0.0, 150.0, 300.0, 600.0, 600.0], atol=1e-9)
    assert E.experiment_run(exp, "longer").problem.params["length"] == pytest.approx(8e-3, rel=1e-12)


def test_run_of_an_unknown_trace_or_one_without_time():
    exp = load_experiment(EXAMPLES / "vhb4910_uniaxial.toml")
    with pytest.raises(ValueError, match=r"vhb4910_uniaxial.toml: no trace named 'nope'; traces: vhb4910_1.5_0.05"):
        E.experiment_run(exp, "nope")
    timeless = dataclasses.replace(exp, traces=(dataclasses.replace(exp.traces[0], time=None),))
    with pytest.raises(ValueError, match="has no time column; dejax run needs one"):
        E.experiment_run(timeless)


def test_run_fit_and_diagnose_build_one_problem():
    """``experiment_problem`` is the one builder: the run of an experiment, its fit forward
    and its diagnosis forward simulate the same tube with the same probe (the outer edge
    when [geometry] probe = "outer"; the fit forward used to ignore the key)."""
    import jax.numpy as jnp

    from dejax import parameters
    from fitting.forward import forward_from_experiment

    tube = load_experiment(EXAMPLES / "tube_example.toml")
    outer = dataclasses.replace(tube, geometry={**tube.geometry, "probe": "outer"})
    fwd, params0, *_, targets, _, _ = E.from_experiment(outer, n_steps=5)
    assert fwd.probe == "outer"
    problems = {
        "run": E.experiment_run(outer).problem,
        "fit": fwd.problem({k: jnp.asarray(v) for k, v in params0.items()}, targets[0].data),
        "diagnose": forward_from_experiment(outer)[0].problem,
    }
    inner = E.experiment_run(tube).problem
    for name, p in problems.items():
        assert p.output_fn == problems["run"].output_fn, name
        assert p.model.structure.n_free == inner.model.structure.n_free, name
    assert problems["run"].output_fn != inner.output_fn  # the probe moved to the outer edge
    mat = parameters.from_flat({k: jnp.asarray(v) for k, v in params0.items()}, fwd.n_units)
    with pytest.raises(ValueError, match="unknown scenario 'tubular'"):
        E.experiment_problem("tubular", tube.geometry, mat)
