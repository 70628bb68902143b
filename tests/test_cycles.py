"""Cycle measures against closed forms for drifting sinusoids.

Reference signal: x(t) = a + b sin(w t - delta) + c t, w = 2 pi f, v = V sin(w t).
Per-cycle extrema of x follow from dx/dt = 0: cos(w t - delta) = -c / (b w).
"""
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from dejax import cycles as F

A, B, C, DELTA, FREQ = 0.2, 1.3, 0.4, 0.3, 30.0
W = 2 * np.pi * FREQ
T = 1 / FREQ


def signal(t, a=A, b=B, c=C, delta=DELTA):
    return a + b * np.sin(W * t - delta) + c * t


def grid(n_cycles=6, per_cycle=400.0):  # one shared shape keeps jit recompilation low
    """Samples covering n_cycles whole cycles, endpoint included; per_cycle may
    be non-integer (samples then do not align with cycle boundaries)."""
    dt = T / per_cycle
    n = int(np.floor(n_cycles * T / dt + 1e-9))
    t = np.arange(n + 1) * dt
    if t[-1] < n_cycles * T - 1e-12:
        t = np.append(t, n_cycles * T)
    return t


def analytic_extrema(n_cycles, a=A, b=B, c=C, delta=DELTA):
    """Exact per-cycle max and min of signal() on [k T, (k + 1) T)."""
    psi = np.arccos(-c / (b * W))  # in (0, pi): sin(psi) > 0 -> maximum; -psi -> minimum

    def in_window(phase, k):
        # times where W t - delta = phase + 2 pi j, within cycle k
        j = np.arange(-2, n_cycles + 3)
        tt = (phase + delta + 2 * np.pi * j) / W
        sel = tt[(tt >= k * T) & (tt < (k + 1) * T)]
        assert sel.size == 1
        return sel[0]

    hi, lo, t_hi, t_lo = [], [], [], []
    for k in range(n_cycles):
        th, tl = in_window(psi, k), in_window(-psi, k)
        hi.append(signal(th, a, b, c, delta))
        lo.append(signal(tl, a, b, c, delta))
        t_hi.append(th)
        t_lo.append(tl)
        # the interior critical points are the window's extrema (not its ends)
        ends = signal(np.array([k * T, (k + 1) * T]), a, b, c, delta)
        assert hi[-1] > ends.max() and lo[-1] < ends.min()
    return np.array(hi), np.array(lo), np.array(t_hi), np.array(t_lo)


@pytest.mark.parametrize("per_cycle", [400.0, 333.3])
def test_extrema_mean_per_cycle(per_cycle):
    t = grid(6, per_cycle)
    x = signal(t)
    hi, lo, _, _ = analytic_extrema(6)
    # sampled extrema are low by at most b (w dt)^2 / 8 plus the drift over dt/2
    tol = B * (2 * np.pi / per_cycle) ** 2 / 8 + C * T / per_cycle
    got_hi = np.asarray(F.x_max(t, x, FREQ))
    got_lo = np.asarray(F.x_min(t, x, T=T))
    assert got_hi.shape == (6,) and got_lo.shape == (6,)
    np.testing.assert_allclose(got_hi, hi, atol=tol)
    np.testing.assert_allclose(got_lo, lo, atol=tol)
    assert np.all(got_hi <= hi + 1e-12) and np.all(got_lo >= lo - 1e-12)
    np.testing.assert_allclose(np.asarray(F.mean(t, x, FREQ)), 0.5 * (hi + lo), atol=tol)
    np.testing.assert_allclose(np.asarray(F.amplitude(t, x, FREQ)), 0.5 * (hi - lo), atol=tol)


def test_kc_linear_drift():
    t = grid(6)
    x = signal(t)
    hi, lo, t_hi, t_lo = analytic_extrema(6)
    xbar = 0.5 * (hi + lo)
    # closed form: the sine parts cancel in the mean, leaving the drift at the
    # midpoint of the two extremum times: xbar_k = a + c (t_hi + t_lo) / 2
    np.testing.assert_allclose(xbar, A + C * 0.5 * (t_hi + t_lo), rtol=1e-12)
    expected = xbar / xbar[1]
    got = np.asarray(F.k_c(t, x, FREQ))
    assert got[1] == pytest.approx(1.0, abs=1e-14)
    np.testing.assert_allclose(got, expected, atol=2e-4)
    # the mean grows by c T per cycle
    np.testing.assert_allclose(np.diff(np.asarray(F.mean(t, x, FREQ))), C * T, rtol=1e-2)


def test_kc_needs_two_cycles():
    t = grid(1)
    with pytest.raises(ValueError, match="at least 2 whole cycle"):
        F.k_c(t, signal(t), FREQ)


@pytest.mark.parametrize("per_cycle", [400.0, 333.3])
def test_phase_lag_and_harmonics_of_drifting_sine(per_cycle):
    t = grid(6, per_cycle)
    x = signal(t)
    v = np.sin(W * t)
    assert float(F.phase_lag(t, x, v, FREQ)) == pytest.approx(DELTA, abs=1e-9)
    h = np.asarray(F.harmonics(t, x, FREQ, 4))
    np.testing.assert_allclose(h, [B, 0, 0, 0], atol=1e-9)
    # negative lag (x leads v) and a voltage with an offset
    x2 = signal(t, delta=-0.7)
    v2 = 3.0 + 2.0 * np.sin(W * t)
    assert float(F.phase_lag(t, x2, v2, FREQ)) == pytest.approx(-0.7, abs=1e-9)


def test_harmonics_of_distorted_signal():
    t = grid(6, 400.0)
    x = 0.5 + np.sin(W * t) + 0.2 * np.sin(2 * W * t + 0.1) + 0.05 * np.cos(3 * W * t)
    np.testing.assert_allclose(np.asarray(F.harmonics(t, x, FREQ, 4, detrend=False)), [1, 0.2, 0.05, 0],
                               atol=1e-10)
    a, b = F.fourier(t, x, FREQ, 3)
    np.testing.assert_allclose(np.asarray(a), [0, 0.2 * np.sin(0.1), 0.05], atol=1e-10)
    np.testing.assert_allclose(np.asarray(b), [1, 0.2 * np.cos(0.1), 0], atol=1e-10)


def test_detrend_matters_for_drift():
    t = grid(6, 400.0)
    x = signal(t)
    with_trend = float(F.harmonics(t, x, FREQ, 1)[0])
    without = float(F.harmonics(t, x, FREQ, 1, detrend=False)[0])
    assert with_trend == pytest.approx(B, abs=1e-9)
    assert abs(without - B) > 1e-3  # a ramp leaks into the fundamental


@pytest.mark.parametrize("delta", [0.3, 1.1, -0.5])
def test_loop_area_is_ellipse_area(delta):
    per_cycle = 400
    t = grid(6, per_cycle)
    x = signal(t, c=0.0, delta=delta)
    V = 2.5
    v = V * np.sin(W * t)
    area = np.asarray(F.loop_area(x, v, t, FREQ))
    expected = np.pi * B * V * np.sin(delta)
    assert area.shape == (6,)
    np.testing.assert_allclose(area, expected, rtol=1e-4)
    # one closed loop from one cycle of samples (no endpoint), no t
    one = float(F.loop_area(x[:per_cycle], v[:per_cycle]))
    assert one == pytest.approx(expected, rel=1e-4)


def test_cycle_assignment_with_offset_t0_and_incomplete_tail():
    t = np.linspace(0.0, 3.5 * T, 3501)
    x = np.sin(W * t)
    c = F.cycles(t, FREQ, t0=0.25 * T)
    assert c.n == 3  # [0.25T, 3.25T]; the rest is an incomplete cycle
    assert np.all(c.ids[t < 0.25 * T - 1e-12] == 3)
    # each window holds a full period: max 1, min -1
    np.testing.assert_allclose(np.asarray(F.x_max(t, x, FREQ, t0=0.25 * T)), 1.0, atol=1e-5)
    np.testing.assert_allclose(np.asarray(F.x_min(t, x, FREQ, n_cycles=2)), -1.0, atol=1e-5)
    with pytest.raises(ValueError, match="exactly one of f"):
        F.x_max(t, x)
    with pytest.raises(ValueError, match="increase strictly"):
        F.x_max(t[::-1], x, FREQ)


def test_soft_extrema_close_and_smooth():
    t = grid(6, 400.0)
    x = signal(t)
    hard = np.asarray(F.x_max(t, x, FREQ))
    soft = np.asarray(F.x_max(t, x, FREQ, soft=True))
    span = x.max() - x.min()
    # Boltzmann mean: below the max, within about temperature / 2 (temperature = 1e-2 span)
    assert np.all(soft < hard)
    np.testing.assert_allclose(soft, hard, atol=1e-2 * span)
    cold = np.asarray(F.x_max(t, x, FREQ, soft=True, temperature=1e-6))
    np.testing.assert_allclose(cold, hard, atol=1e-5)
    soft_min = np.asarray(F.x_min(t, x, FREQ, soft=True))
    assert np.all(soft_min > np.asarray(F.x_min(t, x, FREQ)))


def test_gradients_match_finite_differences():
    t = grid(6, 400.0)
    s = np.sin(W * t - DELTA)
    v = np.sin(W * t)

    def measures(p):
        amp, drift = p
        x = A + amp * s + drift * t
        out = []
        for soft in (False, True):
            kc = F.k_c(t, x, FREQ, soft=soft, temperature=0.02 if soft else None)
            out += [kc[-1], F.x_min(t, x, FREQ, soft=soft)[2]]
        out += [F.phase_lag(t, x, v, FREQ), F.loop_area(x, v, t, FREQ)[0], F.harmonics(t, x, FREQ, 2)[0]]
        return jnp.stack(out)

    p0 = np.array([B, C])
    J = np.asarray(jax.jit(jax.jacrev(measures))(p0))  # reverse mode, as a fit uses
    m = jax.jit(measures)
    h = 1e-6
    e = np.eye(2) * h
    fd = np.stack([(np.asarray(m(p0 + e[i])) - np.asarray(m(p0 - e[i]))) / (2 * h) for i in range(2)], axis=1)
    assert np.all(np.isfinite(J))
    np.testing.assert_allclose(J, fd, rtol=1e-5, atol=1e-7)


def test_cycle_features_dict():
    t = grid(6, 400.0)
    x = signal(t)
    v = np.sin(W * t)
    out = F.cycle_features(t, x, v, FREQ, n_harmonics=2)
    assert out["n_cycles"] == 6 and out["period"] == pytest.approx(T)
    for key in ("x_max", "x_min", "mean", "amplitude", "k_c", "loop_area"):
        assert out[key].shape == (6,), key
    assert out["harmonics"].shape == (2,) and out["v_harmonics"].shape == (2,)
    assert float(out["phase_lag"]) == pytest.approx(DELTA, abs=1e-9)
    np.testing.assert_allclose(np.asarray(out["x_max"]), np.asarray(F.x_max(t, x, FREQ)))
    no_v = F.cycle_features(t, x, f=FREQ)
    assert "loop_area" not in no_v and "phase_lag" not in no_v


def test_traced_time_is_rejected_clearly():
    t = grid(2, 50.0)
    with pytest.raises(TypeError, match="concrete"):
        jax.jit(lambda tt: F.x_max(tt, jnp.sin(W * tt), FREQ))(t)


def test_trace_cycle_measures_closed_form():
    f, d = 2.0, 0.3
    t = np.linspace(0, 3 / f, 241)
    u = np.sin(2 * np.pi * f * t)  # command
    y = 0.5 + 0.2 * np.sin(2 * np.pi * f * t - d)
    M = F.trace_cycle_measures(t, y, u, f)
    assert len(M["mean"]) == 3
    np.testing.assert_allclose(M["mean"], 0.5, atol=1e-9)
    np.testing.assert_allclose(M["amplitude"], 0.2, atol=1e-9)
    np.testing.assert_allclose(M["phase_lag"], d, atol=1e-9)
    np.testing.assert_allclose(M["h2"], 0.0, atol=1e-9)
    # closed integral of y du over an ellipse: pi A_u A_y sin(d) (clockwise in (u, y) => sign)
    np.testing.assert_allclose(np.abs(M["loop_area"]), math.pi * 1.0 * 0.2 * math.sin(d), rtol=2e-3)
    # the closing sample joins the last cycle; no frequency: one cycle, no measures
    ids = F.trace_cycle_ids(t, f)
    assert ids[0] == 0 and ids[-1] == 2 and np.sum(ids == 2) == 81
    assert F.trace_cycle_measures(t, y, u, None)["mean"].size == 0
