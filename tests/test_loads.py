"""Voltage histories (dejax.loads) against their closed forms, and ``from_spec``."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from dejax import loads

T = np.linspace(0.0, 2.0, 81)


def test_sine_is_eq42_by_default_and_takes_a_phase_and_offset():
    f, phi = 3.0, 10e3
    np.testing.assert_allclose(loads.Sine(phi, f)(T), 0.5 * phi * (1 - np.cos(2 * np.pi * f * T)), atol=1e-9)
    assert float(loads.Sine(phi, f)(0.0)) == pytest.approx(0.0, abs=1e-9)
    h = loads.Sine(2.0, f, phase=0.0, offset=-1.0)  # sin(w t)
    np.testing.assert_allclose(h(T), np.sin(2 * np.pi * f * T), atol=1e-12)
    # differentiable in its parameters: d phi / d offset = 1, d phi / d phi_m = (1 + sin)/2
    g = jax.grad(lambda o: loads.Sine(2.0, f, 0.3, o)(0.1))(0.5)
    assert float(g) == pytest.approx(1.0)


def test_ramp_hold_constant_piecewise():
    r = loads.RampHold(8e3, 1.0)
    np.testing.assert_allclose(r(np.array([0.0, 0.5, 1.0, 2.0])), [0.0, 4e3, 8e3, 8e3], atol=1e-9)
    np.testing.assert_allclose(loads.Constant(5.0)(T), 5.0)
    p = loads.PiecewiseLinear([0.0, 1.0], [0.0, 10.0])
    np.testing.assert_allclose(p(np.array([-1.0, 0.5, 2.0])), [0.0, 5.0, 10.0])
    with pytest.raises(ValueError, match="strictly increasing"):
        loads.PiecewiseLinear([0.0, 0.0], [1.0, 2.0])


@pytest.mark.parametrize("spec, expected", [
    ({"kind": "sine", "phi_max": 2.0, "freq": 3.0, "phase": 0.0, "offset": -1.0}, lambda t: np.sin(6 * np.pi * t)),
    ({"kind": "sine", "phi_max": 4.0, "freq": 1.0}, lambda t: 2.0 * (1 - np.cos(2 * np.pi * t))),
    ({"kind": "ramp_hold", "phi_max": 8e3}, lambda t: np.where(t <= 1, 4e3 * (1 - np.cos(np.pi * t)), 8e3)),
    ({"kind": "constant", "phi": 7.0}, lambda t: np.full_like(t, 7.0)),
    ({"kind": "piecewise", "times": [0.0, 2.0], "values": [1.0, 3.0]}, lambda t: 1.0 + t),
])
def test_from_spec(spec, expected):
    np.testing.assert_allclose(loads.from_spec(spec)(jnp.asarray(T)), expected(T), atol=1e-9)


def test_from_spec_rejects_an_unknown_kind():
    with pytest.raises(ValueError, match="unknown loading kind 'square'; known: sine, ramp_hold, constant, piecewise"):
        loads.from_spec({"kind": "square"})


def test_sample_stacks_histories():
    out = loads.sample((loads.Constant(1.0), loads.RampHold(2.0, 1.0)), T)
    assert out.shape == (T.size, 2)
    assert loads.sample((), T).shape == (T.size, 0)


def test_read_csv_is_piecewise_linear_through_the_rows(tmp_path):
    p = tmp_path / "v.csv"
    p.write_text("time_s,voltage_V\n0,0\n0.01,1000\n0.03,-500\n")
    h = loads.read_csv(p)
    np.testing.assert_allclose(np.asarray(h(jnp.array([0.0, 0.005, 0.02, 0.05]))), [0.0, 500.0, 250.0, -500.0])


@pytest.mark.parametrize("text, message", [
    ("time_s,voltage_V\n0,0\n0.01,abc\n", "row 3, column 2 ('voltage_V'): 'abc' is not a number"),
    ("time_s,voltage_V\n0,0\n0.02,1\n0.01,2\n", "row 4, column 1: time 0.01 s does not increase"),
    ("time_s,voltage_V\n0,0\n0.01\n", "row 3: 1 column(s)"),
    ("time_s,voltage_V\n0,nan\n0.01,1\n", "row 2, column 2 ('voltage_V'): 'nan' is not finite"),
    ("time_s,voltage_V\n0,0\n", "1 data row(s)"),
    ("", "empty file"),
])
def test_read_csv_names_file_row_and_column(tmp_path, text, message):
    p = tmp_path / "v.csv"
    p.write_text(text)
    with pytest.raises(ValueError) as e:
        loads.read_csv(p)
    assert str(p) in str(e.value) and message in str(e.value)


def test_read_csv_missing_file(tmp_path):
    with pytest.raises(ValueError, match="not found"):
        loads.read_csv(tmp_path / "nope.csv")


def test_evaluate_outside_jit_matches_the_closed_form():
    """loads.evaluate (one compiled program per history and grid length) on a sine and a
    piecewise-linear history, against their closed forms in numpy."""
    t = np.linspace(0.0, 0.3, 7)
    sine = loads.evaluate(loads.Sine(12e3, 5.0), t)
    np.testing.assert_allclose(sine, 0.5 * 12e3 * (1.0 + np.sin(2 * np.pi * 5.0 * t + 1.5 * np.pi)), rtol=1e-14,
                               atol=1e-9)
    pw = loads.evaluate(loads.PiecewiseLinear([0.0, 0.2], [0.0, 4.0]), t)
    np.testing.assert_allclose(pw, np.minimum(t, 0.2) * 20.0, rtol=1e-14, atol=1e-14)
