"""Candidate unmodelled effects: small, switchable augmentations of a dejax forward model.

An effect has a name, a few parameters (each with bounds, an "off" value that leaves
the baseline unchanged, a start value for fitting and a scale) and an ``apply``
function ``(pieces, values) -> pieces`` acting on the forward-model pieces:

  ``Pieces(model, loading, sensor, info)``: the dejax ``Model`` (its ``material``,
  ``mass_e``, ``gravity`` leaves), the ``Loading`` (voltages wrapped in
  ``EffectiveVoltage``) and a ``Sensor`` output transform; ``info`` holds static
  data (slot indices of dormant viscous units, specimen size).

Compiled-code reuse: every effect only swaps leaves. ``augment_material`` adds two
*dormant* viscous units (shear modulus 1e-9 mu_inf, i.e. off) that the ``creep``
and ``hysteresis`` effects switch on, and every voltage history is wrapped in an
``EffectiveVoltage`` whose lag/leak are off by default; so the baseline and all
candidates share one pytree structure and one compiled ``simulate``.

Library (``EFFECTS``):

==================  ==========================================  =====================================
name                parameters (SI)                             realisation
==================  ==========================================  =====================================
creep               mu (Pa), tau (s) ~ 0.5-50 s                 extra slow Gent viscous unit
hysteresis          mu (Pa), tau (s) ~ 1e-3-0.5 s               extra fast Gent viscous unit
voltage_lag         tau (s)                                     first-order RC filter command->electrode
amplifier_slew      rate (V/s)                                  electrode voltage follows the command at
                                                                most at this rate (``slew_limited``)
leakage             frac (-), tau (s)                           field screening by leakage/space charge
mu_drift            rate (1/s)                                  moduli x (1 + rate t) (temperature drift)
electrostriction    eps_b (-), eps_a (-)                        eps(1 + eps_b(lambda_E - 1) + eps_a(I1bar - 3))
electrode_stiffness rel (-)                                     mu_inf -> mu_inf (1 + rel)
added_mass          rel (-)                                     mass matrix -> (1 + rel) M
prestress           s0 (Pa)                                     dead traction s0 on the free faces
                                                                (block: lateral, tube: axial end)
mullins             d (-), m (Pa)                               Ogden-Roxburgh softening of the
                                                                equilibrium branch (Material.mullins_*,
                                                                history wmax per Gauss point)
prestretch          lam (-)                                     kinematic pre-stretch (Material.pre) of
                                                                the equilibrium branch, held by the
                                                                frame's dead load on the free faces
sensor_offset       c (output units; kPa for a stress)          y -> y + c
sensor_drift        rate (output units / s; kPa/s)             y -> y + rate t
sensor_latency      delay (s)                                   y(t) -> y(t - delay)
==================  ==========================================  =====================================

Baseline refits (not candidates: the baseline's own parameters, fitted jointly with every
candidate by ``dejax diagnose --refit``): ``refit:NAME`` for a material parameter NAME of
``dejax.parameters`` (mu_inf, Jm_inf, mu_1, eta_1, ...), one parameter ``factor`` (log scale,
off 1, bounds [1/10, 10]) multiplying the baseline's value (``refit_names``).

Every named effect is realisable (``UNAVAILABLE`` is empty).

Normalized parameters (what the diagnosis's screening and fits move): each parameter maps
its bounds onto z in [0, 1], linearly or in log scale (``Param.z_of``, ``Param.from_z``,
``Param.dx_dz``); ``param_list(names)`` orders the parameters of several effects and
``values_at(names, z)`` gives their values at a point z.
"""
from __future__ import annotations

import dataclasses
import functools
import math
from typing import Callable, Mapping, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from dejax import integrate as it
from dejax import loads
from dejax import parameters
from dejax.material import Material, equilibrium_energy

__all__ = [
    "Param", "Effect", "Pieces", "Sensor", "EffectiveVoltage", "lowpass", "slew_limited", "slew_active", "SLEW_OFF",
    "SlewSwitch", "slew_grid",
    "EFFECTS", "UNAVAILABLE", "get", "names", "applies", "augment_material", "make_pieces", "apply_effects",
    "from_experiment", "param_list", "values_at", "REFIT_PREFIX", "refit_names",
]

DORMANT = 1e-9  # shear modulus of a dormant viscous unit, relative to mu_inf
_GL_X, _GL_W = np.polynomial.legendre.leggauss(64)


# ----------------------------------------------------------------------------- voltage filters


def lowpass(history, tau, t):
    """First-order low-pass of ``history`` (t -> V) with time constant tau (s), zero state at t = 0:

        y(t) = int_0^t exp(-(t - s)/tau)/tau phi(s) ds.

    Evaluated with the substitution w = 1 - exp(-u/tau), u = t - s, as
    y(t) = int_0^W phi(t + tau log(1 - w)) dw, W = 1 - exp(-t/tau), by 64-point
    Gauss-Legendre (smooth in w for smooth phi; relative error ~1e-5 for a few-cycle sine,
    see tests). tau <= 1e-9 returns phi(t). Pure jnp: runs inside jit, differentiable."""
    t = jnp.asarray(t, dtype=float)
    tau = jnp.asarray(tau, dtype=float)
    ts = jnp.maximum(tau, 1e-9)
    W = -jnp.expm1(-t / ts)
    w = 0.5 * W[..., None] * (jnp.asarray(_GL_X) + 1.0)
    s = t[..., None] + ts * jnp.log1p(-w)
    y = 0.5 * W * jnp.sum(jnp.asarray(_GL_W) * history(s), axis=-1)
    return jnp.where(tau <= 1e-9, history(t), y)


SLEW_OFF = 1e9
"""Slew rate (V/s) that stands for an unlimited amplifier: 1e9 V/s is 400 times a 25 kV sine's
steepest rate at 100 Hz (a slew rate at or above it is not applied)."""


def slew_limited(history, rate: float, times, substeps: int = 16, knots: int = 4):
    """An amplifier whose output follows the command ``history`` (t -> V) at most at ``rate``
    (V/s), starting on the command at times[0]: v' = phi' while v = phi and |phi'| <= rate,
    else v moves towards phi at the full rate. Integrated exactly for a command linear within
    each of ``substeps`` sub-intervals per interval of ``times`` (error at most rate x
    sub-interval where the limit starts to act). Returns (grid, v): the output on ``knots``
    points per interval of ``times`` (a history linear between them stays within
    (interval / knots)^2 |phi''| / 8 of it)."""
    t = np.asarray(times, dtype=float)
    k = max(int(substeps), 1)
    m = max(min(int(knots), k), 1)
    while k % m:
        k += 1
    fine = slew_grid(t, k)
    phi = np.asarray(loads.evaluate(history, fine), dtype=float)
    v = np.empty_like(phi)
    v[0] = phi[0]
    step = rate * np.diff(fine)
    for i in range(1, phi.size):
        v[i] = v[i - 1] + min(max(phi[i] - v[i - 1], -step[i - 1]), step[i - 1])
    return fine[:: k // m], v[:: k // m]


class SlewSwitch(eqx.Module):
    """A commanded history ``base`` (t -> V) beside its slew-limited version ``limited`` (a
    PiecewiseLinear on ``slew_grid``), used where ``on``: one pytree structure whether the
    limit acts or not, so that the baseline and a slew-limited candidate share one compiled
    simulation (``fitting.forward.drive_voltage``)."""

    base: eqx.Module
    limited: eqx.Module
    on: jax.Array

    def __call__(self, t):
        return jnp.where(self.on, self.limited(t), self.base(t))


def slew_grid(times, knots: int = 4) -> np.ndarray:
    """The ``knots`` points per interval of ``times`` (plus the last time) on which
    ``slew_limited`` returns its output: (knots (n - 1) + 1,) s."""
    t = np.asarray(times, dtype=float)
    frac = np.arange(knots) / knots
    return np.concatenate([(t[:-1, None] + np.diff(t)[:, None] * frac[None, :]).ravel(), t[-1:]])


def slew_active(rate) -> bool:
    """True if the slew rate ``rate`` (V/s) limits (below ``SLEW_OFF``, to round-off)."""
    return float(rate) < SLEW_OFF * (1.0 - 1e-9)


class EffectiveVoltage(eqx.Module):
    """Electrode voltage seen by the film, from the commanded history ``base``:

        v_e = LP_lag(phi)                         (RC lag of amplifier + electrode resistance)
        phi_eff = (v_e - frac * LP_leak(phi)) / sqrt(1 + mu_drift t)

    lag = 0, frac = 0 and mu_drift = 0 (the defaults) give phi_eff = phi. The last factor
    realises a temperature drift of the moduli, mu(t) = mu (1 + mu_drift t) for every
    modulus of the film: the elastic balance mu f(stretch) = eps E^2 g(stretch) is the same
    with the moduli scaled by s and the field by 1/sqrt(s) (exact when inertia is negligible;
    the viscous units' relaxation times eta/(2 mu) are held, i.e. eta drifts with mu). The leakage term models a
    film whose leakage current charges a screening (space-charge / contact) layer with
    time constant tau_leak: under a constant command phi_eff decays from phi to
    (1 - frac) phi as 1 - frac (1 - exp(-t/tau_leak)). (Approximation: the leak filter acts
    on the command, not on the lagged voltage; exact when tau_leak >> lag.)"""

    base: eqx.Module
    lag: jax.Array
    frac: jax.Array
    tau_leak: jax.Array
    mu_drift: jax.Array
    slew_rate: jax.Array  # V/s; not applied here: fitting.forward.drive_voltage slews the command

    def __init__(self, base, lag=0.0, frac=0.0, tau_leak=1.0, mu_drift=0.0, slew_rate=SLEW_OFF):
        self.base = base
        self.lag = jnp.asarray(lag, dtype=float)
        self.frac = jnp.asarray(frac, dtype=float)
        self.tau_leak = jnp.asarray(tau_leak, dtype=float)
        self.mu_drift = jnp.asarray(mu_drift, dtype=float)
        self.slew_rate = jnp.asarray(slew_rate, dtype=float)

    def __call__(self, t):
        ve = lowpass(self.base, self.lag, t)
        scale = jax.lax.rsqrt(jnp.maximum(1.0 + self.mu_drift * jnp.asarray(t, dtype=float), 1e-6))
        return (ve - self.frac * lowpass(self.base, self.tau_leak, t)) * scale


# ----------------------------------------------------------------------------- pieces


class Sensor(eqx.Module):
    """Output transform y_meas(t) = (1 + gain_rate t) y(t - delay) + offset + drift t
    (y(t) = y(0) for t < 0; t from the trace's start). ``gain_rate`` carries the moduli's
    drift into a measured stress (see the ``mu_drift`` effect)."""

    delay: jax.Array = dataclasses.field(default_factory=lambda: jnp.asarray(0.0))
    offset: jax.Array = dataclasses.field(default_factory=lambda: jnp.asarray(0.0))
    drift: jax.Array = dataclasses.field(default_factory=lambda: jnp.asarray(0.0))
    gain_rate: jax.Array = dataclasses.field(default_factory=lambda: jnp.asarray(0.0))

    def __call__(self, t, y):
        t = jnp.asarray(t, dtype=float)
        y = jnp.asarray(y, dtype=float)
        yd = jnp.interp(t - self.delay, t, y)
        return (1.0 + self.gain_rate * (t - t[0])) * yd + self.offset + self.drift * (t - t[0])


@dataclasses.dataclass(frozen=True)
class Pieces:
    """Forward-model pieces an effect acts on (see the module docstring)."""

    model: object
    loading: it.Loading
    sensor: Sensor
    info: Mapping = dataclasses.field(default_factory=dict)

    def replace(self, **kw) -> "Pieces":
        return dataclasses.replace(self, **kw)


@dataclasses.dataclass(frozen=True)
class Param:
    """One effect parameter: ``off`` leaves the baseline unchanged; ``start`` is where a
    fit begins; ``scale`` "lin" or "log" is the fitting parametrisation."""

    name: str
    off: float
    bounds: tuple[float, float]
    start: float
    scale: str = "lin"
    unit: str = "-"
    doc: str = ""
    probe: bool = False  # a threshold: screened by the secant from off to its data start (no slope at off)

    def _span(self) -> tuple[float, float]:
        lo, hi = self.bounds
        return (math.log(lo), math.log(hi)) if self.scale == "log" else (lo, hi)

    def z_of(self, x: float) -> float:
        """Normalized position of the value ``x`` (clipped to the bounds) in [0, 1]; 0.5 for
        x <= 0 in log scale."""
        if self.scale == "log" and x <= 0:
            return 0.5
        x = min(max(x, self.bounds[0]), self.bounds[1])
        a, b = self._span()
        return min(max(((math.log(x) if self.scale == "log" else x) - a) / (b - a), 0.0), 1.0)

    def from_z(self, z: float) -> float:
        """The value at the normalized position ``z`` (clipped to [0, 1])."""
        a, b = self._span()
        v = a + min(max(z, 0.0), 1.0) * (b - a)
        return math.exp(v) if self.scale == "log" else v

    def dx_dz(self, x: float) -> float:
        """d value / d z at the value ``x``."""
        a, b = self._span()
        return x * (b - a) if self.scale == "log" else (b - a)


@dataclasses.dataclass(frozen=True)
class Effect:
    name: str
    params: tuple[Param, ...]
    apply: Callable[[Pieces, Mapping[str, float]], Pieces]
    doc: str
    kind: str = "model"  # "model" (needs a new simulation) or "sensor" (output transform only)
    needs: tuple[str, ...] = ()  # what the scenario must have: "voltage", "inertia", "prestress_load"
    on_sensor: bool = False  # a model effect that also acts on the sensor (mu_drift on a stress)
    # extra starting values read off the traces (a threshold effect starts where it acts)
    data_starts: Callable[[Sequence], list] | None = None
    # the parameter whose off value switches the whole effect off: there the others act on
    # nothing (a unit's relaxation time at zero modulus), so their screening columns are zero
    gate: str | None = None

    def starts(self, traces) -> list[dict]:
        """Starting values from the data (``data_starts``; none by default)."""
        return [] if self.data_starts is None else list(self.data_starts(traces))

    @property
    def acts_on_sensor(self) -> bool:
        return self.kind == "sensor" or self.on_sensor

    @property
    def n_params(self) -> int:
        return len(self.params)

    def off(self) -> dict:
        return {p.name: p.off for p in self.params}

    def start(self) -> dict:
        return {p.name: p.start for p in self.params}

    def values(self, given: Mapping | None = None) -> dict:
        """Parameter values: ``given`` (e.g. an [effects.NAME] table) over the off values;
        unknown keys raise."""
        given = dict(given or {})
        out = self.off()
        for k, v in given.items():
            if k not in out:
                raise KeyError(f"effect '{self.name}' has no parameter '{k}'; parameters: {sorted(out)}")
            out[k] = float(v)
        return out


# ----------------------------------------------------------------------------- apply functions


def _set_unit(pieces: Pieces, slot_key: str, mu, tau) -> Pieces:
    m = pieces.model.material
    k = pieces.info[slot_key]
    mu_floor = DORMANT * m.mu_inf
    mu_k = jnp.maximum(jnp.asarray(mu, dtype=float), mu_floor)
    ratio = pieces.info.get("K_over_mu", 1e5)
    mat = eqx.tree_at(lambda mm: (mm.mu, mm.K, mm.eta),
                      m, (m.mu.at[k].set(mu_k), m.K.at[k].set(ratio * mu_k), m.eta.at[k].set(2.0 * mu_k * tau)))
    return pieces.replace(model=eqx.tree_at(lambda md: md.material, pieces.model, mat))


def _map_voltages(pieces: Pieces, fn) -> Pieces:
    if pieces.loading is None:  # pieces without a loading (a closed-form test forward)
        return pieces
    v = tuple(fn(h) for h in pieces.loading.voltages)
    return pieces.replace(loading=eqx.tree_at(lambda l: l.voltages, pieces.loading, v))


def _creep(p, v):
    return _set_unit(p, "slot_creep", v["mu"], v["tau"])


def _hyst(p, v):
    return _set_unit(p, "slot_hysteresis", v["mu"], v["tau"])


def _lag(p, v):
    return _map_voltages(p, lambda h: eqx.tree_at(lambda e: e.lag, h, jnp.asarray(v["tau"], dtype=float)))


def _leak(p, v):
    return _map_voltages(p, lambda h: eqx.tree_at(lambda e: (e.frac, e.tau_leak), h,
                                                  (jnp.asarray(v["frac"], dtype=float),
                                                   jnp.asarray(v["tau"], dtype=float))))


def _slew(p, v):
    return _map_voltages(p, lambda h: eqx.tree_at(lambda e: e.slew_rate, h, jnp.asarray(v["rate"], dtype=float)))


def _slew_starts(traces) -> list[dict]:
    """Slew rates at 0.8, 0.5 and 0.25 of the steepest commanded rate of ``traces`` (V/s),
    where a slew limit begins to act."""
    rates = []
    for tr in traces:
        v = tr.voltage()
        if v is not None and tr.time is not None and len(tr.time) > 1:
            rates.append(float(np.max(np.abs(np.gradient(np.asarray(v, dtype=float), tr.time)))))
    top = max(rates, default=0.0)
    return [{"rate": f * top} for f in (0.8, 0.5, 0.25)] if top > 0 else []


def _mullins_starts(traces) -> list[dict]:
    """Energy scales m over the range (Pa): the energies a test reaches are not known before a
    simulation (a 1 mm block at 14 kV reaches ~100 Pa, a film stretched threefold ~10 kPa).
    The off value of m, its lower bound, makes the screening's column for d the saturated
    softening (a constant factor below the largest energy), whatever the energies."""
    return [{"m": m} for m in (1e3, 1e5)]


def _mu_drift(p, v):
    rate = jnp.asarray(v["rate"], dtype=float)
    p = _map_voltages(p, lambda h: eqx.tree_at(lambda e: e.mu_drift, h, rate))
    if p.info.get("output_is_stress"):  # the mechanical stress scales with the moduli
        p = p.replace(sensor=eqx.tree_at(lambda s: s.gain_rate, p.sensor, rate))
    return p


def _electrostriction(p, v):
    mat = eqx.tree_at(lambda m: (m.eps_b, m.eps_a), p.model.material,
                      (jnp.asarray(v["eps_b"], dtype=float), jnp.asarray(v["eps_a"], dtype=float)))
    return p.replace(model=eqx.tree_at(lambda md: md.material, p.model, mat))


def _stiff(p, v):
    m = p.model.material
    mat = eqx.tree_at(lambda mm: mm.mu_inf, m, m.mu_inf * (1.0 + v["rel"]))
    return p.replace(model=eqx.tree_at(lambda md: md.material, p.model, mat))


def _mass(p, v):
    return p.replace(model=eqx.tree_at(lambda md: md.mass_e, p.model, p.model.mass_e * (1.0 + v["rel"])))


def _prestress_unit(p, name: str):
    unit = p.info.get("prestress_load")
    if unit is None:
        raise ValueError(f"the {name} effect needs a block (free faces x1, y1) or a rolled tube (free end 'top'): "
                         "no unit face load in the pieces")
    return jnp.asarray(unit)


def _prestress(p, v):
    # a dead nominal traction s0 on the scenario's free faces (block: equal-biaxial on x = L and
    # y = L; tube: axial on the free end), the consistent loads per unit stress from make_pieces
    unit = _prestress_unit(p, "prestress")
    return p.replace(model=eqx.tree_at(lambda md: md.dead_load, p.model, p.model.dead_load + v["s0"] * unit))


def prestretch_of(lam, mode: str):
    """(3,) principal pre-stretches of an isochoric pre-stretch lam: "biaxial" (block: lam in
    x and y, lam^-2 through the thickness z) or "axial" (tube: lam along its axis x, lam^-1/2
    across)."""
    lam = jnp.asarray(lam, dtype=float)
    return jnp.stack([lam, lam, lam ** -2.0]) if mode == "biaxial" else jnp.stack([lam, lam ** -0.5, lam ** -0.5])


_branch_stress = jax.jit(jax.grad(equilibrium_energy))
"""P (3, 3) of the equilibrium branch at (F, E, material): one compiled program."""


def _prestretch(p, v):
    # the film pre-stretched by lam long before the test (Material.pre: the equilibrium branch
    # sees F diag(pre), the relaxed viscous units F), held in the reference configuration by the
    # frame's dead load on the free faces: the nominal stress P_xx - P_zz of the equilibrium
    # branch at F = I (the faces across the pre-stretch traction-free)
    unit = _prestress_unit(p, "prestretch")
    mat = eqx.tree_at(lambda m: m.pre, p.model.material, prestretch_of(v["lam"], p.info["prestretch_mode"]))
    P = _branch_stress(jnp.eye(3), jnp.zeros(3), mat)
    load = p.model.dead_load + (P[0, 0] - P[2, 2]) * unit
    return p.replace(model=eqx.tree_at(lambda md: (md.material, md.dead_load), p.model, (mat, load)))


def _mullins(p, v):
    mat = eqx.tree_at(lambda m: (m.mullins_d, m.mullins_m), p.model.material,
                      (jnp.asarray(v["d"], dtype=float), jnp.asarray(v["m"], dtype=float)))
    return p.replace(model=eqx.tree_at(lambda md: md.material, p.model, mat))


def _output_unit(p) -> float:
    """SI value of one output unit of the sensor effects: 1, or 1 kPa for a stress (Pa)."""
    return 1e3 if p.info.get("output_is_stress") else 1.0


def _offset(p, v):
    c = jnp.asarray(v["c"], dtype=float) * _output_unit(p)
    return p.replace(sensor=eqx.tree_at(lambda s: s.offset, p.sensor, c))


def _drift(p, v):
    rate = jnp.asarray(v["rate"], dtype=float) * _output_unit(p)
    return p.replace(sensor=eqx.tree_at(lambda s: s.drift, p.sensor, rate))


def _latency(p, v):
    return p.replace(sensor=eqx.tree_at(lambda s: s.delay, p.sensor, jnp.asarray(v["delay"], dtype=float)))


EFFECTS: dict[str, Effect] = {e.name: e for e in [
    Effect("creep", (Param("mu", 0.0, (0.0, 2e5), 5e3, unit="Pa", doc="shear modulus of the extra unit"),
                     Param("tau", 5.0, (0.5, 50.0), 5.0, "log", "s", "relaxation time eta/(2 mu)")),
           _creep, "additional slow viscous Gent unit (creep / slow relaxation over many cycles)", gate="mu"),
    Effect("hysteresis", (Param("mu", 0.0, (0.0, 2e5), 5e3, unit="Pa"),
                          Param("tau", 0.05, (1e-3, 0.5), 0.05, "log", "s")),
           _hyst, "additional fast viscous Gent unit (loop area / hysteresis within a cycle)", gate="mu"),
    Effect("voltage_lag", (Param("tau", 0.0, (0.0, 0.2), 0.0, unit="s", doc="RC time constant"),),
           _lag, "first-order lag between commanded and electrode voltage (source/electrode resistance x capacitance)",
           needs=("voltage",)),
    Effect("amplifier_slew", (Param("rate", SLEW_OFF, (1e4, SLEW_OFF), 1e5, "log", "V/s",
                                    "largest rate of change of the amplifier's output", probe=True),),
           _slew, "slew-rate limit of the high-voltage amplifier: the electrode voltage follows the command at "
           "most at this rate (a sine's steepest parts turned into ramps at high frequency and voltage)",
           needs=("voltage",), data_starts=_slew_starts),
    Effect("leakage", (Param("frac", 0.0, (0.0, 0.6), 0.0, doc="screened fraction of the field at steady state"),
                       Param("tau", 2.0, (0.05, 50.0), 2.0, "log", "s", "charging time of the screening layer")),
           _leak, "leakage current / charge injection: effective field decays under constant voltage",
           needs=("voltage",), gate="frac"),
    Effect("electrostriction", (Param("eps_b", 0.0, (-0.5, 0.5), 0.0,
                                      doc="first order: eps(1 + eps_b (lambda_E - 1)), lambda_E the stretch along the field"),
                                Param("eps_a", 0.0, (-0.3, 0.3), 0.0, doc="second order: eps(1 + eps_a (I1bar - 3))")),
           _electrostriction, "stretch-dependent permittivity (Material.eps_b, first order in the stretch along the "
           "field, as measured on acrylic films; Material.eps_a, through I1bar - 3)", needs=("voltage",)),
    Effect("mu_drift", (Param("rate", 0.0, (-0.05, 0.05), 0.0, unit="1/s", doc="mu(t) = mu (1 + rate t)"),),
           _mu_drift, "temperature drift of the moduli over the test (film warming by dissipation or the room): "
           "every modulus scales by 1 + rate t, realised as the equivalent field scaling (inertia neglected) "
           "and, where the output is a stress, the same factor on its mechanical part", on_sensor=True),
    Effect("electrode_stiffness", (Param("rel", 0.0, (-0.5, 2.0), 0.0, doc="mu_layer t_layer / (mu_inf h)"),),
           _stiff, "stiffness of electrodes/fixtures: a parallel neo-Hookean layer, lumped into mu_inf "
           "(approximation: the layer shares the film's Gent limit Jm_inf)"),
    Effect("added_mass", (Param("rel", 0.0, (0.0, 100.0), 0.0, doc="added mass / film mass"),),
           _mass, "mass of electrodes/fixtures, smeared over the film (mass matrix scaled; gravity, if any, too)",
           needs=("inertia",)),
    Effect("prestress", (Param("s0", 0.0, (0.0, 1e5), 0.0, unit="Pa", doc="nominal in-plane dead-load stress"),),
           _prestress, "equibiaxial in-plane dead load (pre-stress): a nominal traction s0 on the free lateral "
           "faces (the film pulled by its frame or weights)", needs=("prestress_load",)),
    Effect("prestretch", (Param("lam", 1.0, (1.0, 3.0), 1.5, doc="in-plane (block) or axial (tube) pre-stretch"),),
           _prestretch, "kinematic pre-stretch of the film, applied long before the test (viscous units relaxed) "
           "and held by its frame: the equilibrium branch stretched by lam from its natural state "
           "(Material.pre), the frame's dead load on the free faces balancing it",
           needs=("prestress_load",)),
    Effect("mullins", (Param("d", 0.0, (0.0, 0.9), 0.3, doc="largest relative softening below the largest "
                             "energy seen"),
                       Param("m", 1e2, (1e2, 1e6), 1e4, "log", "Pa", "energy scale of the softening")),
           _mullins, "Mullins-type stress softening (Ogden-Roxburgh): the equilibrium branch softer on unloading "
           "and reloading below the largest energy a point has seen (a history variable per Gauss point)",
           data_starts=_mullins_starts, gate="d"),
    Effect("sensor_offset", (Param("c", 0.0, (-1.0, 1.0), 0.0, unit="output"),), _offset,
           "constant sensor offset", "sensor"),
    Effect("sensor_drift", (Param("rate", 0.0, (-1.0, 1.0), 0.0, unit="output/s"),), _drift,
           "linear sensor drift", "sensor"),
    Effect("sensor_latency", (Param("delay", 0.0, (0.0, 0.2), 0.0, unit="s"),), _latency,
           "sensor latency (pure delay of the measured output)", "sensor"),
]}

UNAVAILABLE: dict[str, str] = {}
"""Effects named but not realisable with the current core ({name: why}); none at present."""


REFIT_PREFIX = "refit:"
"""Prefix of the baseline-refit effects: ``refit:mu_inf`` multiplies the baseline's mu_inf."""
REFIT_BOUNDS = (0.1, 10.0)
"""Range of a refit factor: a decade either side of the fitted baseline."""


def refit_names(params: Sequence[str]) -> list[str]:
    """The refit effects of the material parameters ``params`` (e.g. an experiment's ``[fit]
    free``): ["refit:mu_inf", ...]. KeyError for a name that is no material parameter."""
    out = [REFIT_PREFIX + p for p in params]
    for n in out:
        get(n)
    return out


@functools.lru_cache(maxsize=None)
def _refit_effect(param: str) -> Effect:
    """The effect ``refit:param``: the baseline's material parameter ``param`` times ``factor``
    (its viscous unit i = 1, 2, ... among the baseline's own, not the dormant ones)."""
    g = parameters.PATTERN.match(param)
    if not g or param == "c_d":
        raise KeyError(f"refit: {param!r} is not a material parameter (expected mu_inf, K_inf, Jm_inf, eps, rho, "
                       "mu_i, K_i, Jm_i, eta_i)")

    def apply(p, v):
        m = p.model.material
        if g.group(2):
            key, i = g.group(2), int(g.group(3)) - 1
            n_real = p.info.get("slot_creep", m.n_units)
            if not 0 <= i < n_real:
                raise ValueError(f"refit: {param!r}: the baseline has {n_real} viscous unit(s)")
            value = getattr(m, key)[i]
        else:
            value = getattr(m, param)
        mat = parameters.replace(m, {param: value * jnp.asarray(v["factor"], dtype=float)})
        return p.replace(model=eqx.tree_at(lambda md: md.material, p.model, mat))

    lo, hi = REFIT_BOUNDS
    return Effect(REFIT_PREFIX + param,
                  (Param("factor", 1.0, (lo, hi), 1.0, "log", "-", f"factor on the baseline's {param}"),),
                  apply, f"the baseline's {param} refitted (a factor on its value)")


def applies(name: str, pieces: Pieces) -> bool:
    """True if the effect ``name`` can act in the scenario of ``pieces``: voltage effects need
    a voltage, added mass needs a dynamic (not quasi-static) run, the pre-stress the
    scenario's free faces (``Effect.needs``; ``make_pieces`` records what a scenario has)."""
    have = {"voltage": lambda: pieces.loading is None or bool(pieces.loading.voltages),  # None: not known
            "inertia": lambda: not pieces.info.get("quasi_static", False),
            "prestress_load": lambda: "prestress_load" in pieces.info}
    return all(have[k]() for k in get(name).needs)


def names(pieces: "Pieces | None" = None) -> list[str]:
    """Every effect of the library; with ``pieces``, those that apply to its scenario
    (``applies``)."""
    return [n for n in EFFECTS if pieces is None or applies(n, pieces)]


def get(name: str) -> Effect:
    if name.startswith(REFIT_PREFIX):
        return _refit_effect(name[len(REFIT_PREFIX):])
    if name in UNAVAILABLE:
        raise NotImplementedError(f"effect '{name}' is not realisable with the current core: {UNAVAILABLE[name]}")
    if name not in EFFECTS:
        raise KeyError(f"unknown effect '{name}'; known: {sorted(EFFECTS)}")
    return EFFECTS[name]


# ----------------------------------------------------------------------------- building


def augment_material(material: Material, n_extra: int = 2, Jm: float = 5.0) -> Material:
    """The material with ``n_extra`` dormant viscous units appended (mu = 1e-9 mu_inf,
    K = K/mu ratio of the baseline (1e5 without units), eta = 2 mu tau with tau 1 s)."""
    mu0 = DORMANT * float(material.mu_inf)
    ratio = float(material.K[0] / material.mu[0]) if material.n_units else 1e5
    return Material(material.mu_inf, material.K_inf, material.Jm_inf, material.eps, material.rho,
                    mu=list(np.asarray(material.mu)) + [mu0] * n_extra,
                    K=list(np.asarray(material.K)) + [ratio * mu0] * n_extra,
                    Jm=list(np.asarray(material.Jm)) + [Jm] * n_extra,
                    eta=list(np.asarray(material.eta)) + [2.0 * mu0] * n_extra, eps_a=material.eps_a,
                    eps_b=material.eps_b, pre=material.pre, mullins_d=material.mullins_d,
                    mullins_m=material.mullins_m)


def make_pieces(problem) -> Pieces:
    """Pieces of a dejax ``Problem`` built with an ``augment_material`` material (two dormant
    units last): voltages wrapped in EffectiveVoltage, identity Sensor."""
    mat = problem.model.material
    n = mat.n_units
    if n < 2:
        raise ValueError("make_pieces: build the problem with augment_material(...) (two dormant units)")
    ratio = float(mat.K[0] / mat.mu[0]) if n > 2 else 1e5
    volt = tuple(h if isinstance(h, EffectiveVoltage) else EffectiveVoltage(h) for h in problem.loading.voltages)
    loading = eqx.tree_at(lambda l: l.voltages, problem.loading, volt) if volt else problem.loading
    info = {"slot_creep": n - 2, "slot_hysteresis": n - 1, "K_over_mu": ratio,
            "quasi_static": bool(getattr(problem, "quasi_static", False)),
            "output_is_stress": problem.name == "uniaxial"}
    mesh = problem.extras.get("mesh")
    if mesh is not None:
        from dejax import model as mdl

        if problem.name == "block" and {"x1", "y1"} <= set(mesh.node_sets):
            info["prestress_load"] = np.asarray(mdl.face_traction_load(mesh, "x1", (1.0, 0.0, 0.0))
                                                + mdl.face_traction_load(mesh, "y1", (0.0, 1.0, 0.0)))
            info["prestretch_mode"] = "biaxial"
        elif problem.name == "rolled":  # axial pre-load of the free end (a weight, a pre-stretched roll)
            info["prestress_load"] = np.asarray(mdl.face_traction_load(mesh, "top", (1.0, 0.0, 0.0)))
            info["prestretch_mode"] = "axial"
    return Pieces(problem.model, loading, Sensor(), info)


def apply_effects(pieces: Pieces, effects: Mapping[str, Mapping[str, float]]) -> Pieces:
    """Apply several effects in turn: {name: {param: value}} (missing params: off values)."""
    for name, vals in effects.items():
        e = get(name)
        pieces = e.apply(pieces, e.values(vals))
    return pieces


def param_list(names: Sequence[str]) -> list[tuple[str, Param]]:
    """(effect name, Param) of every parameter of the effects ``names``, in order: the
    components of a normalized point z."""
    return [(n, p) for n in names for p in get(n).params]


def values_at(names: Sequence[str], z, fixed: Mapping | None = None) -> dict:
    """{name: {param: value}} of the effects ``names`` at the normalized point ``z`` (see
    ``param_list``), with the other effects of ``fixed`` ({name: values}) added."""
    fixed = dict(fixed or {})
    out = {n: dict(fixed.get(n, get(n).off())) for n in names}
    for (n, p), zi in zip(param_list(names), z):
        out[n][p.name] = p.from_z(zi)
    return {**fixed, **out}


def from_experiment(exp) -> dict:
    """{name: values} of the effects switched on in an Experiment's [effects] tables
    (parameters not given take their off values; unknown effects raise)."""
    return {name: get(name).values({k: v for k, v in params.items() if isinstance(v, (int, float))})
            for name, params in exp.effects.items()}
