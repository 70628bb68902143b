"""fitting.effects: closed-form checks of the voltage filters, sensor transform and leaf edits."""
import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from dejax import integrate as it
from dejax import loads
from dejax import scenarios as sc
from fitting import effects as fx


def _sine_lowpass_exact(A, w, tau, t):
    # low-pass (zero state) of A/2 (1 - cos w t)
    cos_resp = (np.cos(w * t) + w * tau * np.sin(w * t) - np.exp(-t / tau)) / (1 + (w * tau) ** 2)
    return 0.5 * A * (1 - np.exp(-t / tau)) - 0.5 * A * cos_resp


@pytest.mark.parametrize("tau", [0.003, 0.02, 0.5, 3.0])
def test_lowpass_matches_closed_form(tau):
    A, f = 14e3, 2.0
    h = loads.Sine(A, f)
    t = np.linspace(0.0, 1.5, 61)
    y = np.asarray(fx.lowpass(h, tau, jnp.asarray(t)))
    exact = _sine_lowpass_exact(A, 2 * np.pi * f, tau, t)
    assert np.max(np.abs(y - exact)) < 1e-4 * A


def test_lowpass_off_is_identity():
    h = loads.Sine(10e3, 3.0)
    t = jnp.linspace(0.0, 1.0, 11)
    np.testing.assert_allclose(fx.lowpass(h, 0.0, t), h(t), rtol=0, atol=1e-9)


def test_leakage_constant_voltage_decay():
    # constant command: phi_eff = phi (1 - frac (1 - exp(-t/tau)))
    ev = fx.EffectiveVoltage(loads.Constant(5e3), lag=0.0, frac=0.3, tau_leak=0.7)
    t = np.array([0.1, 0.5, 1.0, 3.0, 10.0])
    expect = 5e3 * (1 - 0.3 * (1 - np.exp(-t / 0.7)))
    np.testing.assert_allclose(np.asarray(ev(jnp.asarray(t))), expect, rtol=1e-6)


def test_sensor_transform():
    t = jnp.linspace(0.0, 1.0, 101)
    y = jnp.sin(2 * jnp.pi * t)
    s = fx.Sensor(delay=jnp.asarray(0.1), offset=jnp.asarray(0.5), drift=jnp.asarray(2.0))
    out = np.asarray(s(t, y))
    tt = np.asarray(t)
    expect = np.where(tt >= 0.1, np.sin(2 * np.pi * (tt - 0.1)), 0.0) + 0.5 + 2.0 * tt
    np.testing.assert_allclose(out, expect, atol=1e-3)  # linear interpolation on a 0.01 s grid


def _pieces():
    mat = fx.augment_material(sc.block_material())
    return fx.make_pieces(sc.block(material=mat, voltage=loads.Sine(12e3, 2.0)))


def test_augment_and_apply_leaves():
    p = _pieces()
    m = p.model.material
    assert m.n_units == 3 and float(m.mu[1]) == pytest.approx(67e3 * fx.DORMANT)
    q = fx.apply_effects(p, {"creep": {"mu": 1e4, "tau": 4.0}, "hysteresis": {"mu": 2e4, "tau": 0.02},
                             "electrostriction": {"eps_a": 0.1, "eps_b": -0.2}, "electrode_stiffness": {"rel": 0.25},
                             "added_mass": {"rel": 1.0}, "voltage_lag": {"tau": 0.01},
                             "leakage": {"frac": 0.2, "tau": 3.0}, "sensor_offset": {"c": 0.1}})
    mm = q.model.material
    assert float(mm.mu[1]) == pytest.approx(1e4) and float(mm.eta[1]) == pytest.approx(2 * 1e4 * 4.0)
    assert float(mm.mu[2]) == pytest.approx(2e4) and float(mm.eta[2]) == pytest.approx(2 * 2e4 * 0.02)
    assert float(mm.mu[0]) == pytest.approx(67e3)  # baseline unit untouched
    assert float(mm.eps_a) == pytest.approx(0.1) and float(mm.eps_b) == pytest.approx(-0.2)
    assert float(mm.mu_inf) == pytest.approx(67e3 * 1.25)
    np.testing.assert_allclose(q.model.mass_e, 2.0 * p.model.mass_e)
    v = q.loading.voltages[0]
    assert float(v.lag) == pytest.approx(0.01) and float(v.frac) == pytest.approx(0.2)
    assert float(q.sensor.offset) == pytest.approx(0.1)
    # same pytree structure as the baseline: compiled code is shared
    assert jax.tree_util.tree_structure(q.model) == jax.tree_util.tree_structure(p.model)
    assert jax.tree_util.tree_structure(q.loading) == jax.tree_util.tree_structure(p.loading)


def test_prestress_resultant():
    # body-force resultant on the x = 0 face = s0 * face area (L = 1 mm)
    p = _pieces()
    q = fx.apply_effects(p, {"prestress": {"s0": 1e4}})
    from dejax import model as mdl

    f = np.asarray(mdl.external_force(q.model)).reshape(-1, 4, 3)
    assert f[:, 0, 0].sum() == pytest.approx(1e4 * 1e-6, rel=1e-9)
    assert f[:, 0, 1].sum() == pytest.approx(1e4 * 1e-6, rel=1e-9)
    assert abs(f[:, 0, 2].sum()) < 1e-15


def test_prestretch_block_under_voltage_matches_the_closed_form():
    """A 1-element hyperelastic block pre-stretched equibiaxially by lam_p = 1.4 (``prestretch``:
    the equilibrium branch sees F diag(lam_p, lam_p, lam_p^-2), the frame's dead load holds it)
    under a voltage ramp to 14 kV, quasi-static: without voltage it stays in its reference
    configuration; at 14 kV its lateral stretch is the stationary point of Gent(lam lam_p) -
    eps/2 (phi/H)^2 lam^4 - 2 s0 lam on the incompressible equibiaxial path, with s0 = dGent/dlam / 2
    at lam = 1 (the frame's stress), written here by hand and solved by scipy."""
    from scipy import optimize

    mu, Jm, eps, H, phi, lp = 67e3, 15.0, 4e-11, 1e-3, 14e3, 1.4
    mat = sc.block_material(mu=[], K=[], Jm=[], eta=[])
    prob = sc.block(material=mat, voltage=loads.PiecewiseLinear([0.0, 0.1, 1.0], [0.0, 0.0, phi]))
    pieces = fx.make_pieces(dataclasses.replace(prob, model=eqx.tree_at(lambda m: m.material, prob.model,
                                                                        fx.augment_material(mat))))
    times = np.linspace(0.0, 1.0, 11)
    out = {}
    for lam in (1.0, lp):
        q = fx.apply_effects(pieces, {"prestretch": {"lam": lam}})
        sol = it.simulate(q.model, q.loading, times, prob.output_fn, it.QuasiStatic()).check()
        out[lam] = np.asarray(sol.outputs["lateral_stretch"])
    # no voltage yet: held where it is, to the compressibility (the frame stress ~1e5 Pa over K = 6.7 GPa)
    assert abs(out[lp][1] - 1.0) < 2e-5

    def gent(x):  # Gent energy of the equibiaxial stretch x from the natural state (incompressible)
        return -0.5 * mu * Jm * np.log(1.0 - (2.0 * x ** 2 + x ** -4 - 3.0) / Jm)

    d = lambda f, x, h=1e-6: (f(x + h) - f(x - h)) / (2.0 * h)  # noqa: E731
    s0 = 0.5 * d(lambda l: gent(l * lp), 1.0)
    ref = optimize.brentq(lambda l: d(lambda x: gent(x * lp) - 0.5 * eps * (phi / H) ** 2 * x ** 4 - 2 * s0 * x, l),
                          1.0, 1.5, xtol=1e-14)
    assert out[lp][-1] == pytest.approx(ref, rel=2e-5)
    # and larger than without the pre-stretch: the frame-held film is softer per unit relative
    # stretch (lam_p^2 Gent''(lam_p) = 0.74 Gent''(1) on this path, Gent''(1) = 12 mu)
    d2 = lambda f, x, h=1e-4: (f(x + h) - 2.0 * f(x) + f(x - h)) / h ** 2  # noqa: E731
    assert lp ** 2 * d2(gent, lp) < 0.8 * d2(gent, 1.0)
    assert out[lp][-1] > out[1.0][-1] > 1.0


def test_prestretch_is_isochoric_and_only_the_equilibrium_branch_sees_it():
    from dejax import material as mt

    with pytest.raises(ValueError, match="isochoric"):
        mt.Material(67e3, 6.7e9, 15.0, 4e-11, 1100.0, pre=(1.5, 1.5, 1.0)).validate()
    pre = fx.prestretch_of(1.3, "axial")
    assert float(jnp.prod(pre)) == pytest.approx(1.0, rel=1e-14)
    m0 = sc.block_material()
    m1 = eqx.tree_at(lambda m: m.pre, m0, pre)
    F = jnp.array([[1.1, 0.05, 0.0], [0.02, 0.95, 0.03], [0.0, 0.01, 0.97]])
    E = jnp.array([0.0, 2e6, 1e7])
    # the equilibrium branch at F diag(pre), the electrostatic term at F
    elec = mt.equilibrium_energy(F, E, m0) - mt.equilibrium_energy(F, jnp.zeros(3), m0)
    expect = mt.equilibrium_energy(F * pre[None, :], jnp.zeros(3), m0) + elec
    assert float(mt.equilibrium_energy(F, E, m1)) == pytest.approx(float(expect), rel=1e-13)
    # the viscous units do not see it
    Cv = jnp.broadcast_to(jnp.eye(3), (1, 3, 3))
    dv = lambda m: mt.free_energy(F, E, Cv, m) - mt.equilibrium_energy(F, E, m)  # noqa: E731
    assert float(dv(m1)) == pytest.approx(float(dv(m0)), rel=1e-13)


def test_names_and_errors():
    assert {"creep", "hysteresis", "voltage_lag", "leakage", "electrostriction", "electrode_stiffness",
            "added_mass", "prestress", "prestretch", "mullins", "sensor_offset", "sensor_drift",
            "sensor_latency"} <= set(fx.names())
    assert fx.get("mullins").n_params == 2 and not fx.UNAVAILABLE
    with pytest.raises(KeyError):
        fx.get("creeep")
    with pytest.raises(KeyError, match="no parameter"):
        fx.get("creep").values({"eta": 1.0})
    for e in fx.EFFECTS.values():
        for p in e.params:
            assert p.bounds[0] <= p.off <= p.bounds[1] and p.bounds[0] <= p.start <= p.bounds[1]


def test_normalized_parameters():
    """z in [0, 1] spans a parameter's bounds linearly or in log scale; values outside the
    bounds are clipped; values_at fills a point's effects, the off values elsewhere."""
    lin = fx.Param("c", 0.0, (-1.0, 1.0), 0.0)
    log = fx.Param("tau", 5.0, (0.5, 50.0), 5.0, "log")
    assert lin.z_of(0.0) == 0.5 and lin.from_z(0.75) == 0.5 and lin.dx_dz(0.3) == 2.0
    assert lin.z_of(3.0) == 1.0 and lin.from_z(-0.2) == -1.0  # clipped to the box
    assert log.z_of(5.0) == pytest.approx(0.5, rel=1e-14)  # the geometric middle of [0.5, 50]
    assert log.from_z(0.25) == pytest.approx(0.5 * 10 ** 0.5, rel=1e-14)
    assert log.dx_dz(5.0) == pytest.approx(5.0 * np.log(100.0), rel=1e-14)
    assert log.z_of(0.0) == 0.5  # no log of 0: the middle
    for z in (0.0, 0.3, 1.0):
        assert log.z_of(log.from_z(z)) == pytest.approx(z, abs=1e-14)
    assert [(n, p.name) for n, p in fx.param_list(["leakage", "sensor_offset"])] == [
        ("leakage", "frac"), ("leakage", "tau"), ("sensor_offset", "c")]
    v = fx.values_at(["leakage", "sensor_offset"], [0.5, 0.0, 1.0], fixed={"voltage_lag": {"tau": 0.01}})
    assert v["leakage"] == pytest.approx({"frac": 0.3, "tau": 0.05}, rel=1e-14)
    assert (v["sensor_offset"], v["voltage_lag"], len(v)) == ({"c": 1.0}, {"tau": 0.01}, 3)


def test_mu_drift_is_the_equivalent_field_scaling():
    """mu_drift: phi_eff = phi / sqrt(1 + rate t); and that is the moduli drift it stands for:
    the closed-form Gent equilibrium of the block with mu x s equals the one with phi / sqrt(s)."""
    from dejax.verification import models

    p = fx.apply_effects(_pieces(), {"mu_drift": {"rate": 0.02}})
    v = p.loading.voltages[0]
    t = jnp.array([0.0, 0.3, 1.7])
    base = loads.Sine(12e3, 2.0)
    np.testing.assert_allclose(np.asarray(v(t)), np.asarray(base(t)) / np.sqrt(1 + 0.02 * np.asarray(t)), rtol=1e-12)
    s = 1.3
    for phi in (6e3, 12e3):
        a = models.gent_equibiaxial_stretch(phi / np.sqrt(s), 1e-3, 67e3, 15.0, 4e-11)
        b = models.gent_equibiaxial_stretch(phi, 1e-3, 67e3 * s, 15.0, 4e-11)
        assert a == pytest.approx(b, rel=1e-10) and a > 1.0
    assert fx.get("mu_drift").off() == {"rate": 0.0}


def test_slew_limited_follows_the_command_up_to_the_rate():
    """A sine phi = A sin(w t) (steepest rate A w at t = 0) through an amplifier of slew rate
    S < A w, on the command at t = 0. Closed form over the first half period: a ramp S t
    until it meets the sine (t_m), the sine while its slope is within S, then from
    t3 = (pi - arccos(S / (A w))) / w a ramp down at S (still above the sine at the half
    period). And an amplifier faster than the command is the command."""
    from scipy.optimize import brentq

    A, f, S = 10e3, 50.0, 1.5e6  # V, Hz, V/s (A w = 3.14e6 V/s)
    w = 2 * np.pi * f
    t = np.linspace(0.0, 1.0 / (2 * f), 401)
    hist = lambda s: A * jnp.sin(w * s)  # noqa: E731
    grid, v = fx.slew_limited(hist, S, t, substeps=32, knots=1)
    np.testing.assert_array_equal(grid, t)
    t_m = brentq(lambda s: A * np.sin(w * s) - S * s, 1e-6, 0.5 / f)
    t3 = (np.pi - np.arccos(S / (A * w))) / w
    ref = np.where(t <= t_m, S * t, np.where(t <= t3, A * np.sin(w * t), A * np.sin(w * t3) - S * (t - t3)))
    assert np.max(np.abs(v - ref)) < S * (t[1] - t[0]) / 32
    assert np.max(np.abs(np.diff(v)) / np.diff(t)) <= S * (1 + 1e-12)
    grid, v_off = fx.slew_limited(hist, fx.SLEW_OFF, t)
    assert grid.size == 4 * (t.size - 1) + 1 and grid[4] == t[1]
    np.testing.assert_allclose(v_off, np.asarray(hist(jnp.asarray(grid))), rtol=0, atol=1e-12 * A)
    p = fx.get("amplifier_slew").params[0]
    assert not fx.slew_active(p.from_z(1.0)) and fx.slew_active(p.from_z(1.0 - 1e-3))


def test_amplifier_slew_is_screened_by_its_secant():
    """A threshold effect: no slope at off (the limit acts only below the command's rate), so
    the screening's column is the secant from off to the start value."""
    (p,) = fx.get("amplifier_slew").params
    assert p.probe and p.off == fx.SLEW_OFF and p.z_of(p.off) == 1.0 and p.start < p.off
