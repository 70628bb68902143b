"""Tests of the independent reduced reference models (dejax.verification.models).

Every expected value here is computed independently of the code under test: closed
forms derived by hand (in the comments) and solved with scipy, or the numbers printed
in docs/paper-notes.md.
"""
import math
import re

import jax.numpy as jnp
import numpy as np
import pytest
from scipy import optimize

import dejax  # noqa: F401  (float64)
from dejax.verification import models as R

# Block parameters of docs/paper-notes.md (SI)
MU_INF, JM_INF, MU1, JM1, ETA1 = 67e3, 15.0, 67e3, 5.0, 3000.0
L, EPS = 1e-3, 4e-11


def gent_H(I1, Jm):
    return 1.0 - (I1 - 3.0) / Jm


# ---------------------------------------------------------------------------
# 1. Closed-form equal-biaxial Gent equilibrium
# ---------------------------------------------------------------------------


def test_closed_form_inverts():
    phi_max, lam_max = R.pullin_voltage(L, MU_INF, JM_INF, EPS)
    lam = np.concatenate([np.linspace(1.0, 1.0 + 0.98 * (lam_max - 1.0), 60), [1.0 + 1e-9, 1.001]])
    phi = R.gent_equibiaxial_voltage(lam, L, MU_INF, JM_INF, EPS)
    # voltage formula re-derived here: (lam^-2 - lam^-8)/H = eps/mu (phi/L)^2
    H = gent_H(2 * lam**2 + lam**-4, JM_INF)
    np.testing.assert_allclose(phi, L * np.sqrt(MU_INF / EPS * (lam**-2 - lam**-8) / H), rtol=1e-14)
    back = R.gent_equibiaxial_stretch(phi, L, MU_INF, JM_INF, EPS)
    assert np.max(np.abs(back - lam)) < 1e-12
    # scalar in, float out
    assert abs(R.gent_equibiaxial_stretch(float(phi[10]), L, MU_INF, JM_INF, EPS) - lam[10]) < 1e-12


def test_pullin_is_the_maximum_and_raises():
    phi_max, lam_max = R.pullin_voltage(L, MU_INF, JM_INF, EPS)
    # independent: brute-force maximum of the voltage formula on a fine grid
    lam = np.linspace(1.0 + 1e-6, 2.0, 400001)
    phi = L * np.sqrt(MU_INF / EPS * (lam**-2 - lam**-8) / gent_H(2 * lam**2 + lam**-4, JM_INF))
    k = int(np.argmax(phi))
    assert abs(lam_max - lam[k]) < 1e-5
    assert abs(phi_max / phi[k] - 1.0) < 1e-10
    assert phi_max >= phi[k]
    with pytest.raises(ValueError, match="pull-in") as info:
        R.gent_equibiaxial_stretch(1.001 * phi_max, L, MU_INF, JM_INF, EPS)
    msg = str(info.value)
    nums = [float(x) for x in re.findall(r"\d+\.\d+", msg)]
    assert any(abs(x / (1.001 * phi_max) - 1) < 1e-9 for x in nums), msg  # names the voltage
    assert any(abs(x / phi_max - 1) < 1e-9 for x in nums), msg  # and the pull-in voltage
    # a stiff Gent limit (Jm = 5) has no pull-in: phi(lam) grows up to the limit
    assert R.pullin_voltage(L, MU_INF, 5.0, EPS)[0] == math.inf
    big = 10 * phi_max
    lam5 = R.gent_equibiaxial_stretch(big, L, MU_INF, 5.0, EPS)
    assert abs(R.gent_equibiaxial_voltage(lam5, L, MU_INF, 5.0, EPS) / big - 1) < 1e-12


def test_small_strain_limit():
    # lam = 1 + e: lam^-2 - lam^-8 = 6 e - 33 e^2 + O(e^3), H = 1 - 12 e^2/Jm, so
    # e = e0 + 5.5 e0^2 + O(e0^3) with e0 = eps (phi/L)^2 / (6 mu_inf).
    # The leading order (rel -> 0) and the first correction (5.5 e0) are both checked; the
    # remainder is O(e0^2) (coefficient ~ 40).
    for e0 in (1e-5, 1e-4, 1e-3):
        phi = L * math.sqrt(6 * MU_INF * e0 / EPS)
        e = R.gent_equibiaxial_stretch(phi, L, MU_INF, JM_INF, EPS) - 1.0
        rel = e / e0 - 1.0
        assert abs(rel - 5.5 * e0) < 50 * e0**2 + 1e-9


def test_neo_hookean_pullin():
    # Jm -> inf: d/dlam (lam^-2 - lam^-8) = 0 -> lam^6 = 4, lam = 2^(1/3);
    # (lam^-2 - lam^-8) = 2^(-2/3) (1 - 1/4) -> phi_max = L sqrt(mu/eps) sqrt(3/4) 2^(-1/3)
    phi_max, lam_max = R.pullin_voltage(L, MU_INF, 1e6, EPS)
    assert abs(lam_max - 2 ** (1 / 3)) < 1e-6
    expect = L * math.sqrt(MU_INF / EPS) * math.sqrt(0.75) * 2 ** (-1 / 3)
    assert abs(phi_max / expect - 1.0) < 1e-6


# ---------------------------------------------------------------------------
# 2. Viscoelastic equal-biaxial block
# ---------------------------------------------------------------------------


def block(t, phi_m, eta=ETA1, Jm1=JM1, **kw):
    return R.homogeneous_block_response(t, R.eq41(phi_m), L, MU_INF, JM_INF, EPS, MU1, Jm1, eta, **kw)


def test_eq41_voltage():
    t = np.array([0.0, 0.25, 0.5, 1.0, 1.5, 3.0])
    np.testing.assert_allclose(
        np.asarray(R.eq41_voltage(t, 8e3)), 4e3 * (1 + np.sin(np.pi * np.minimum(t, 1) - np.pi / 2)), atol=1e-9
    )


def test_block_notes_numbers():
    # docs/paper-notes.md: independent scipy solution of the reduced model
    expected = {8e3: (1.006534, 1.006602), 12e3: (1.015411, 1.015593), 16e3: (1.029470, 1.029894)}
    for phi_m, (l1, l3) in expected.items():
        lam = block([1.0, 3.0], phi_m)
        assert abs(lam[0] - l1) < 5e-7 and abs(lam[1] - l3) < 5e-7, (phi_m, lam)
        assert np.round(lam, 6).tolist() == [l1, l3]
        # independent cross-check: after the 2 s hold (>> eta/(2 mu) = 22 ms) the unit is
        # relaxed and lam(3 s) is the closed-form Gent equilibrium of mu_inf alone
        relaxed = optimize.brentq(lambda l: MU_INF * (l**-2 - l**-8) / gent_H(2 * l * l + l**-4, JM_INF)
                                  - EPS * (phi_m / L) ** 2, 1.0, 1.2, xtol=1e-15, rtol=1e-15)
        assert abs(relaxed - l3) < 5e-7 and abs(lam[1] - relaxed) < 1e-9


def _frozen_lam(phi, Jm1):
    # Cv = I: both branches are Gent in the same I1 = 2 lam^2 + lam^-4
    N = lambda l: l**-2 - l**-8
    g = lambda l: (MU_INF * N(l) / gent_H(2 * l * l + l**-4, JM_INF) + MU1 * N(l) / gent_H(2 * l * l + l**-4, Jm1)
                   - EPS * (phi / L) ** 2)
    return 1.0 if phi == 0 else optimize.brentq(g, 1.0, 1.2, xtol=1e-15, rtol=1e-15)


def test_block_frozen_unit():
    # eta -> inf: xi stays 1 (Cv = I), the unit acts as a second elastic Gent branch
    t = np.array([0.25, 0.5, 1.0, 3.0])
    phi = 16e3 * 0.5 * (1 + np.sin(np.pi * np.minimum(t, 1) - np.pi / 2))
    lam = block(t, 16e3, eta=1e15)
    ref = np.array([_frozen_lam(p, JM1) for p in phi])
    assert np.max(np.abs(lam - ref)) < 1e-9
    # with Jm_1 = Jm_inf the frozen block is one Gent material of modulus mu_inf + mu_1
    lam = block(t, 16e3, eta=1e15, Jm1=JM_INF)
    ref = R.gent_equibiaxial_stretch(phi, L, MU_INF + MU1, JM_INF, EPS)
    assert np.max(np.abs(lam - ref)) < 1e-9


def test_block_relaxed_unit():
    # eta -> 0: xi = lam, the relaxed unit carries no stress (lam^-2 xi^-2 - lam^-8 xi^4 = 0),
    # so the block follows the closed-form Gent equilibrium of the equilibrium branch
    # (mu_inf) alone. tau = eta/(2 mu) = 1e-5 s against the 1 s ramp: the unit lags by
    # ~ tau dlam/dt < 5e-7 during the ramp and is fully relaxed during the hold.
    t = np.array([0.25, 0.5, 0.75, 1.0, 2.0, 3.0])
    phi = 16e3 * 0.5 * (1 + np.sin(np.pi * np.minimum(t, 1) - np.pi / 2))
    lam, xi = block(t, 16e3, eta=2 * MU1 * 1e-5, return_xi=True)
    ref = np.array([optimize.brentq(
        lambda l: MU_INF * (l**-2 - l**-8) / gent_H(2 * l * l + l**-4, JM_INF) - EPS * (p / L) ** 2, 1.0, 1.2,
        xtol=1e-15, rtol=1e-15) for p in phi])
    assert np.max(np.abs(lam - ref)) < 1e-6
    assert np.max(np.abs(lam[-2:] - ref[-2:])) < 1e-10  # fully relaxed during the hold
    assert np.max(np.abs(xi[:, 0] - lam)) < 1e-6
    # the paper notes' lam(3 s) = 1.029894 (16 kV) is this relaxed state (tau = 22 ms << 2 s hold)
    assert abs(lam[-1] - 1.029894) < 5e-7


def test_block_creep_time():
    # Small strain, voltage held (t > 1 s): 6 mu_inf e + 6 mu_1 (e - v) = eps E^2 and
    # dv/dt = (2 mu_1/eta)(e - v) give dv/dt = (v_inf - v)/tau_b with
    # tau_b = eta (mu_inf + mu_1)/(2 mu_1 mu_inf) = 44.8 ms (creep at fixed voltage), twice
    # the unit's stress-relaxation time eta/(2 mu_1) at fixed stretch.
    tau_b = ETA1 * (MU_INF + MU1) / (2 * MU1 * MU_INF)
    t = 1.0 + np.linspace(0.1, 0.3, 9)
    lam = block(t, 2e3)
    lam_eq = optimize.brentq(lambda l: MU_INF * (l**-2 - l**-8) / gent_H(2 * l * l + l**-4, JM_INF)
                             - EPS * (2e3 / L) ** 2, 1.0, 1.2, xtol=1e-15, rtol=1e-15)
    rate = -np.polyfit(t, np.log(lam_eq - lam), 1)[0]
    assert abs(rate * tau_b - 1.0) < 3e-3, rate * tau_b  # finite-strain correction ~ 3 e ~ 1e-3


def test_block_past_pullin_raises():
    # 35 kV exceeds the relaxed (mu_inf-only) pull-in voltage (~28.7 kV): as the unit relaxes
    # the equilibrium disappears; this must be reported, not returned as NaN
    phi_relaxed, _ = R.pullin_voltage(L, MU_INF, JM_INF, EPS)
    assert phi_relaxed < 35e3
    with pytest.raises(ValueError, match="pull-in"):
        block([0.5, 1.0, 3.0], 35e3)


def test_block_two_units_split():
    # two identical units with mu_1/2 each = one unit with mu_1 (N-unit generalisation)
    t = np.array([0.5, 1.0, 3.0])
    one = block(t, 12e3)
    two = R.homogeneous_block_response(t, R.eq41(12e3), L, MU_INF, JM_INF, EPS, [MU1 / 2, MU1 / 2], [JM1, JM1],
                                       [ETA1 / 2, ETA1 / 2])
    np.testing.assert_allclose(two, one, atol=1e-9)
    # no viscous unit: the closed form
    phi = 12e3 * 0.5 * (1 + np.sin(np.pi * np.minimum(t, 1) - np.pi / 2))
    zero = R.homogeneous_block_response(t, R.eq41(12e3), L, MU_INF, JM_INF, EPS, (), (), ())
    np.testing.assert_allclose(zero, R.gent_equibiaxial_stretch(phi, L, MU_INF, JM_INF, EPS), atol=1e-13)


def test_block_mullins_softening_against_the_hand_written_equilibrium():
    """No viscous unit, phi = 20 kV sin(pi t / 2) over t in [0, 2]: loading to 20 kV (t = 1) on
    the virgin curve, then unloading, where the Gent term is softened by eta = 1 - d erf((W1 -
    W)/m), W = -mu Jm/2 ln H the equal-biaxial Gent energy and W1 its value at the peak:
    lam(t) solves eta (lam^-2 - lam^-8)/H = eps (phi/L)^2 / mu, hand-written here for brentq.
    Off (d = 0) the same call gives the virgin curve on the way down as well."""
    d, m = 0.4, 300.0
    t = np.array([0.25, 0.5, 0.75, 1.0, 1.25, 1.5, 1.75])
    phi = 20e3 * np.sin(np.pi * t / 2)

    def W(lam):
        return -0.5 * MU_INF * JM_INF * np.log(gent_H(2 * lam**2 + lam**-4, JM_INF))

    def solve(p, eta=lambda lam: 1.0):
        return optimize.brentq(lambda l: eta(l) * MU_INF * (l**-2 - l**-8) / gent_H(2 * l * l + l**-4, JM_INF)
                               - EPS * (p / L) ** 2, 1.0, 1.2, xtol=1e-15, rtol=1e-15)

    lam1 = solve(20e3)
    soft = lambda lam: 1.0 - d * math.erf((W(lam1) - W(lam)) / m)  # noqa: E731
    ref = np.array([solve(p) if tt <= 1.0 else solve(p, soft) for p, tt in zip(phi, t)])
    virgin = np.array([solve(p) for p in phi])
    phi_fn = lambda tt: 20e3 * jnp.sin(jnp.pi * tt / 2)  # noqa: E731
    lam = R.homogeneous_block_response(t, phi_fn, L, MU_INF, JM_INF, EPS, (), (), (), mullins_d=d, mullins_m=m)
    off = R.homogeneous_block_response(t, phi_fn, L, MU_INF, JM_INF, EPS, (), (), ())
    assert W(lam1) > 3 * m  # the softening reaches most of d at phi = 0
    # lam_max is integrated (dlam_max/dt = dlam/dt while rising): it ends the loading 3e-8 short
    np.testing.assert_allclose(lam, ref, rtol=0, atol=3e-8)
    np.testing.assert_allclose(off, virgin, atol=1e-12)
    assert np.all(lam[4:] - virgin[4:] > 1e-4)  # softer on the way down: larger stretch


# ---------------------------------------------------------------------------
# 3. Uniaxial tension
# ---------------------------------------------------------------------------
# Incompressible uniaxial: lam, lam^-1/2, lam^-1/2; I1 = lam^2 + 2/lam; lateral faces free:
# P11 = dW/dlam = mu (lam - lam^-2)/H. A unit with Cv = I adds mu_1 (lam - lam^-2)/H_1(I1).


def gent_uniaxial(lam, mu, Jm):
    return mu * (lam - lam**-2) / gent_H(lam**2 + 2 / lam, Jm)


def test_uniaxial_slow_is_equilibrium():
    # tau = eta/(2 mu) = 1.5e-7 s, C^1 ramp to 1.5 over 1 s: unit stress ~ 3 mu tau dlam/dt < 0.03 Pa
    t = np.array([0.25, 0.5, 0.75, 1.0, 1.5, 2.0])
    P = R.homogeneous_uniaxial_response(t, R.ramp_hold(1.5, 1.0, smooth=True), MU_INF, JM_INF, MU1, JM1, 0.02)
    lam = 1 + 0.5 * 0.5 * (1 - np.cos(np.pi * np.minimum(t, 1)))
    np.testing.assert_allclose(P, gent_uniaxial(lam, MU_INF, JM_INF), rtol=1e-5)
    np.testing.assert_allclose(P[-2:], gent_uniaxial(lam[-2:], MU_INF, JM_INF), rtol=1e-12)


def test_uniaxial_fast_is_instantaneous():
    # ramp to 1.5 in 1 ns << tau = 22 ms: Cv = I, equilibrium + unit stress
    t = np.array([0.5e-9, 1e-9])
    P = R.homogeneous_uniaxial_response(t, R.ramp_hold(1.5, 1e-9), MU_INF, JM_INF, MU1, JM1, ETA1)
    lam = np.array([1.25, 1.5])
    np.testing.assert_allclose(P, gent_uniaxial(lam, MU_INF, JM_INF) + gent_uniaxial(lam, MU1, JM1), rtol=1e-6)


def test_uniaxial_relaxation_time():
    # Linearised flow rule: da/dt = (2 mu/eta)(lam - a), so a held stretch relaxes with
    # tau = eta/(2 mu) (half of eta/mu). P(t) = P_eq + (P_0 - P_eq) exp(-t/tau).
    lam0 = 1.001
    tau = ETA1 / (2 * MU1)
    t = np.concatenate([np.linspace(0.0, 4 * tau, 9), [40 * tau]])
    P = R.homogeneous_uniaxial_response(t, R.ramp_hold(lam0, 0.0), MU_INF, JM_INF, MU1, JM1, ETA1)
    P_eq = gent_uniaxial(lam0, MU_INF, JM_INF)
    P_0 = P_eq + gent_uniaxial(lam0, MU1, JM1)
    assert abs(P[0] / P_0 - 1) < 1e-12
    assert abs(P[-1] / P_eq - 1) < 1e-7
    rate = -np.polyfit(t[:-1], np.log(P[:-1] - P_eq), 1)[0]
    assert abs(rate * tau - 1.0) < 1e-3, rate * tau  # finite-strain correction ~ 2e-4 at 0.1 %
    assert abs(rate * ETA1 / MU1 - 1.0) > 0.9  # i.e. not the Maxwell-dashpot value eta/mu
    assert abs(R.relaxation_time(MU1, ETA1) - tau) < 1e-15


def test_uniaxial_voltage_elastic():
    # No viscous unit, lam = 1 held, voltage phi across direction 3 (thickness h):
    # l2 = s, l3 = 1/s, I1 = 1 + s^2 + s^-2, W = -mu Jm/2 ln H - eps/2 E^2 s^2.
    # dW/ds = 0: mu (s - s^-3)/H = eps E^2 s;  P11 = dW/dlam = mu (1 - s^-2)/H - eps E^2 s^2.
    h, phi = 1e-3, 12e3
    E2 = (phi / h) ** 2
    H = lambda s: gent_H(1 + s * s + s**-2, JM_INF)
    s = optimize.brentq(lambda s: MU_INF * (s - s**-3) / H(s) - EPS * E2 * s, 1.0, 1.5, xtol=1e-15, rtol=1e-15)
    P_ref = MU_INF * (1 - s**-2) / H(s) - EPS * E2 * s * s
    P, (l2, _) = R.homogeneous_uniaxial_response(
        [0.5, 2.0], R.ramp_hold(1.0, 0.0), MU_INF, JM_INF, (), (), (), eps=EPS, phi_fn=R.eq41(phi), thickness=h,
        return_state=True,
    )
    assert abs(l2[1] - s) < 1e-12
    assert abs(P[1] - P_ref) < 1e-9 * MU_INF
    assert P[1] < 0  # the voltage relieves the axial stress


def test_uniaxial_voltage_viscous():
    # viscous path with a voltage: (a) zero voltage reproduces the lam2 = lam3 model;
    # (b) frozen unit (eta huge) = elastic two-branch closed form with Cv = I.
    t = np.array([0.25, 1.0, 2.0])
    lam_fn = R.ramp_hold(1.3, 1.0, smooth=True)
    P_mech = R.homogeneous_uniaxial_response(t, lam_fn, MU_INF, JM_INF, MU1, JM1, ETA1)
    P_v0 = R.homogeneous_uniaxial_response(t, lam_fn, MU_INF, JM_INF, MU1, JM1, ETA1, eps=EPS,
                                           phi_fn=R.eq41(0.0), thickness=L)
    np.testing.assert_allclose(P_v0, P_mech, rtol=1e-8)

    h, phi = 1e-3, 10e3
    E2 = (phi / h) ** 2
    lam = 1.3
    # lam held, l2 = s, l3 = 1/(lam s): I1 = lam^2 + s^2 + lam^-2 s^-2
    H = lambda s, Jm: gent_H(lam**2 + s * s + (lam * s) ** -2, Jm)
    dI_ds = lambda s: 2 * s - 2 * lam**-2 * s**-3
    dI_dl = lambda s: 2 * lam - 2 * lam**-3 * s**-2
    G = lambda s: MU_INF / (2 * H(s, JM_INF)) + MU1 / (2 * H(s, JM1))
    s = optimize.brentq(lambda s: G(s) * dI_ds(s) - EPS * E2 * lam**2 * s, 0.5, 1.5, xtol=1e-15, rtol=1e-15)
    P_ref = G(s) * dI_dl(s) - EPS * E2 * lam * s * s
    P, (l2, _) = R.homogeneous_uniaxial_response(
        [1.5, 2.0], lam_fn, MU_INF, JM_INF, MU1, JM1, 1e18, eps=EPS, phi_fn=R.eq41(phi), thickness=h,
        return_state=True,
    )
    assert abs(l2[-1] - s) < 1e-9
    assert abs(P[-1] - P_ref) < 1e-8 * MU_INF


def test_block_output_grid_with_a_remainder_at_an_output_time():
    """3 Hz sine on 121 outputs over 1 s: a step clipped to an output time left a round-off
    remainder below the former dtmin (1e-13 of the span) and the solve failed at t = 0.508 s;
    a finer grid (241 outputs) gives the same stretch at the common times."""
    import jax.numpy as jnp

    phi = lambda s: 6e3 * (1 - jnp.cos(2 * np.pi * 3.0 * s))  # noqa: E731
    args = (1e-3, 67e3, 15.0, 4e-11, [67e3], [5.0], [3000.0])
    a = R.homogeneous_block_response(np.linspace(0, 1.0, 121), phi, *args)
    b = R.homogeneous_block_response(np.linspace(0, 1.0, 241), phi, *args)
    np.testing.assert_allclose(a, b[::2], rtol=1e-9)
