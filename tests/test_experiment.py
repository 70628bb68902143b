"""Forward models of fits from experiment files (fitting.experiment.from_experiment): which
forward each scenario gets, its targets, one number of steps per forward (one compiled
simulation), and the errors for what dejax fit cannot do. Nothing is simulated here."""
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
