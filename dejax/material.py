"""Hyper-viscoelastic Gent dielectric elastomer (paper Eqs. 18-20, 37-39).

All energies are per unit reference volume (J/m^3) and pure functions of the
deformation gradient ``F`` (3 x 3), the nominal electric field ``E`` (3,) (V/m,
``E = -Grad phi`` in the reference configuration) and the viscous right
Cauchy-Green tensors ``Cv`` (n_units, 3, 3) of the parallel viscous units.
Batch over Gauss points with ``jax.vmap``. Forces and tangents come from
``jax.grad`` / ``jax.jvp`` (forward lanes) of ``free_energy``; nothing here is hand-derived.

Free energy (docs/paper-notes.md, Eqs. 18-20)::

    psi_inf = -mu_inf Jm_inf / 2 ln(1 - (J^(-2/3) I1 - 3) / Jm_inf)
              + K_inf / 2 (J - 1)^2 - eps / 2 J E^T C^-1 E
    psi_s   = -mu_s Jm_s / 2 ln(1 - (Je^(-2/3) I1e - 3) / Jm_s) + K_s / 2 (Je - 1)^2
    I1e = tr(C Cv_s^-1),  Je = J / sqrt(det Cv_s)

Viscous flow (Eq. 37, cleaned up in docs/paper-notes.md)::

    dCv/dt = A (C - tr(C Cv^-1) Cv / 3),   A = (2 mu_s / eta_s) Je^(-2/3) / H_s

integrated by an implicit step that keeps ``det Cv`` exactly constant: backward Euler
(Eq. 39, ``viscous_update``) or BDF2 (second order, ``bdf2_flow_step``; the default of
the time steppers in ``integrate``).

Mullins-type softening (an extension beyond the paper, off by default: ``mullins_d = 0``),
the pseudo-elastic model of Ogden and Roxburgh (1999) on the equilibrium branch's isochoric
Gent energy W, with the largest W the point has seen, ``wmax``, as its history variable::

    psi_inf -> eta W + (bulk, electrostatic),  eta = 1 - d erf((wmax - W) / m),
    wmax_new = max(wmax_old, W)

(eta = 1 on the primary loading path, softer on unloading and reloading below wmax); the
stress is eta dW/dF (``eta`` held, as Cv_new is), its tangent through eta(F) by autodiff.
"""
from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.custom_derivatives import SymbolicZero

from .tensor import det3, gram3, inv3, mm3


class GentLimitError(FloatingPointError):
    """A state reached (or passed) the Gent limiting stretch: ln(1 - ...) is undefined."""


class Material(eqx.Module):
    """Gent dielectric elastomer with ``n_units`` parallel viscous Gent units.

    Scalars are float arrays (so the material is a differentiable pytree); the
    viscous fields are (n_units,) arrays (length 0 = hyperelastic).

    Attributes:
      mu_inf: equilibrium shear modulus (Pa).
      K_inf: equilibrium bulk modulus (Pa); ``inf`` (exact incompressibility) is allowed
        with the mixed volumetric form only.
      Jm_inf: equilibrium Gent limit I_lim (-).
      eps: permittivity (F/m).
      rho: mass density (kg/m^3).
      mu, K, Jm, eta: per viscous unit shear modulus (Pa), bulk modulus (Pa),
        Gent limit (-), viscosity (Pa s); the small-strain relaxation time of a unit
        under this flow rule is eta / (2 mu).
      eps_a, eps_b: electrostriction coefficients (-), default 0 (the paper's model): the
        permittivity is eps (1 + eps_a (I1bar - 3) + eps_b (lambda_E - 1)), lambda_E the
        stretch of the material line along the nominal field, sqrt(E.C E / E.E). eps_b is the
        first-order dependence measured on acrylic films (permittivity falling as the film is
        stretched in plane, i.e. thinned along the field: Wissler and Mazza 2007); I1bar - 3 is
        of second order in the strain.
      pre: (3,) principal pre-stretches (-) along x, y, z of the equilibrium branch, default
        1 (the paper's model): a kinematic pre-stretch of the film applied long before the
        test, so that the equilibrium branch sees F diag(pre) (the stretch from the film's
        natural state) while the viscous units, relaxed in the pre-stretched reference
        configuration, see F; isochoric (prod(pre) = 1). The field, the permittivity and
        its electrostriction refer to the reference (pre-stretched) configuration.
      mullins_d, mullins_m: Mullins softening (module docstring): the largest relative
        softening d in [0, 1) (0 = off, the paper's model) and the energy scale m (Pa = J/m^3)
        over which it develops below the largest energy seen.
    """

    mu_inf: jax.Array
    K_inf: jax.Array
    Jm_inf: jax.Array
    eps: jax.Array
    rho: jax.Array
    mu: jax.Array
    K: jax.Array
    Jm: jax.Array
    eta: jax.Array
    eps_a: jax.Array
    eps_b: jax.Array
    pre: jax.Array
    mullins_d: jax.Array
    mullins_m: jax.Array

    def __init__(self, mu_inf, K_inf, Jm_inf, eps, rho, mu=(), K=(), Jm=(), eta=(), eps_a=0.0, eps_b=0.0,
                 pre=(1.0, 1.0, 1.0), mullins_d=0.0, mullins_m=1e4):
        self.mu_inf = jnp.asarray(mu_inf, dtype=float)
        self.K_inf = jnp.asarray(K_inf, dtype=float)
        self.Jm_inf = jnp.asarray(Jm_inf, dtype=float)
        self.eps = jnp.asarray(eps, dtype=float)
        self.rho = jnp.asarray(rho, dtype=float)
        n = jnp.atleast_1d(jnp.asarray(mu, dtype=float)).reshape(-1).shape[0]  # static, also for tracers
        arrs = []
        for name, v in (("mu", mu), ("K", K), ("Jm", Jm), ("eta", eta)):
            a = jnp.atleast_1d(jnp.asarray(v, dtype=float)).reshape(-1)
            if a.shape[0] != n:
                raise ValueError(
                    f"Material: viscous parameter {name!r} has {a.shape[0]} entries, "
                    f"but mu has {n} (one per viscous unit)"
                )
            arrs.append(a)
        self.mu, self.K, self.Jm, self.eta = arrs
        self.eps_a = jnp.asarray(eps_a, dtype=float)
        self.eps_b = jnp.asarray(eps_b, dtype=float)
        self.pre = jnp.broadcast_to(jnp.asarray(pre, dtype=float), (3,))
        self.mullins_d = jnp.asarray(mullins_d, dtype=float)
        self.mullins_m = jnp.asarray(mullins_m, dtype=float)

    @property
    def n_units(self) -> int:
        return int(self.mu.shape[0])

    def validate(self) -> "Material":
        """Raise ValueError naming the parameter and bound for any unphysical value."""
        checks = [
            ("mu_inf", self.mu_inf, 0.0),
            ("K_inf", self.K_inf, 0.0),
            ("Jm_inf", self.Jm_inf, 0.0),
            ("eps", self.eps, -np.inf),
            ("rho", self.rho, 0.0),
            ("mu", self.mu, 0.0),
            ("K", self.K, -np.inf),
            ("Jm", self.Jm, 0.0),
            ("eta", self.eta, 0.0),
        ]
        for name, value, lower in checks:
            try:
                v = np.asarray(value, dtype=float)
            except Exception:  # traced: cannot check
                continue
            finite = np.isfinite(v) | ((name == "K_inf") & (v == np.inf))  # K_inf = inf: incompressible
            if not np.all(finite):
                raise ValueError(f"Material parameter {name} = {v} is not finite")
            if np.any(v <= lower) if lower == 0.0 else np.any(v < lower):
                raise ValueError(f"Material parameter {name} = {v} must be > {lower}")
        if np.any(np.asarray(self.eps) < 0):
            raise ValueError(f"Material parameter eps = {self.eps} must be >= 0")
        if np.any(np.asarray(self.K) < 0):
            raise ValueError(f"Material parameter K = {self.K} must be >= 0")
        try:
            pre = np.asarray(self.pre, dtype=float)
            d, m = float(self.mullins_d), float(self.mullins_m)
        except Exception:  # traced: cannot check
            return self
        if not 0.0 <= d < 1.0:
            raise ValueError(f"Material parameter mullins_d = {d} must lie in [0, 1)")
        if not m > 0.0:
            raise ValueError(f"Material parameter mullins_m = {m} must be > 0 (Pa)")
        if not np.all(np.isfinite(pre) & (pre > 0)):
            raise ValueError(f"Material parameter pre = {pre} must be finite and > 0")
        if abs(float(np.prod(pre)) - 1.0) > 1e-9:
            raise ValueError(f"Material parameter pre = {pre}: a pre-stretch is isochoric, its product "
                             f"{float(np.prod(pre)):.12g} must be 1")
        return self


def _safe_log1m(x):
    """ln(1 - x) for x < 1; returns 0 (not NaN) past the limit, which is flagged elsewhere."""
    ok = x < 1.0
    return jnp.where(ok, jnp.log1p(-jnp.where(ok, x, 0.0)), 0.0)


def gent_energy(I1bar, mu, Jm):
    """Gent energy -mu Jm/2 ln(1 - (I1bar - 3)/Jm) (Eq. 18), I1bar the isochoric first invariant."""
    return -0.5 * mu * Jm * _safe_log1m((I1bar - 3.0) / Jm)


def gent_margin(I1bar, Jm):
    """H = 1 - (I1bar - 3)/Jm: positive inside the Gent limit, <= 0 at or past it."""
    return 1.0 - (I1bar - 3.0) / Jm


def _natural_invariants(F, mat: Material):
    """(J, I1bar) of F diag(mat.pre), the stretch of the equilibrium branch from the film's
    natural state (``Material.pre``)."""
    Fn = F * mat.pre[None, :]
    Jn = det3(Fn)
    return Jn, Jn ** (-2.0 / 3.0) * jnp.trace(gram3(Fn))


def equilibrium_gent_energy(F, mat: Material):
    """W: the equilibrium branch's isochoric Gent energy at F diag(mat.pre) (J/m^3), the
    energy Mullins softening measures (``mullins_factor``)."""
    return gent_energy(_natural_invariants(F, mat)[1], mat.mu_inf, mat.Jm_inf)


def mullins_factor(F, wmax_old, mat: Material):
    """(eta, wmax_new): the Ogden-Roxburgh softening factor eta = 1 - d erf((wmax - W)/m) at
    F with the history wmax_new = max(wmax_old, W) (J/m^3); eta = 1 where d = 0 (off) and on
    the primary loading path (W = wmax)."""
    W = equilibrium_gent_energy(F, mat)
    wmax = jnp.maximum(wmax_old, W)
    return 1.0 - mat.mullins_d * jax.scipy.special.erf((wmax - W) / mat.mullins_m), wmax


def equilibrium_energy(F, E, mat: Material, bulk: bool = True, softening=1.0):
    """psi_inf(F, E): Gent + bulk + electrostatic (Eq. 18). J/m^3.

    ``bulk=False`` leaves out the penalty K_inf/2 (J - 1)^2 (the mixed form supplies the
    volumetric part itself, see ``mixed_free_energy``). With ``mat.eps_a`` or ``mat.eps_b``
    non-zero the permittivity depends on stretch (electrostriction, see ``Material``; an
    extension beyond the paper used by the sim-to-real diagnosis). The Gent and bulk terms
    see F diag(mat.pre), the stretch from the film's natural state (``Material.pre``);
    ``softening`` multiplies the Gent term (the Mullins factor eta, held: ``mullins_factor``)."""
    C = gram3(F)
    J = det3(F)
    I1bar = J ** (-2.0 / 3.0) * jnp.trace(C)
    Jn, I1bar_n = _natural_invariants(F, mat)
    EE = jnp.dot(E, E)
    safe = jnp.where(EE > 0.0, EE, 1.0)
    lam_E = jnp.sqrt(jnp.where(EE > 0.0, jnp.dot(E, C @ E) / safe, 1.0))  # 1 without field
    eps = mat.eps * (1.0 + mat.eps_a * (I1bar - 3.0) + mat.eps_b * (lam_E - 1.0))
    elec = -0.5 * eps * J * jnp.sum(E[:, None] * inv3(C) * E[None, :])
    psi = softening * gent_energy(I1bar_n, mat.mu_inf, mat.Jm_inf) + elec
    return psi + 0.5 * mat.K_inf * (Jn - 1.0) ** 2 if bulk else psi


def _viscous_invariants(F, Cv):
    """(Je, I1e) of one unit: Je = J / sqrt(det Cv), I1e = tr(C Cv^-1)."""
    C = gram3(F)
    J = det3(F)
    Je = J / jnp.sqrt(det3(Cv))
    I1e = jnp.sum(C * inv3(Cv).T)  # tr(C Cv^-1)
    return Je, I1e


def viscous_energy(F, Cv, mu, K, Jm, bulk: bool = True):
    """psi_s(F, Cv) of one viscous unit (Eq. 19). J/m^3. ``bulk=False``: without K/2 (Je - 1)^2."""
    Je, I1e = _viscous_invariants(F, Cv)
    psi = gent_energy(Je ** (-2.0 / 3.0) * I1e, mu, Jm)
    return psi + 0.5 * K * (Je - 1.0) ** 2 if bulk else psi


def free_energy(F, E, Cv, mat: Material, bulk: bool = True, softening=1.0):
    """Total free energy psi = psi_inf + sum_s psi_s (Eq. 20). Cv: (n_units, 3, 3).

    ``bulk=False``: the isochoric and electrostatic part only (no penalty bulk terms);
    ``softening``: the Mullins factor on the equilibrium Gent term (held, 1 = none)."""
    psi = equilibrium_energy(F, E, mat, bulk, softening)
    if mat.n_units:
        unit = lambda Cv_s, mu, K, Jm: viscous_energy(F, Cv_s, mu, K, Jm, bulk)
        psi = psi + jnp.sum(jax.vmap(unit)(Cv, mat.mu, mat.K, mat.Jm))
    return psi


def bulk_modulus(mat: Material):
    """K = K_inf + sum_s K_s (Pa): the bulk modulus of the mixed form.

    The viscous flow keeps det Cv_s = 1, so Je = J and the paper's penalty terms add up to
    K/2 (J - 1)^2. ``inf`` means exact incompressibility."""
    return mat.K_inf + jnp.sum(mat.K)


def mixed_free_energy(F, E, Cv, p, mat: Material, softening=1.0):
    """Perturbed-Lagrangian free energy psi_iso + p (J - 1) - p^2 / (2 K) (J/m^3).

    p (Pa) is the pressure at the point (the model interpolates it per element); eliminating
    it pointwise (p = K (J - 1)) gives back ``free_energy``. K = ``bulk_modulus(mat)``
    may be ``inf``: then p is the Lagrange multiplier of J = 1."""
    K = bulk_modulus(mat)
    return free_energy(F, E, Cv, mat, bulk=False, softening=softening) + p * (det3(F) - 1.0) - 0.5 * p * p / K


def min_gent_margin(F, Cv, mat: Material):
    """Smallest Gent margin H over the equilibrium branch (at F diag(mat.pre)) and every viscous unit."""
    h = gent_margin(_natural_invariants(F, mat)[1], mat.Jm_inf)
    if mat.n_units:
        def unit(Cv_s, Jm):
            Je, I1e = _viscous_invariants(F, Cv_s)
            return gent_margin(Je ** (-2.0 / 3.0) * I1e, Jm)

        h = jnp.minimum(h, jnp.min(jax.vmap(unit)(Cv, mat.Jm)))
    return h


# ---------------------------------------------------------------------------
# Viscous update: implicit steps (backward Euler, BDF2) that keep det Cv constant.
# ---------------------------------------------------------------------------
#
# Backward Euler on the flow rule reads Cv (1 + dt A tr(C Cv^-1)/3) = Cv_old + dt A C.
# The flow is isochoric (d det Cv / dt = 0), which the literal update keeps only to
# O(dt^2) per step. We keep the same structure, Cv = (Cv_old + dt A C) / kappa, and pick
# the scalar kappa so that det Cv = det Cv_old exactly (kappa = 1 + dt A tr(C Cv_old^-1)/3
# + O(dt^2): the same first-order scheme). Je is then fixed, and the implicit unknown is
# the scalar rate A = (2 mu / eta) Je^(-2/3) / H(Cv): one scalar Newton solve, whose
# derivative with respect to F comes from the implicit function theorem.
#
# BDF2 has the same structure with another base and step (Cv_n + b (Cv_n - Cv_{n-1}) and
# c h instead of Cv_n and h), so one scalar solve serves both (``FlowStep``).


class FlowStep(eqx.Module):
    """What one implicit step of the flow rule needs besides the end-of-step F, per unit.

    The step solves Cv_new = (base + dt A C) / kappa, A = A(F, Cv_new) (Eq. 37 at the end of
    the step), kappa fixed by det Cv_new = det_old. Backward Euler (Eq. 39): base = Cv_n,
    dt = h. BDF2: base = Cv_n + b (Cv_n - Cv_{n-1}), dt = c h (``bdf2_flow_step``).

    Fields, each with leading axis n_units: base (3, 3), base_inv (3, 3) its inverse,
    det_base, det_old (det Cv_n), dt (s).
    """

    base: jax.Array
    base_inv: jax.Array
    det_base: jax.Array
    det_old: jax.Array
    dt: jax.Array


def _flow_step(base, det_base, det_old, dt) -> FlowStep:
    return FlowStep(base, jax.vmap(inv3)(base), det_base, det_old, dt)


def backward_euler_flow_step(Cv_old, dt) -> FlowStep:
    """FlowStep of the backward-Euler update (Eq. 39) from Cv_old (n_units, 3, 3) over dt (s)."""
    Cv_old = jnp.asarray(Cv_old)
    det_old = jax.vmap(det3)(Cv_old)
    return _flow_step(Cv_old, det_old, det_old, jnp.broadcast_to(jnp.asarray(dt, dtype=Cv_old.dtype), det_old.shape))


def bdf2_flow_step(Cv, Cv_prev, h, h_prev) -> FlowStep:
    """FlowStep of the variable-step BDF2 update from Cv_n, Cv_{n-1} (n_units, 3, 3).

    With w = h / h_prev: Cv_{n+1} - Cv_n - b (Cv_n - Cv_{n-1}) = c h dCv/dt(t_{n+1}),
    b = w^2 / (1 + 2 w), c = (1 + w) / (1 + 2 w): second order and L-stable (a unit much
    faster than the step relaxes in one step, as with backward Euler). Backward Euler is
    used instead where BDF2 does not apply: the first step (h_prev = 0), a step more than
    twice the previous one (w > 2, where variable-step BDF2 loses zero-stability), or a
    point where the extrapolated base is not positive definite (a unit that relaxed by
    O(1) in one step).
    """
    Cv, Cv_prev = jnp.asarray(Cv), jnp.asarray(Cv_prev)
    det_old = jax.vmap(det3)(Cv)
    h = jnp.asarray(h, dtype=Cv.dtype)
    usable = (h_prev > 0) & (h <= 2.0 * h_prev)
    w = h / jnp.where(usable, h_prev, h)
    b = w * w / (1.0 + 2.0 * w)
    c = (1.0 + w) / (1.0 + 2.0 * w)
    base = Cv + b * (Cv - Cv_prev)
    # positive definite (leading minors, relative to Cv's) and not far from Cv
    m1 = base[:, 0, 0] / Cv[:, 0, 0]
    m2 = (base[:, 0, 0] * base[:, 1, 1] - base[:, 0, 1] * base[:, 1, 0]) / (
        Cv[:, 0, 0] * Cv[:, 1, 1] - Cv[:, 0, 1] * Cv[:, 1, 0])
    det_base = jax.vmap(det3)(base)
    ok = usable & (m1 > 0.25) & (m2 > 0.25 ** 2) & (det_base / det_old > 0.25 ** 3)
    base = jnp.where(ok[:, None, None], base, Cv)
    det_base = jnp.where(ok, det_base, det_old)
    dt = jnp.where(ok, c * h, h)
    return _flow_step(base, det_base, det_old, dt)


# The scalar equation needs no 3 x 3 algebra inside the iteration. With s = dt A and
# M = base^-1 C (invariants I1, I2, I3), B = base + s C = base (I + s M), and with
# beta = det base / det_old,
#   kappa^3 = det B / det_old = beta P(s),  P(s) = 1 + s I1 + s^2 I2 + s^3 I3,
#   tr(C Cv^-1) = kappa tr(M (I + s M)^-1) = kappa P'(s) / P(s),
#   Je^(-2/3) = (det C / det_old)^(-1/3) = (beta I3)^(-1/3),
#   Je^(-2/3) tr(C Cv^-1) = I3^(-1/3) P'(s) P(s)^(-2/3),
# an exact rewriting (measured 16x cheaper per Gauss point than forming B each iteration).


def _flow_invariants(F, base_inv, det_base):
    """(I1, I2, I3) of M = base^-1 C (C = F^T F): the data of the scalar rate equation."""
    C = gram3(F)
    M = mm3(base_inv, C)
    I1 = jnp.trace(M)
    I2 = 0.5 * (I1 * I1 - jnp.sum(M * M.T))
    I3 = det3(F) ** 2 / det_base
    return I1, I2, I3


def _rate_margin(A, I1, I2, I3, i3, dt, Jm):
    """(H, dH/dA): the Gent margin of Cv(A), H = 1 - (i3 P'(s) P(s)^(-2/3) - 3) / Jm with
    s = dt A and i3 = I3^(-1/3), and its slope, written out with one power (the local
    Newton runs at every Gauss point, unit and Newton iteration)."""
    s = dt * A
    P = 1.0 + s * (I1 + s * (I2 + s * I3))
    dP = I1 + s * (2.0 * I2 + 3.0 * s * I3)
    ddP = 2.0 * I2 + 6.0 * s * I3
    P23 = P ** (-2.0 / 3.0)
    dI1e = i3 * dt * P23 * (ddP - (2.0 / 3.0) * dP * dP / P)  # d(i3 dP P^-2/3)/dA
    return gent_margin(i3 * dP * P23, Jm), -dI1e / Jm


def _rate_residual_inv(A, I1, I2, I3, je23, dt, mu, eta, Jm):
    """A H(Cv(A)) - (2 mu / eta) Je^(-2/3) from the invariants of base^-1 C."""
    H, _ = _rate_margin(A, I1, I2, I3, I3 ** (-1.0 / 3.0), dt, Jm)
    return A * H - (2.0 * mu / eta) * je23


def _cv_from_rate(A, C, base, det_old, dt):
    B = base + dt * A * C
    kappa = (det3(B) / det_old) ** (1.0 / 3.0)
    return B / kappa


def _je23(I3, det_base, det_old):
    """Je^(-2/3) = (det C / det_old)^(-1/3) = (I3 det_base / det_old)^(-1/3)."""
    return (I3 * det_base / det_old) ** (-1.0 / 3.0)


def _rate_residual(A, F, base_inv, det_base, det_old, dt, mu, eta, Jm):
    I1, I2, I3 = _flow_invariants(F, base_inv, det_base)
    return _rate_residual_inv(A, I1, I2, I3, _je23(I3, det_base, det_old), dt, mu, eta, Jm)


@jax.custom_jvp
def _solve_rate(F, base_inv, det_base, det_old, dt, mu, eta, Jm):
    """Scalar Newton for A (primal); derivatives by the implicit function theorem."""
    I1, I2, I3 = _flow_invariants(F, base_inv, det_base)
    je23 = _je23(I3, det_base, det_old)
    i3 = I3 ** (-1.0 / 3.0)
    c = (2.0 * mu / eta) * je23
    A0 = c / jnp.maximum(gent_margin(i3 * I1, Jm), 1e-3)

    def body(carry):
        # the residual A H - c of _rate_residual_inv and its slope H + A dH/dA
        A, _, k = carry
        H, dH = _rate_margin(A, I1, I2, I3, i3, dt, Jm)
        step = (A * H - c) / (H + A * dH)
        return A - step, jnp.abs(step), k + 1

    def cond(carry):
        A, step, k = carry
        # quadratic convergence: after a step of 1e-12 |A| the error is at round-off
        return (step > 1e-12 * jnp.abs(A) + 1e-300) & (k < 50)

    A, _, _ = jax.lax.while_loop(cond, body, (A0, jnp.asarray(jnp.inf, A0.dtype), 0))
    return A


def _solve_rate_jvp(primals, tangents):
    """Implicit function theorem on the rate residual, differentiated only along the inputs that
    carry a tangent (symbolic zeros skipped: the consistent tangent perturbs F alone)."""
    A = _solve_rate(*primals)
    g_A = jax.grad(_rate_residual, argnums=0)(A, *primals)
    live = [i for i, t in enumerate(tangents) if not isinstance(t, SymbolicZero)]
    if not live:
        return A, jnp.zeros_like(A)

    def residual(*xs):
        args = list(primals)
        for i, x in zip(live, xs):
            args[i] = x
        return _rate_residual(A, *args)

    _, g_dot = jax.jvp(residual, [primals[i] for i in live], [tangents[i] for i in live])
    return A, -g_dot / g_A


_solve_rate.defjvp(_solve_rate_jvp, symbolic_zeros=True)


def _update_unit(F, base, base_inv, det_base, det_old, dt, mu, eta, Jm):
    A = _solve_rate(F, base_inv, det_base, det_old, dt, mu, eta, Jm)
    return _cv_from_rate(A, gram3(F), base, det_old, dt)


def viscous_update(F, Cv_old, dt, mu, eta, Jm):
    """One backward-Euler step of the flow rule for one unit (Eqs. 37-39).

    Args:
      F: (3, 3) deformation gradient at the end of the step.
      Cv_old: (3, 3) viscous tensor at the start of the step.
      dt: step (s); mu (Pa), eta (Pa s), Jm (-): the unit's parameters.
    Returns:
      (3, 3) Cv at the end of the step; symmetric, det Cv = det Cv_old to round-off,
      differentiable in every argument (implicit function theorem).
    """
    Cv_old = jnp.asarray(Cv_old)
    det_old = det3(Cv_old)
    return _update_unit(F, Cv_old, inv3(Cv_old), det_old, det_old, dt, mu, eta, Jm)


def viscous_rate(F, Cv, mu, eta, Jm):
    """dCv/dt of the flow rule at (F, Cv) (docs/paper-notes.md form of Eq. 37). (3, 3)."""
    C = gram3(F)
    Je, I1e = _viscous_invariants(F, Cv)
    H = gent_margin(Je ** (-2.0 / 3.0) * I1e, Jm)
    A = (2.0 * mu / eta) * Je ** (-2.0 / 3.0) / H
    return A * (C - I1e / 3.0 * Cv)


def update_all_units(F, Cv_old, dt, mat: Material):
    """The flow-rule step of every unit: Cv_old (n_units, 3, 3) -> Cv_new (n_units, 3, 3).

    ``Cv_old`` is either the viscous state at the step's start (backward Euler over ``dt``,
    Eq. 39) or a ``FlowStep`` carrying its own step data (``dt`` is then unused)."""
    if not mat.n_units:
        return Cv_old.base if isinstance(Cv_old, FlowStep) else Cv_old
    # jnp.asarray: jit(vmap(custom_jvp)) rejects a closed-over numpy constant
    flow = Cv_old if isinstance(Cv_old, FlowStep) else backward_euler_flow_step(jnp.asarray(Cv_old), dt)
    return jax.vmap(_update_unit, in_axes=(None, 0, 0, 0, 0, 0, 0, 0, 0))(
        F, flow.base, flow.base_inv, flow.det_base, flow.det_old, flow.dt, mat.mu, mat.eta, mat.Jm)


# The point laws below are jitted: JAX caches an inner jit's traced program by its
# arguments' shapes, here those of one Gauss point, so every later simulation program of
# the same material structure (another mesh, output, scan length or solver) reuses the
# traced law and its vmapped and differentiated forms instead of tracing them again (the
# consistent tangent is about a third of a simulation program's tracing). XLA inlines them.
@jax.jit
def stress_and_update(F, E, Cv_old, dt, mat: Material, wmax=0.0):
    """First Piola-Kirchhoff stress at the end of a step and the updated Cv.

    P = d psi / d F at fixed Cv_new and Mullins factor eta (``mullins_factor`` from the
    point's history ``wmax``, J/m^3), with Cv_new = viscous_update(F, Cv_old); the total
    derivative dP/dF (forward-mode, ``stress_tangent_update_and_flow_tangent``) is the
    consistent tangent including dCv/dF and d eta/dF.

    Returns:
      P (3, 3) in Pa, Cv_new (n_units, 3, 3).
    """
    Cv_new = update_all_units(F, Cv_old, dt, mat)
    soft, _ = mullins_factor(F, wmax, mat)
    P = jax.grad(free_energy, argnums=0)(F, E, Cv_new, mat, True, soft)
    return P, Cv_new


@jax.jit
def stress_tangent_and_update(F, E, Cv_old, dt, mat: Material, wmax=0.0):
    """(P, D, Cv_new) with D = dP/dF (3, 3, 3, 3), D[i, j, k, l] = dP_ij / dF_kl, the
    consistent tangent."""
    P, D, Cv_new, _ = stress_tangent_update_and_flow_tangent(F, E, Cv_old, dt, mat, wmax)
    return P, jnp.transpose(D, (2, 3, 0, 1)), Cv_new


# The consistent tangent's forward pass, one lane per direction of F (and of p), keeps the
# lanes first in its results (D[k, l] = dP/dF_kl): jax.jacfwd moves them last, a strided
# copy of every per-point Jacobian (`python bench/tangent_layout.py`: the tangent and
# stiffness of the tube 4x8x1, 7.1-7.3 ms with it, 4.8-5.3 ms without).
_F_DIRECTIONS = np.eye(9).reshape(9, 3, 3)


def _tangent_lanes(f, F, extra_directions=None):
    """(f(F), its derivatives along the 9 unit directions of F, lanes first), f returning a
    pytree; with ``extra_directions`` (an argument x and its directions (n, ...)), f(F, x)
    and 9 + n lanes: the F directions at fixed x, then x's at fixed F."""
    dF = jnp.asarray(_F_DIRECTIONS)
    if extra_directions is None:
        return jax.vmap(lambda t: jax.jvp(f, (F,), (t,)), out_axes=(None, 0))(dF)
    x, dx = extra_directions
    tF = jnp.concatenate([dF, jnp.zeros((dx.shape[0], 3, 3))])
    tx = jnp.concatenate([jnp.zeros((9,) + dx.shape[1:]), dx])
    return jax.vmap(lambda a, b: jax.jvp(f, (F, x), (a, b)), out_axes=(None, 0))(tF, tx)


@jax.jit
def stress_tangent_update_and_flow_tangent(F, E, Cv_old, dt, mat: Material, wmax=0.0):
    """(P, D, Cv_new, Cv_F) with the derivative's direction first: D (3, 3, 3, 3),
    D[k, l, i, j] = dP_ij / dF_kl (``stress_tangent_and_update`` transposed), and Cv_F (3, 3,
    n_units, 3, 3) = dCv_new / dF_kl: the flow rule's derivative, a by-product of the
    consistent tangent's forward pass (no extra work)."""
    (P, Cv_new), (dP, dCv) = _tangent_lanes(lambda F_: stress_and_update(F_, E, Cv_old, dt, mat, wmax), F)
    return P, dP.reshape(3, 3, 3, 3), Cv_new, dCv.reshape((3, 3) + dCv.shape[1:])


@jax.jit
def mixed_stress_and_update(F, E, Cv_old, dt, p, mat: Material, wmax=0.0):
    """Mixed form at one point: (P (3, 3) Pa, r_p = d psi / d p = J - 1 - p / K (-), Cv_new)."""
    Cv_new = update_all_units(F, Cv_old, dt, mat)
    soft, _ = mullins_factor(F, wmax, mat)
    P, r_p = jax.grad(mixed_free_energy, argnums=(0, 3))(F, E, Cv_new, p, mat, soft)
    return P, r_p, Cv_new


@jax.jit
def mixed_tangent_and_update(F, E, Cv_old, dt, p, mat: Material, wmax=0.0):
    """Mixed form at one point: (P, r_p, D (3, 3, 3, 3), dP/dp (3, 3), dr_p/dp, Cv_new, Cv_F
    (3, 3, n_units, 3, 3)), the derivatives along F with their direction first:
    D[k, l, i, j] = dP_ij / dF_kl, Cv_F[k, l] = dCv_new / dF_kl.

    D is the consistent tangent (dCv/dF included); dr_p/dF = dP/dp (= cof F); Cv_new does
    not depend on p. dCv_new/dF is a by-product of D's forward pass."""
    f = lambda F_, p_: mixed_stress_and_update(F_, E, Cv_old, dt, p_, mat, wmax)  # noqa: E731
    (P, r_p, Cv_new), (dP, dr, dCv) = _tangent_lanes(f, F, (p, jnp.ones((1,) + jnp.shape(p))))
    return P, r_p, dP[:9].reshape(3, 3, 3, 3), dP[9], dr[9], Cv_new, dCv[:9].reshape((3, 3) + dCv.shape[1:])


@jax.jit
def _margins_and_dets(F, Cv, mat: Material):
    """(min_gent_margin, det F) at the points F (n, 3, 3), Cv (n, n_units, 3, 3): one compiled
    program per shape (eager, each operation would be compiled on its own)."""
    return jax.vmap(min_gent_margin, in_axes=(0, 0, None))(F, Cv, mat), jax.vmap(det3)(F)


def check_state(F, Cv, mat: Material, where: str = "") -> None:
    """Raise GentLimitError (eager, not jittable) if any point is at or past a Gent limit.

    Args:
      F: (..., 3, 3) deformation gradients; Cv: (..., n_units, 3, 3).
    """
    F = jnp.asarray(F)
    batch = F.shape[:-2]
    Ff = F.reshape(-1, 3, 3)
    Cvf = jnp.asarray(Cv).reshape((-1, mat.n_units, 3, 3)) if mat.n_units else jnp.zeros((Ff.shape[0], 0, 3, 3))
    H, J = (np.asarray(x) for x in _margins_and_dets(Ff, Cvf, mat))
    point = lambda i: tuple(int(k) for k in np.unravel_index(i, batch))
    if np.any(J <= 0):
        i = int(np.argmin(J))
        raise GentLimitError(f"{where}inverted material: det F = {J[i]:.3e} <= 0 at point {point(i)}")
    if not (np.all(np.isfinite(J)) and np.all(np.isfinite(H))):
        i = int(np.flatnonzero(~(np.isfinite(J) & np.isfinite(H)))[0])
        raise GentLimitError(f"{where}non-finite state (det F = {J[i]:.3e}, Gent margin {H[i]:.3e}) at point {point(i)}")
    if np.any(H <= 0):
        i = int(np.argmin(H))
        raise GentLimitError(
            f"{where}state past the Gent limit: 1 - (I1bar - 3)/Jm = {H[i]:.3e} <= 0 at point {point(i)}"
        )


def evaluate(F, E, Cv, mat: Material):
    """Eager, checked evaluation: (psi, P) at one or many points; raises GentLimitError.

    Args:
      F: (..., 3, 3); E: (..., 3); Cv: (..., n_units, 3, 3).
    """
    check_state(F, Cv, mat)
    return _energy_and_stress(jnp.asarray(F), jnp.asarray(E), jnp.asarray(Cv), mat)


@jax.jit
def _energy_and_stress(F, E, Cv, mat: Material):
    """(psi, P) at the points F (..., 3, 3) (``evaluate``), compiled once per shape."""
    fn = lambda F_, E_, Cv_: (free_energy(F_, E_, Cv_, mat), jax.grad(free_energy)(F_, E_, Cv_, mat))
    for _ in range(F.ndim - 2):
        fn = jax.vmap(fn)
    return fn(F, E, Cv)
