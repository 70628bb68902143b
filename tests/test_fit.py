"""fitting.fit: parameter transform, parameter replacement, and recovery of a known
viscoelastic parameter set from synthetic dejax traces (0.5 % noise) with a withheld
trace predicted (the independent expectation is the synthetic truth).

The recovery test compiles a 1-element uniaxial simulation with 2 viscous units
(value_and_grad and jacfwd: two compilations of 30-100 s each on a loaded 2-core
machine), so it is marked slow; run with --runslow."""
import json

import jax.numpy as jnp
import numpy as np
import pytest

from fitting import fit as F
from fitting.experiment import UniaxialForward, triangle_knots, uniaxial_target

TRUTH = dict(mu_inf=20e3, K_inf=2e7, Jm_inf=60.0, eps=4.7e-11, rho=960.0,
             mu_1=30e3, K_1=3e7, Jm_1=50.0, eta_1=3e3,      # tau_1 = eta/(2 mu) = 0.05 s
             mu_2=10e3, K_2=1e7, Jm_2=50.0, eta_2=2e4)      # tau_2 = 1 s
N_STEPS = 100
PEAK = 1.5


def test_logbox_roundtrip_and_bounds():
    box = F.LogBox(np.array([1.0, 1e3]), np.array([100.0, 1e6]))
    p = np.array([3.0, 5e4])
    assert np.allclose(np.asarray(box.to_p(jnp.asarray(box.to_theta(p)))), p, rtol=1e-9)
    big = np.asarray(box.to_p(jnp.asarray([50.0, -50.0])))
    assert big[0] <= 100.0 * (1 + 1e-12) and big[1] >= 1e3 * (1 - 1e-12)


def test_fit_rejects_bad_input():
    with pytest.raises(KeyError):
        F.fit(lambda p, d: d, {"a": 1.0}, ["b"], None, [])
    with pytest.raises(ValueError):
        F.fit(lambda p, d: d, {"a": 1.0}, ["a"], {"a": (2.0, 3.0)}, [])


def _synthetic(rate, noise, seed):
    """A triangle 1 -> PEAK -> 1 at ``rate`` (1/s), stress from dejax with TRUTH (+ noise)."""
    T = 2 * (PEAK - 1) / rate
    t = np.linspace(0, T, 41)
    lam = np.interp(t, [0, T / 2, T], [1, PEAK, 1])
    fwd = UniaxialForward(2)
    tg = uniaxial_target(f"rate_{rate:g}", t, lam, np.zeros_like(t), N_STEPS, knots=triangle_knots(t, lam))
    y = np.asarray(fwd(TRUTH, tg.data))
    assert np.all(np.isfinite(y))
    rng = np.random.default_rng(seed)
    y = y + noise * np.ptp(y) * rng.standard_normal(y.size)
    return uniaxial_target(f"rate_{rate:g}", t, lam, y, N_STEPS, knots=triangle_knots(t, lam))


@pytest.mark.slow
def test_recovers_synthetic_viscoelastic_parameters(tmp_path):
    train = [_synthetic(0.5, 0.005, 1), _synthetic(5.0, 0.005, 2)]
    held = [_synthetic(1.5, 0.0, 3)]
    free = ["mu_inf", "mu_1", "eta_1", "mu_2", "eta_2"]
    p0 = dict(TRUTH)
    for k, f in zip(free, [1.4, 0.7, 2.0, 1.6, 0.5]):  # start away from the truth
        p0[k] = TRUTH[k] * f
    bounds = {k: (TRUTH[k] / 20, TRUTH[k] * 20) for k in free}
    res = F.fit(UniaxialForward(2), p0, free, bounds, train, held, adam_steps=15, adam_lr=0.15, lbfgs_steps=40)
    for k in free:
        err = abs(res.params[k] - TRUTH[k])
        assert err <= max(0.05 * TRUTH[k], 2 * res.stderr[k]), (k, res.params[k], TRUTH[k], res.stderr[k])
    assert res.rms["rate_1.5"]["rel_rms"] < 0.02
    # noise level 0.5 % of the amplitude: the training RMS must be about that
    for tg in train:
        assert res.rms[tg.name]["rel_rms"] < 0.01
    paths = res.save(tmp_path)
    d = json.loads((tmp_path / "fit.json").read_text())
    assert set(d["free"]) == set(free) and len(d["correlation"]) == len(free)
    assert any(p.name.startswith("loop_") for p in paths)


def _cli(argv):
    import argparse

    from fitting import cli as fitting_cli

    ap = argparse.ArgumentParser(prog="dejax")
    sub = ap.add_subparsers(dest="command", required=True)
    fitting_cli.register_fit(sub)
    args = ap.parse_args(argv)
    return args.func(args)


def test_fit_verb_bad_file_exits_2(tmp_path, capsys):
    assert _cli(["fit", str(tmp_path / "missing.toml")]) == 2
    assert "error" in capsys.readouterr().err


@pytest.mark.slow
def test_fit_verb_on_example_experiment(tmp_path, capsys):
    from pathlib import Path

    toml = Path(__file__).resolve().parents[1] / "data" / "examples" / "vhb4910_uniaxial.toml"
    rc = _cli(["fit", str(toml), "--out", str(tmp_path), "--adam-steps", "2", "--lbfgs-steps", "2",
               "--max-points", "20"])
    assert rc == 0
    d = json.loads((tmp_path / "fit.json").read_text())
    assert d["free"] == ["mu_inf", "mu_1", "eta_1"]
    assert d["loss"] < d["loss0"]  # the fit improved on the initial guess
    assert d["rms"]["vhb4910_1.5_0.03"]["role"] == "holdout"
    assert (tmp_path / "loop_vhb4910_1.5_0.05.png").exists()
    assert "RMS" in capsys.readouterr().out


def _linear_targets(bad=None):
    """Two traces of y = mu_inf * x (Pa); ``bad``: the trace whose prediction is NaN."""
    x = jnp.linspace(0.0, 1.0, 5)
    return [F.Target(name, np.asarray(2e4 * x), {"x": x, "nan": jnp.asarray(np.nan if name == bad else 0.0)},
                     unit="Pa") for name in ("slow", "fast")]


def _linear(params, data):
    return params["mu_inf"] * data["x"] + data["nan"]


def test_fit_table_shows_units_of_parameters_and_rms(capsys):
    res = F.fit(_linear, {"mu_inf": 1e4}, ["mu_inf"], {"mu_inf": (1e3, 1e5)}, _linear_targets(), adam_steps=2,
                lbfgs_steps=3, covariance=False, verbose=True, method="adam-lbfgs")
    log = capsys.readouterr().out.splitlines()
    adam = [line for line in log if line.startswith("[fit] adam")]
    assert [line.split()[2] for line in adam] == ["1/2", "2/2"] and all("mu_inf=" in line for line in adam)
    assert all("loss" in line and line.endswith(" s)") for line in adam)
    lines = res.table().splitlines()
    assert lines[0].endswith("unit") and lines[1].split()[0] == "mu_inf" and lines[1].split()[-1] == "Pa"
    rms_rows = [line for line in lines if line.split()[:1] in (["slow"], ["fast"])]
    assert len(rms_rows) == 2 and all(r.split()[-1] == "Pa" for r in rms_rows)
    assert res.rms["slow"]["unit"] == "Pa" and res.to_dict()["units"] == {"mu_inf": "Pa"}


def test_fit_with_a_failing_trace_names_it(capsys):
    with pytest.raises(FloatingPointError, match="trace 'fast': the prediction is not finite") as e:
        F.fit(_linear, {"mu_inf": 1e4}, ["mu_inf"], None, _linear_targets(bad="fast"), adam_steps=1, lbfgs_steps=0)
    assert "'slow'" not in str(e.value)
    assert "[fit] compiling the forward model" in capsys.readouterr().out


def test_failed_simulation_of_a_trace_is_explained_with_time_and_cause():
    """Stretching to 3 with Jm_inf = 1 reaches the Gent limit near stretch 1.7 (t ~ 0.35 s)."""
    t = np.linspace(0.0, 1.0, 11)
    lam = 1.0 + 2.0 * t
    tg = uniaxial_target("too-far", t, lam, np.zeros_like(t), 10)
    params = dict(mu_inf=20e3, K_inf=2e8, Jm_inf=1.0, eps=4.7e-11, rho=960.0)
    msg = F.explain_nonfinite(UniaxialForward(0), params, tg)
    assert msg.startswith("trace 'too-far': simulation failed at t = ")
    t_fail = float(msg.split("t = ")[1].split(" s")[0])
    assert 0.2 <= t_fail <= 0.5
    assert "Gent" in msg or ("Newton" in msg and "try more steps (--steps" in msg)


def test_traces_of_different_lengths_share_shapes():
    """fit._common_shapes pads every trace's arrays to the longest by repeating the last
    entry and masks the padded observations; the real entries are untouched."""
    from fitting.fit import Target, _common_shapes

    t1 = Target("a", np.array([1.0, 2.0, 3.0]), {"times": np.linspace(0, 1, 5), "t_obs": np.array([0.0, 0.5, 1.0])})
    t2 = Target("b", np.array([4.0, 5.0]), {"times": np.linspace(0, 2, 9), "t_obs": np.array([0.0, 2.0])})
    out = _common_shapes([t1, t2])
    (d1, y1, m1), (d2, y2, m2) = out["a"], out["b"]
    assert d1["times"].shape == d2["times"].shape == (9,)
    np.testing.assert_array_equal(d1["times"], np.r_[np.linspace(0, 1, 5), [1.0] * 4])
    np.testing.assert_array_equal(y2, [4.0, 5.0, 5.0])
    np.testing.assert_array_equal(m1, [1, 1, 1])
    np.testing.assert_array_equal(m2, [1, 1, 0])
    np.testing.assert_array_equal(d2["t_obs"], [0.0, 2.0, 2.0])


def _quadratic(params, data):
    return params["a"] * data["x"] + params["b"] * data["x"] ** 2


def test_forward_and_reverse_mode_fits_agree_with_least_squares(monkeypatch):
    """With few free parameters the Adam + L-BFGS fit differentiates in forward mode (one
    program for loss, gradient, covariance and predictions), otherwise in reverse mode;
    Levenberg-Marquardt uses the forward-mode Jacobian. All three reach the linear
    least-squares solution (numpy's lstsq) and the same standard errors (numpy's
    s^2 (X^T X)^-1 of the log-parameters), on traces of different lengths (padded to common
    shapes)."""
    rng = np.random.default_rng(5)
    targets = []
    for name, n in (("short", 7), ("long", 12)):
        x = np.linspace(0.1, 1.0, n)
        targets.append(F.Target(name, 3.0 * x + 2.0 * x ** 2 + 0.01 * rng.standard_normal(n), {"x": jnp.asarray(x)}))
    X = np.concatenate([np.stack([t.data["x"], t.data["x"] ** 2], 1) * np.sqrt(1 / t.y.size) / t.norm for t in targets])
    Y = np.concatenate([t.y * np.sqrt(1 / t.y.size) / t.norm for t in targets])
    ref, rss = np.linalg.lstsq(X, Y, rcond=None)[:2]
    cov = float(rss[0]) / (Y.size - 2) * np.linalg.inv(X.T @ X)
    se_ref = np.sqrt(np.diag(cov))  # of (a, b); the fit reports them from log p: the same to first order
    results = []
    for method, max_free in (("adam-lbfgs", 4), ("adam-lbfgs", 0), ("lm", 4)):
        monkeypatch.setattr(F, "FORWARD_MODE_MAX_FREE", max_free)
        res = F.fit(_quadratic, {"a": 1.0, "b": 1.0}, ["a", "b"], {"a": (0.1, 10.0), "b": (0.1, 10.0)}, targets,
                    adam_steps=30, lbfgs_steps=60, verbose=False, method=method)
        np.testing.assert_allclose([res.params["a"], res.params["b"]], ref, rtol=1e-5)
        np.testing.assert_allclose([res.stderr[k] for k in "ab"], se_ref, rtol=1e-6)
        # predictions of the fit traces: the model at the optimum
        for t in targets:
            np.testing.assert_allclose(res.predictions[t.name], ref[0] * t.data["x"] + ref[1] * t.data["x"] ** 2,
                                       rtol=1e-5)
        results.append(res)
    assert results[2].n_evals < results[0].n_evals / 3  # Levenberg-Marquardt: far fewer evaluations
