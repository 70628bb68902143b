"""dejax.verification.block_effects: the independent truth of the diagnosis validation.

Each realised effect is checked against a reference computed another way: the static
equilibria (electrostriction, pre-stress, pre-stretch, electrode stiffness) against the stationary point of
the block's total energy found numerically (scipy, finite differences of the energy, not the
hand-derived residual); the closed-form RC filter against scipy's ODE integration; the output
transforms and the moduli drift against their definitions."""
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import integrate, optimize

import dejax  # noqa: F401
from dejax.verification import block_effects as B
from dejax.verification import models as R

BLK = B.BLOCK


def _static_stretch(phi, mu_inf=BLK["mu_inf"], eps_b=0.0, s=0.0, lam_p=1.0):
    """Stationary point in lam of the hyperelastic block's potential per reference volume:
    Gent energy (of lam lam_p, the stretch from the natural state) - eps/2 (1 + eps_b (lam^-2 - 1))
    E^2 lam^4 - 2 s (lam - 1), E = phi/L, s plus the frame's stress holding lam = 1 without
    voltage when lam_p != 1 (derivatives by central differences of the energy)."""
    E = phi / BLK["L"]

    def gent(x):
        return -0.5 * mu_inf * BLK["Jm_inf"] * np.log(1 - (2 * x**2 + x**-4 - 3) / BLK["Jm_inf"])

    frame = (gent(lam_p * (1 + 1e-7)) - gent(lam_p * (1 - 1e-7))) / 4e-7 if lam_p != 1.0 else 0.0

    def pot(lam):
        elec = 0.5 * BLK["eps"] * (1 + eps_b * (lam**-2 - 1)) * E**2 * lam**4
        return gent(lam * lam_p) - elec - 2 * (s + frame) * (lam - 1)

    d = lambda lam: (pot(lam + 1e-7) - pot(lam - 1e-7)) / 2e-7  # noqa: E731
    return optimize.brentq(d, 1.0 - 1e-3, 1.3, xtol=1e-14)


@pytest.mark.parametrize("effects, kw", [
    ({"electrostriction": {"eps_b": -0.3}}, dict(eps_b=-0.3)),
    ({"prestress": {"s0": 20e3}}, dict(s=20e3)),
    ({"electrode_stiffness": {"rel": 0.4}}, dict(mu_inf=BLK["mu_inf"] * 1.4)),
    ({"prestretch": {"lam": 1.3}}, dict(lam_p=1.3)),
])
def test_static_effects_against_the_energy_stationary_point(effects, kw):
    # the block without its viscous unit, at the peak of a slow sine: hyperelastic equilibrium
    phi = 12e3
    t = np.array([0.0, 40.0])
    elastic = dict(BLK, mu=[], Jm=[], eta=[])
    lam = B.block_response(t, phi, 1.0 / 80.0, effects, block=elastic)  # half a period = 40 s: phi(40 s) = phi_max
    assert lam[-1] == pytest.approx(_static_stretch(phi, **kw), rel=1e-7)
    assert abs(lam[-1] - _static_stretch(phi)) > 1e-4  # the effect changes the stretch


def test_rc_filter_closed_form_against_ode():
    c, w, tau = 5e3, 2 * np.pi * 3.0, 0.02
    t = np.linspace(0.0, 1.0, 201)
    sol = integrate.solve_ivp(lambda s, y: (c * (1 - np.cos(w * s)) - y) / tau, (0, 1), [0.0], t_eval=t,
                              rtol=1e-11, atol=1e-9)
    np.testing.assert_allclose(np.asarray(B._rc_sine(t, c, w, tau)), sol.y[0], rtol=0, atol=1e-6 * c)


def test_output_transforms_and_drift():
    t = np.linspace(0.0, 1.0, 41)
    base = B.block_response(t, 12e3, 2.0, {})
    np.testing.assert_allclose(base, R.homogeneous_block_response(t, lambda s: 6e3 * (1 - jnp.cos(2 * np.pi * 2.0 * s)),
                                                                    BLK["L"], BLK["mu_inf"], BLK["Jm_inf"], BLK["eps"],
                                                                    BLK["mu"], BLK["Jm"], BLK["eta"]), rtol=1e-12)
    off = B.block_response(t, 12e3, 2.0, {"sensor_offset": {"c": 1e-3}, "sensor_drift": {"rate": 2e-3}})
    np.testing.assert_allclose(off, base + 1e-3 + 2e-3 * t, rtol=1e-12)
    late = B.block_response(t, 12e3, 2.0, {"sensor_latency": {"delay": 0.1}})
    np.testing.assert_allclose(late[t >= 0.1], B.block_response(t[t >= 0.1] - 0.1, 12e3, 2.0, {}), rtol=1e-10)
    assert np.all(late[t < 0.1] == 1.0)
    with pytest.raises(ValueError, match="added_mass"):
        B.block_response(t, 12e3, 2.0, {"added_mass": {"rel": 1.0}})


def test_extra_unit_slows_the_response():
    t = np.linspace(0.0, 1.0, 41)
    base = B.block_response(t, 12e3, 2.0, {})
    creep = B.block_response(t, 12e3, 2.0, {"creep": {"mu": 40e3, "tau": 3.0}})
    assert np.max(creep) < np.max(base)  # a stiff slow unit holds the film back within the cycles


def test_mullins_acts_below_the_largest_stretch_only():
    """Ogden-Roxburgh softening on the block: the first loading (up to the first peak, t = 0.25 s
    at 2 Hz) is the virgin response (eta = 1 on the primary path); from the first unloading on,
    the softened block stretches more than the virgin one at the same voltage, the more for the
    larger d."""
    t = np.linspace(0.0, 1.0, 81)
    base = B.block_response(t, 14e3, 2.0, {})
    soft = {d: B.block_response(t, 14e3, 2.0, {"mullins": {"d": d, "m": 150.0}}) for d in (0.25, 0.5)}
    first = t <= 0.25
    later = (t > 0.3) & (np.abs(np.sin(2 * np.pi * 2.0 * t)) > 0.2)  # away from the peaks and troughs
    for d, lam in soft.items():
        np.testing.assert_allclose(lam[first], base[first], rtol=0, atol=1e-9)
        assert np.all(lam[later] - base[later] > 1e-4)
    assert np.all(soft[0.5][later] > soft[0.25][later])
