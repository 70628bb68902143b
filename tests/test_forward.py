"""fitting.forward: the diagnosis's forward model caches its simulations (sensor effects need
none), its residuals in normalized parameters and their forward differences, and its
builders (synthetic traces in closed form, an experiment file's traces)."""
import dataclasses
from pathlib import Path

import equinox as eqx
import numpy as np
import pytest

from dejax import integrate as it

from fitting import effects as fx
from fitting import forward as fw
from fitting.data import load_experiment
from helpers import AnalyticForward, analytic_traces  # noqa: E402  (tests/helpers.py)

EXAMPLES = Path(__file__).resolve().parents[1] / "data" / "examples"
K = 0.02 / 14e3 ** 2  # AnalyticForward's y = 1 + K u^2


def test_synthetic_traces_follow_the_model_under_a_sine_loading():
    tr = fw.synthetic_traces(AnalyticForward(), [("a", "holdout", 10e3, 4.0)], {}, 0.0, n_cycles=2,
                             samples_per_cycle=8)
    (t,) = tr
    assert (t.name, t.role, t.response, t.conditions) == ("a", "holdout", "stretch", {"phi_max": 10e3, "freq": 4.0})
    np.testing.assert_allclose(t.time, np.linspace(0.0, 0.5, 17), rtol=0, atol=1e-15)
    u = 5e3 * (1.0 + np.sin(2 * np.pi * 4.0 * t.time + 1.5 * np.pi))  # the sine loading, paper Eq. (42)
    np.testing.assert_allclose(t.y, 1.0 + K * u ** 2, rtol=1e-12)


def test_simulations_are_cached_and_sensor_effects_run_none():
    fwd = AnalyticForward()
    t = analytic_traces({}, seed=0)[0]
    y0 = fwd.predict({}, t)
    assert fwd.n_sims == 1
    np.testing.assert_array_equal(fwd.predict({}, t), y0)
    np.testing.assert_allclose(fwd.predict({"sensor_offset": {"c": 1e-3}}, t), y0 + 1e-3, rtol=0, atol=1e-15)
    drift = fwd.predict({"sensor_drift": {"rate": 2e-3}}, t)
    np.testing.assert_allclose(drift, y0 + 2e-3 * (t.time - t.time[0]), rtol=0, atol=1e-15)
    assert fwd.n_sims == 1  # the sensor effects transform the cached output
    fwd.predict_many([({"voltage_lag": {"tau": 0.01}}, t), ({"voltage_lag": {"tau": 0.01}}, t)])
    assert fwd.n_sims == 2  # one simulation for a new model effect, once


def test_simulations_of_one_call_run_on_threads_and_give_the_one_by_one_results(monkeypatch):
    t = analytic_traces({}, seed=0)
    jobs = [({"voltage_lag": {"tau": tau}}, tr) for tau in (0.0, 0.01, 0.02) for tr in t]
    one_by_one = [AnalyticForward().raw(*job) for job in jobs]
    monkeypatch.setattr(fw, "SIM_THREADS", 3)
    fwd = AnalyticForward()
    together = fwd.raw_many(jobs + jobs[:2])  # repeated jobs: simulated once
    assert fwd.n_sims == len(jobs)
    for a, b in zip(together, one_by_one + one_by_one[:2]):
        np.testing.assert_array_equal(a, b)


def test_residuals_and_forward_differences_in_normalized_parameters():
    """sensor_offset c = -1 + 2 z: the residuals move by 2 dz, the forward difference is 2
    (backward at the upper bound z = 1)."""
    tr = analytic_traces({"sensor_offset": {"c": 1e-3}}, seed=1)
    fwd = AnalyticForward()
    resid_many = fw.residuals_at(fwd, ["sensor_offset"], tr)
    r_half, r_one = resid_many([np.array([0.5]), np.array([1.0])])
    base = np.concatenate([fwd.predict({}, t) - t.y for t in tr])
    np.testing.assert_allclose(r_half, base, rtol=0, atol=1e-15)
    np.testing.assert_allclose(r_one, base + 1.0, rtol=0, atol=1e-12)
    for z, r in ((np.array([0.5]), r_half), (np.array([1.0]), r_one)):
        J = fw.fd_jacobian(resid_many, z, r)
        assert J.shape == (base.size, 1)
        np.testing.assert_allclose(J, 2.0, rtol=1e-9)


def test_forward_differences_take_per_parameter_step_overrides():
    """A quadratic residual r(z) = z^2 (element-wise): the forward difference with step s is
    2 z + s, so each column shows the step it was taken with (default h, or the override)."""
    resid_many = lambda points: [np.asarray(zz) ** 2 for zz in points]
    z = np.array([0.2, 0.5, 0.99])
    J = fw.fd_jacobian(resid_many, z, z ** 2, h=0.02, overrides={1: 0.3})
    # column 0: forward h; column 1: the override; column 2: backward (z + h leaves [0, 1])
    np.testing.assert_allclose(np.diag(J), [2 * 0.2 + 0.02, 2 * 0.5 + 0.3, 2 * 0.99 - 0.02], rtol=1e-12)
    np.testing.assert_allclose(J - np.diag(np.diag(J)), 0.0, atol=0)


def test_simulated_responses_are_the_prediction_plus_seeded_noise():
    tr = analytic_traces({}, seed=1)
    fwd = AnalyticForward()
    ys = fw.simulated_responses(fwd, tr, {"sensor_offset": {"c": 1e-3}}, noise=1e-4, seed=7)
    rng = np.random.default_rng(7)
    for t, y in zip(tr, ys):  # noise drawn in trace order from one generator
        expect = fwd.predict({"sensor_offset": {"c": 1e-3}}, t) + 1e-4 * rng.standard_normal(len(t.time))
        np.testing.assert_allclose(y, expect, rtol=0, atol=1e-15)


def test_forward_from_an_experiment_file():
    exp = load_experiment(EXAMPLES / "block_example.toml")
    fwd, traces = fw.forward_from_experiment(exp)
    assert [t.name for t in traces] == [t.name for t in exp.traces]
    for t, e in zip(traces, exp.traces):
        assert t.response == "stretch" and t.role == e.role
        np.testing.assert_array_equal(t.y, e["stretch"])
    assert fwd.output == "lateral_stretch" and fwd.transform is None
    assert fwd.pad_to == max(len(e) for e in exp.traces) - 1
    with pytest.raises(ValueError, match="needs a 'stress' channel for the uniaxial scenario"):
        fw.forward_from_experiment(dataclasses.replace(exp, scenario="uniaxial"))


def test_uniaxial_experiment_gives_a_stretch_driven_quasi_static_forward():
    """The shipped uniaxial diagnose example: response stress (Pa) under each trace's own
    measured stretch, stepped quasi-statically; the voltage effects and added mass do not
    apply. The moduli's drift (mu_drift) is realised as a gain on the stress: it rests on
    the stress being homogeneous of degree one in the moduli (viscosities scaled alike), which
    a simulation with every modulus and viscosity scaled by 1.3 confirms."""
    exp = load_experiment(EXAMPLES / "uniaxial_diagnose.toml")
    fwd, traces = fw.forward_from_experiment(exp)
    assert fwd.output == "stress" and isinstance(fwd.scheme, it.QuasiStatic)
    assert [t.response for t in traces] == ["stress"] * 3
    assert set(fx.names(fwd.pieces0)) == {"creep", "hysteresis", "mu_drift", "electrode_stiffness", "mullins",
                                          "sensor_offset", "sensor_drift", "sensor_latency"}
    tr = traces[1]  # 0.03 1/s: stretch 1 -> 2 -> 1 over 66.7 s
    y0 = fwd.predict({}, tr)
    assert 2e4 < y0.max() < 5e4 and abs(np.argmax(y0) - len(y0) // 2) <= 1  # peak stress at peak stretch
    rate = 2e-3
    np.testing.assert_allclose(fwd.predict({"mu_drift": {"rate": rate}}, tr), (1 + rate * tr.time) * y0, rtol=1e-12)
    m = fwd.problem.model.material
    scaled = eqx.tree_at(lambda x: (x.mu_inf, x.K_inf, x.mu, x.K, x.eta), m,
                         (1.3 * m.mu_inf, 1.3 * m.K_inf, 1.3 * m.mu, 1.3 * m.K, 1.3 * m.eta))
    problem = dataclasses.replace(fwd.problem, model=eqx.tree_at(lambda md: md.material, fwd.problem.model, scaled))
    y13 = fw.Forward(problem, "stress", pad_to=fwd.pad_to, drive=fw.drive_stretch).predict({}, tr)  # same compiled run
    np.testing.assert_allclose(y13, 1.3 * y0, rtol=1e-7, atol=1e-6 * y0.max())
    # sensor offsets of a stress are in kPa
    np.testing.assert_allclose(fwd.predict({"sensor_offset": {"c": 0.5}}, tr), y0 + 500.0, rtol=1e-12)


def test_torsional_experiment_gives_a_voltage_driven_twist_forward():
    exp = load_experiment(EXAMPLES / "torsional_diagnose.toml")
    fwd, traces = fw.forward_from_experiment(exp)
    assert fwd.output == "twist_angle" and [t.response for t in traces] == ["angle"] * 3
    assert np.deg2rad(10.0) < max(traces[0].y) < np.deg2rad(30.0)  # tens of degrees, in rad
    assert {"voltage_lag", "leakage", "added_mass"} <= set(fx.names(fwd.pieces0))
    assert "prestress" not in fx.names(fwd.pieces0)


def test_rolled_experiment_gives_a_tube_forward_with_an_axial_preload():
    """The shipped rolled example: response x_P (m) from a displacement column in um; the
    pre-stress effect applies to the tube as an axial dead traction on its free end, whose
    consistent loads per unit stress sum to the end's area pi ((r + h)^2 - r^2) (six
    circumferential elements: within 1 %) and have no lateral part."""
    fwd, traces = fw.forward_from_experiment(load_experiment(EXAMPLES / "tube_diagnose.toml"))
    assert fwd.output == "x_P" and [t.role for t in traces] == ["fit", "fit", "holdout"]
    assert all(t.response == "displacement" for t in traces)
    assert 1e-5 < max(abs(traces[1].y)) < 1e-3  # tens of um, in m
    unit = np.asarray(fwd.pieces0.info["prestress_load"]).reshape(-1, 4, 3)
    area = np.pi * ((2e-3 + 2e-3) ** 2 - 2e-3 ** 2)
    assert abs(unit[:, 0, 0].sum() / area - 1.0) < 1e-2
    assert np.all(unit[:, 0, 1:] == 0.0)
    assert "prestress" in fx.names(fwd.pieces0) and "prestress" not in fx.names(fx.Pieces(None, None, fx.Sensor(), {}))



def test_piecewise_linear_histories_are_padded_to_the_forwards_length_with_the_same_values():
    """A trace of 4 steps padded to 10: its measured voltage (5 knots) gets 11, a slewed
    command (4 knots per step, 17) gets 41, another history the next power of two; the
    values on the trace are unchanged, the added knots hold the last value."""
    from dejax import loads

    t = np.linspace(0.0, 0.4, 5)
    v = np.array([0.0, 1.0, 3.0, 2.0, 5.0])
    fine = np.linspace(0.0, 0.4, 17)
    loading = it.Loading(voltages=(loads.PiecewiseLinear(t, v), loads.PiecewiseLinear(fine, fine ** 2),
                                   loads.PiecewiseLinear(np.arange(6.0), np.arange(6.0)), loads.Constant(2.0)))
    out = fw.pad_knots(loading, 4, 10)
    assert [h.times.shape[0] for h in out.voltages[:3]] == [11, 41, 8]
    assert isinstance(out.voltages[3], loads.Constant)
    tt = np.linspace(-0.1, 0.5, 61)
    for a, b in zip(loading.voltages, out.voltages):
        np.testing.assert_array_equal(np.asarray(a(tt)), np.asarray(b(tt)))
    assert fw.pad_knots(loading, 4, 4).voltages[0].times.shape[0] == 5  # nothing to pad


def test_baseline_slew_limited_and_preloaded_runs_share_one_compiled_simulation(caplog):
    """The commanded voltage always travels beside its slew-limited version
    (effects.SlewSwitch) and the start state is always given: the baseline, a slew-limited
    candidate and a pre-stressed one (its start state from a static pre-load, a program of its
    own) run one traced dynamic program (``jax_log_compiles`` names each tracing), and the switch leaves the
    baseline's command as it was (off) or gives the slewed one (on)."""
    import logging

    import jax
    import jax.numpy as jnp

    from fitting.traces import Trace

    fwd = fw.block_forward()
    t = np.linspace(0.0, 0.01, 11)  # one cycle of a 3 kV, 100 Hz sine: steepest rate 9.4e5 V/s
    tr = Trace(t, {"stretch": np.zeros_like(t)}, "fit", {"phi_max": 3e3, "freq": 100.0}, name="a",
               loading={"kind": "sine", "phi_max": 3e3, "freq": 100.0}, response="stretch")
    runs = ({}, {"amplifier_slew": {"rate": 2e5}}, {"prestress": {"s0": 200.0}})
    prev = jax.config.jax_log_compiles
    jax.config.update("jax_log_compiles", True)
    try:
        with caplog.at_level(logging.WARNING):
            outs = [fwd.raw(e, tr) for e in runs]
    finally:
        jax.config.update("jax_log_compiles", prev)
    traced = [r for r in caplog.records if "_simulate_jit" in r.getMessage() and "tracing" in r.getMessage().lower()]
    # one dynamic program for the three runs, one for the static pre-load (before: four)
    assert len(traced) <= 2, [r.getMessage() for r in traced]
    assert fwd.n_sims == 3 and all(np.all(np.isfinite(y)) for y in outs)
    assert np.max(np.abs(outs[1] - outs[0])) > 0 and np.max(np.abs(outs[2] - outs[0])) > 0
    # the switch: off, the command itself; on, the slew-limited history
    cmd = tr.voltage_history
    off = fw._command(fwd.pieces0.loading, tr)
    tt = jnp.linspace(0.0, 0.01, 41)
    np.testing.assert_array_equal(np.asarray(off(tt)), np.asarray(cmd(tt)))
    slewed = fx.apply_effects(fwd.pieces0, {"amplifier_slew": {"rate": 2e5}}).loading
    on = fw._command(slewed, tr)
    grid, v = fx.slew_limited(cmd, 2e5, tr.time)
    np.testing.assert_allclose(np.asarray(on(jnp.asarray(grid))), v, rtol=0, atol=1e-9)
    assert off.limited.times.shape == on.limited.times.shape
