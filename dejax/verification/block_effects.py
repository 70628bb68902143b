r"""Synthetic "measured" traces of the DE block with effects the model lacks, made
independently of the finite-element forward code that ``dejax diagnose`` fits.

The response is the reduced homogeneous, incompressible block of ``models``
(``homogeneous_block_response``: an index-1 DAE integrated by diffrax), under the Eq. (42)
sine phi(t) = phi_m/2 (1 - cos 2 pi f t); each effect is realised here from its physics,
not from ``fitting.effects``:

==================== ===================================================================
creep, hysteresis    one more viscous Gent unit: mu, Jm = 5, eta = 2 mu tau
voltage_lag          first-order RC filter of the sine, in closed form:
                     y = c (1 - e^-t/tau) - c (cos wt + w tau sin wt - e^-t/tau)/(1 + (w tau)^2),
                     c = phi_m/2
leakage              the screened field: phi_lag - frac * (the same filter with tau_leak)
mu_drift             every modulus x s(t) = 1 + rate t (eta alike): the reduced equilibrium
                     divided by mu_inf s(t) is the one at phi / sqrt(s(t))
electrode_stiffness  mu_inf x (1 + rel)
prestress            an equal-biaxial dead nominal stress s0 on the lateral faces, applied at
                     t = 0 to the film at rest (the viscous units not yet relaxed)
prestretch           the equilibrium branch's natural state lam^-1 in plane (kinematic pre-stretch,
                     ``homogeneous_block_response(prestretch=...)``), held by the frame's dead
                     nominal stress mu_inf lam (lam - lam^-5) / H_inf(lam) on the lateral faces
electrostriction     eps_b: permittivity eps (1 + eps_b (lam_z - 1)) in the reduced
                     equilibrium (``homogeneous_block_response(eps_b=...)``)
mullins              d, m: the equilibrium branch's stress times 1 - d erf((W_max - W)/m), W its
                     equal-biaxial Gent energy, W_max = W at the largest stretch so far (a state
                     of the reduced model's ODE, ``homogeneous_block_response(mullins_d=...)``)
sensor_offset        y + c
sensor_drift         y + rate t
sensor_latency       y(t - delay) (the model evaluated at the delayed times; 1 before)
==================== ===================================================================

Not realised (so not in a validation's truth set): added_mass (the reduced model has no
inertia), the second-order eps_a, effects the library does not have.
"""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from . import models

__all__ = ["BLOCK", "REALISED", "block_response"]

# the paper's Sec. 4 block (scenarios.block_material, L = 1 mm)
BLOCK = dict(L=1e-3, mu_inf=67e3, Jm_inf=15.0, eps=4e-11, mu=[67e3], Jm=[5.0], eta=[3000.0])
REALISED = ("creep", "hysteresis", "voltage_lag", "leakage", "mu_drift", "electrode_stiffness", "prestress",
            "prestretch", "electrostriction", "mullins", "sensor_offset", "sensor_drift", "sensor_latency")


def _rc_sine(t, c, omega, tau):
    """Closed-form first-order low-pass (time constant tau, zero initial state) of
    c (1 - cos omega t); tau = 0 gives the input (differentiable in t there too)."""
    lag = tau > 0
    tau = jnp.where(lag, tau, 1.0)
    e = jnp.exp(-t / tau)
    wt = omega * tau
    filtered = c * (1.0 - e) - c * (jnp.cos(omega * t) + wt * jnp.sin(omega * t) - e) / (1.0 + wt**2)
    return jnp.where(lag, filtered, c - c * jnp.cos(omega * t))


def _phi_eff(c, omega, lag, frac, tau_leak, rate, t):
    """The film's voltage: the lagged sine less the screened part, at moduli drifted by 1 + rate t."""
    v = _rc_sine(t, c, omega, lag) - frac * _rc_sine(t, c, omega, tau_leak)
    return v / jnp.sqrt(1.0 + rate * t)


def _value(effects, name, key, off=0.0):
    return float(effects.get(name, {}).get(key, off))


def block_response(t, phi_max: float, freq: float, effects: dict | None = None, block: dict = BLOCK) -> np.ndarray:
    """Lateral stretch (t,) of the reduced block under the sine (phi_max V, freq Hz) with
    ``effects`` ({name: {param: value}}, parameter names and SI units as in
    ``fitting.effects``); {} gives the paper's model."""
    effects = dict(effects or {})
    unknown = set(effects) - set(REALISED)
    if unknown:
        raise ValueError(f"effects not realised by the reduced block: {sorted(unknown)}; realised: {REALISED}")
    t = np.asarray(t, dtype=float)
    c, omega = 0.5 * float(phi_max), 2.0 * np.pi * float(freq)
    # one compiled reference solve for every case: the history's numbers are array leaves
    phi_fn = jax.tree_util.Partial(_phi_eff, *(jnp.asarray(v, dtype=float) for v in (
        c, omega, _value(effects, "voltage_lag", "tau"), _value(effects, "leakage", "frac"),
        _value(effects, "leakage", "tau", 2.0), _value(effects, "mu_drift", "rate"))))

    mu, Jm, eta = list(block["mu"]), list(block["Jm"]), list(block["eta"])
    for name in ("creep", "hysteresis"):
        if name in effects and _value(effects, name, "mu") > 0:
            m = _value(effects, name, "mu")
            mu.append(m)
            Jm.append(5.0)
            eta.append(2.0 * m * _value(effects, name, "tau"))
    mu_inf = block["mu_inf"] * (1.0 + _value(effects, "electrode_stiffness", "rel"))
    delay = _value(effects, "sensor_latency", "delay")
    ts = np.maximum(t - delay, 0.0)
    order = np.argsort(ts, kind="stable")
    lam_p = _value(effects, "prestretch", "lam", 1.0)
    frame = mu_inf * lam_p * (lam_p - lam_p**-5) / (1.0 - (2.0 * lam_p**2 + lam_p**-4 - 3.0) / block["Jm_inf"])
    lam_sorted = models.homogeneous_block_response(
        ts[order], phi_fn, block["L"], mu_inf, block["Jm_inf"], block["eps"], mu, Jm, eta,
        eps_b=_value(effects, "electrostriction", "eps_b"), prestress=_value(effects, "prestress", "s0") + frame,
        prestretch=lam_p, mullins_d=_value(effects, "mullins", "d"), mullins_m=_value(effects, "mullins", "m", 1e4))
    lam = np.empty_like(lam_sorted)
    lam[order] = lam_sorted
    return lam + _value(effects, "sensor_offset", "c") + _value(effects, "sensor_drift", "rate") * (t - t[0])

