r"""Independent reduced (homogeneous, incompressible) reference models.

These models verify the 3-D finite-element simulator. They are derived here by
hand from the free energy of docs/paper-notes.md and do **not** use ``dejax.material``:
every stress and rate below is written out explicitly, so a mistake in the
simulator's energy, autodiff or flow-rule update cannot cancel against the same
mistake here. SI units throughout: m, s, Pa, Pa s, V, F/m.

Free energy per reference volume (docs/paper-notes.md, Eqs. 18-20), with exact
incompressibility (J = 1, so the K terms drop and Je = 1 because det Cv = 1)::

    psi = -mu_inf Jm_inf/2 ln H_inf - sum_s mu_s Jm_s/2 ln H_s - eps/2 E.C^-1 E
    H_inf = 1 - (I1 - 3)/Jm_inf,  I1 = tr C
    H_s   = 1 - (I1e_s - 3)/Jm_s, I1e_s = tr(C Cv_s^-1)

so d psi / d I1 = mu_inf/(2 H_inf) and d psi / d I1e_s = mu_s/(2 H_s).

Viscous flow rule (docs/paper-notes.md, Eq. 37 cleaned up), with Je = 1::

    dCv_s/dt = (2 mu_s/eta_s)/H_s (C - tr(C Cv_s^-1) Cv_s/3)

For coaxial diagonal C = diag(l_i^2), Cv = diag(c_i) this is
``dc_i/dt = A (l_i^2 - I1e c_i/3)``, which keeps c_1 c_2 c_3 = 1.

**Small-strain relaxation time.** Linearising about C = Cv = I (C = I + 2e,
Cv = I + 2 e_v) gives d e_v/dt = (2 mu_s/eta_s) dev(e - e_v), while the unit's
stress is 2 mu_s dev(e - e_v). The unit therefore relaxes with

    tau_s = eta_s / (2 mu_s)

i.e. half of a "tau = eta/mu" read off the paper (that value belongs to a
Maxwell dashpot sigma = 2 eta de_v/dt; this flow rule is sigma = eta de_v/dt).
For the paper's block (mu_1 = 67 kPa, eta_1 = 3000 Pa s) tau_1 = 22.4 ms, not
45 ms. ``relaxation_time(mu, eta)`` returns this value. Under a *held voltage* the
block creeps more slowly: linearising the block equations below,
6 mu_inf e + 6 mu_1 (e - v) = eps E^2 and dv/dt = (2 mu_1/eta_1)(e - v), so
tau_creep = eta_1 (mu_inf + mu_1)/(2 mu_1 mu_inf) = 44.8 ms, which coincides with
"eta_1/mu_1 = 45 ms" only because mu_inf = mu_1 there. Either way the
viscous delay is short against the 1 s ramp, and by t = 3 s the unit is fully
relaxed: the paper notes' lam(3 s) values are the mu_inf-only Gent equilibrium.

**Verdict on the paper notes' block equations** ("Homogeneous block"): they
are correct. Derivation: F = diag(lam, lam, lam^-2), Cv = diag(xi^2, xi^2,
xi^-4), E = phi/L along z, so I1 = 2 lam^2 + lam^-4, I1e = 2 lam^2 xi^-2 +
lam^-4 xi^4, E.C^-1 E = lam^4 E^2. The traction-free block at fixed voltage is
stationary in lam::

    d psi/d lam = 2 mu_inf (lam - lam^-5)/H_inf
                + sum_s 2 mu_s (lam xi_s^-2 - lam^-5 xi_s^4)/H_s - 2 eps E^2 lam^3 = 0

and dividing by 2 lam^3 gives the paper notes' equilibrium (for one unit, after
dividing by mu_inf). The xx-component of the flow rule,
2 xi dxi/dt = A (lam^2 - I1e xi^2/3) = A (lam^2 - lam^-4 xi^6)/3, gives
dxi/dt = mu_s/(3 eta_s H_s) (lam^2 xi^-1 - lam^-4 xi^5), the paper notes' evolution
(the zz-component gives the same equation). The printed Eq. (63) of the paper
is wrong, as the paper notes say (rate of xi, not lambda_x; limit Jm_1).

All public functions accept numpy (or python) inputs and return numpy arrays.
Time-dependent loadings ``phi_fn`` / ``lam_fn`` are evaluated inside the
diffrax vector field, so they must be JAX-traceable functions of a scalar
time (e.g. written with ``jnp``). Pass them as ``jax.tree_util.Partial`` with
array arguments (see :func:`eq41`) to reuse one compilation for many loadings.
"""
from __future__ import annotations

import math

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from scipy import optimize

import dejax  # noqa: F401  (enables float64)

__all__ = [
    "gent_equibiaxial_voltage",
    "gent_equibiaxial_stretch",
    "gent_limit_stretch",
    "pullin_voltage",
    "relaxation_time",
    "eq41_voltage",
    "eq41",
    "ramp_hold_stretch",
    "ramp_hold",
    "homogeneous_block_response",
    "homogeneous_uniaxial_response",
    "ReferenceSolveError",
]


class ReferenceSolveError(ValueError):
    """The reduced model has no admissible state (pull-in, Gent limit) or its solver failed."""


# ---------------------------------------------------------------------------
# 1. Closed-form quasi-static equal-biaxial Gent equilibrium (no viscosity)
# ---------------------------------------------------------------------------


def _eb_ratio(lam, Jm):
    """f(lam) = (lam^-2 - lam^-8)/H_inf, H_inf = 1 - (2 lam^2 + lam^-4 - 3)/Jm."""
    lam = np.asarray(lam, dtype=float)
    H = 1.0 - (2.0 * lam**2 + lam**-4 - 3.0) / Jm
    return (lam**-2 - lam**-8) / H, H


def _eb_ratio_slope_num(lam, Jm):
    """Numerator of d f/d lam: N' H - N H' (same sign as f' where H > 0)."""
    N = lam**-2 - lam**-8
    dN = -2.0 * lam**-3 + 8.0 * lam**-9
    H = 1.0 - (2.0 * lam**2 + lam**-4 - 3.0) / Jm
    dH = -(4.0 * lam - 4.0 * lam**-5) / Jm
    return dN * H - N * dH


def gent_limit_stretch(Jm):
    """Equal-biaxial stretch lam > 1 at which H = 1 - (2 lam^2 + lam^-4 - 3)/Jm = 0."""
    Jm = float(Jm)
    g = lambda l: 2.0 * l * l + l**-4 - 3.0 - Jm
    hi = math.sqrt((Jm + 3.0) / 2.0) + 1.0  # 2 hi^2 - 3 > Jm
    return optimize.brentq(g, 1.0 + 1e-15, hi, xtol=1e-15, rtol=1e-15, maxiter=500)


def gent_equibiaxial_voltage(lam, L, mu_inf, Jm_inf, eps):
    r"""Voltage (V) holding a hyperelastic Gent membrane at equal-biaxial stretch ``lam``.

    Quasi-static, incompressible, equal-biaxial (lam, lam, lam^-2), no viscous unit,
    nominal field E = phi/L through the thickness L (m)::

        (lam^-2 - lam^-8)/H_inf = (eps/mu_inf) (phi/L)^2
        H_inf = 1 - (2 x^2 + x^-4 - 3)/Jm_inf

    i.e. phi = L sqrt(mu_inf/eps (lam^-2 - lam^-8)/H_inf), for 1 <= lam < the Gent
    limit. mu_inf in Pa, eps in F/m. Vectorised over ``lam``; raises ValueError for
    lam < 1 or at/past the Gent limit.
    """
    lam = np.asarray(lam, dtype=float)
    if np.any(lam < 1.0):
        raise ValueError(f"gent_equibiaxial_voltage: lam must be >= 1 (got min {lam.min()})")
    f, H = _eb_ratio(lam, float(Jm_inf))
    if np.any(H <= 0.0):
        raise ValueError(
            f"gent_equibiaxial_voltage: lam = {lam.max()} is at or past the Gent limit "
            f"{gent_limit_stretch(Jm_inf)} (Jm_inf = {Jm_inf})"
        )
    return L * np.sqrt(mu_inf / eps * f)


def pullin_voltage(L, mu_inf, Jm_inf, eps):
    r"""Pull-in (first local maximum) of phi(lam) on the equal-biaxial Gent curve.

    Returns ``(phi_max, lam_at_max)``: lam_at_max is the first root lam > 1 of
    d/dlam [(lam^-2 - lam^-8)/H_inf] = 0 (found by scanning and a bracketed solve),
    phi_max = gent_equibiaxial_voltage(lam_at_max). Neo-Hookean limit (Jm -> inf):
    lam = 2^(1/3), phi_max = L sqrt(mu/eps) sqrt(3/4 2^(-2/3)) ~ 0.6874 L sqrt(mu/eps).

    For stiff enough Gent limits (Jm_inf below ~ 10) phi(lam) increases monotonically up
    to the Gent limit and there is no pull-in: returns ``(inf, nan)``.
    """
    Jm = float(Jm_inf)
    lam_lim = gent_limit_stretch(Jm)
    grid = 1.0 + (lam_lim - 1.0) * np.linspace(0.0, 1.0, 4001)[1:-1] ** 1.5
    s = _eb_ratio_slope_num(grid, Jm)
    neg = np.nonzero(s <= 0.0)[0]
    if neg.size == 0:
        return math.inf, math.nan
    i = int(neg[0])
    lo = grid[i - 1] if i > 0 else 1.0 + 1e-12
    lam_max = optimize.brentq(lambda l: _eb_ratio_slope_num(l, Jm), lo, grid[i], xtol=1e-15, rtol=1e-15, maxiter=500)
    return float(gent_equibiaxial_voltage(lam_max, L, mu_inf, Jm, eps)), float(lam_max)


def gent_equibiaxial_stretch(phi, L, mu_inf, Jm_inf, eps):
    r"""Inverse of :func:`gent_equibiaxial_voltage` on the stable (first) branch.

    Solves (lam^-2 - lam^-8)/H_inf = (eps/mu_inf)(phi/L)^2 for lam in [1, lam_pullin]
    (or [1, Gent limit) when there is no pull-in) with a bracketed root solver
    (brentq, |d lam| ~ 1e-15). Vectorised over ``phi`` (V). Raises ValueError naming
    the voltage and the pull-in voltage if |phi| exceeds the pull-in voltage.
    """
    phi = np.asarray(phi, dtype=float)
    phi_max, lam_max = pullin_voltage(L, mu_inf, Jm_inf, eps)
    hi = lam_max if np.isfinite(phi_max) else gent_limit_stretch(Jm_inf) * (1.0 - 1e-15)
    bad = np.abs(phi) > phi_max
    if np.any(bad):
        raise ValueError(
            f"gent_equibiaxial_stretch: voltage phi = {float(np.abs(phi)[bad].max()):.10g} V exceeds the "
            f"pull-in (maximum) voltage {phi_max:.10g} V (at lam = {lam_max:.8f}); no equilibrium on the "
            "stable branch"
        )
    target = eps / mu_inf * (phi / L) ** 2
    out = np.empty(phi.shape)
    for k, tk in np.ndenumerate(target):
        if tk == 0.0:
            out[k] = 1.0
            continue
        g = lambda l: float(_eb_ratio(l, float(Jm_inf))[0]) - tk
        if g(hi) <= 0.0:  # at the pull-in voltage itself (to round-off)
            out[k] = hi
        else:
            out[k] = optimize.brentq(g, 1.0, hi, xtol=1e-15, rtol=1e-15, maxiter=500)
    return out if out.ndim else float(out)


def relaxation_time(mu, eta):
    """Small-strain relaxation time of one viscous unit under the docs/paper-notes.md flow rule: eta/(2 mu) (s)."""
    return np.asarray(eta, dtype=float) / (2.0 * np.asarray(mu, dtype=float))


# ---------------------------------------------------------------------------
# Loading history of the block (paper Eq. 41)
# ---------------------------------------------------------------------------


def eq41_voltage(t, phi_m):
    """Ramp-and-hold voltage (V) of Eq. (41): phi_m/2 (1 + sin(pi t - pi/2)) for t <= 1 s, then phi_m.

    jnp-compatible (and numpy-compatible via jnp). C^1 at t = 1 s.
    """
    t = jnp.asarray(t)
    ramp = 0.5 * phi_m * (1.0 + jnp.sin(jnp.pi * jnp.minimum(t, 1.0) - 0.5 * jnp.pi))
    return jnp.where(t <= 1.0, ramp, phi_m * jnp.ones_like(ramp))


def eq41(phi_m):
    """``t -> eq41_voltage(t, phi_m)`` as a pytree Partial (one compilation for every phi_m)."""
    return jax.tree_util.Partial(eq41_voltage, phi_m=jnp.asarray(phi_m, dtype=float))


def ramp_hold_stretch(t, lam_max, t_ramp, smooth=False):
    """Stretch history: ramp from 1 to lam_max over t_ramp (s), then hold (jnp-compatible).

    Linear ramp, or the C^1 ramp 1 + (lam_max - 1)(1 - cos(pi t/t_ramp))/2 if ``smooth``;
    t_ramp = 0 is a step to lam_max at t = 0.
    """
    t = jnp.asarray(t)
    pos = t_ramp > 0
    frac = jnp.where(pos, jnp.clip(t / jnp.where(pos, t_ramp, 1.0), 0.0, 1.0), 1.0)
    frac = jnp.where(smooth, 0.5 * (1.0 - jnp.cos(jnp.pi * frac)), frac)
    return 1.0 + (lam_max - 1.0) * frac


def ramp_hold(lam_max, t_ramp, smooth=False):
    """``t -> ramp_hold_stretch(t, lam_max, t_ramp, smooth)`` as a pytree Partial.

    All three numbers are arrays, so one compilation serves every ramp (and the step).
    """
    return jax.tree_util.Partial(
        ramp_hold_stretch, lam_max=jnp.asarray(lam_max, dtype=float), t_ramp=jnp.asarray(t_ramp, dtype=float),
        smooth=jnp.asarray(bool(smooth)),
    )


# ---------------------------------------------------------------------------
# Generic machinery: scalar Newton with implicit-function derivatives, unit
# padding, and the diffrax call.
# ---------------------------------------------------------------------------


def _newton_primal(resid, z0, x, t, args):
    g = lambda z: resid(z, x, t, args)
    dg = jax.grad(g)

    def body(c):
        z, _, k = c
        step = g(z) / dg(z)
        step = jnp.clip(step, -0.2 * jnp.abs(z), 0.2 * jnp.abs(z))  # step limiter
        return z - step, jnp.abs(step), k + 1

    def cond(c):
        z, step, k = c
        return (step > 1e-14 * jnp.abs(z)) & (k < 80)  # a NaN step stops the loop

    z, step, _ = jax.lax.while_loop(cond, body, (z0, jnp.asarray(jnp.inf, z0.dtype), 0))
    ok = jnp.isfinite(z) & (step <= 1e-10 * jnp.abs(z)) & jnp.isfinite(g(z))
    return jnp.where(ok, z, jnp.nan)


def _bracketed_primal(resid, lo, hi, x, t, args):
    """Root of resid(., x, t, args), increasing on [lo, hi] with resid(lo) <= 0 <= resid(hi):
    Newton steps, bisection where a step leaves the bracket (safe where the residual bends
    sharply, as Mullins softening makes it)."""
    g = lambda z: resid(z, x, t, args)
    dg = jax.grad(g)

    def body(c):
        lo, hi, z, _, k = c
        gz = g(z)
        lo, hi = jnp.where(gz < 0, z, lo), jnp.where(gz < 0, hi, z)
        zn = z - gz / dg(z)
        zn = jnp.where(jnp.isfinite(zn) & (zn > lo) & (zn < hi), zn, 0.5 * (lo + hi))
        return lo, hi, zn, jnp.abs(zn - z), k + 1

    def cond(c):
        _, _, z, step, k = c
        return (step > 1e-14 * jnp.abs(z)) & (k < 200)

    _, _, z, step, _ = jax.lax.while_loop(cond, body, (lo, hi, lo, jnp.asarray(jnp.inf, lo.dtype), 0))
    ok = jnp.isfinite(z) & (step <= 1e-10 * jnp.abs(z)) & jnp.isfinite(g(z))
    return jnp.where(ok, z, jnp.nan)


def _newton_impl(resid, static, z0, x, t, dyn):
    args = eqx.combine(dyn, static)
    if z0.shape == (2,):  # a bracket [lo, hi]
        return _bracketed_primal(resid, z0[0], z0[1], x, t, args)
    return _newton_primal(resid, z0, x, t, args)


_newton_impl = jax.custom_jvp(_newton_impl, nondiff_argnums=(0, 1))


@_newton_impl.defjvp
def _newton_jvp(resid, static, primals, tangents):
    z0, x, t, dyn = primals
    _, dx, dt, ddyn = tangents
    z = _newton_impl(resid, static, z0, x, t, dyn)
    r = lambda z_, x_, t_, d_: resid(z_, x_, t_, eqx.combine(d_, static))
    rz = jax.grad(r)(z, x, t, dyn)
    _, rdot = jax.jvp(lambda x_, t_, d_: r(z, x_, t_, d_), (x, t, dyn), (dx, dt, ddyn))
    return z, -rdot / rz


def _newton(resid, z0, x, t, args):
    """Root z of resid(z, x, t, args) = 0 from z0 (NaN if Newton fails or the root is inadmissible);
    z0 of shape (2,) is a bracket [lo, hi] of an increasing residual (``_bracketed_primal``).

    Derivatives with respect to x, t and the array leaves of args follow from the implicit
    function theorem (custom JVP), so Jacobians for implicit ODE solvers are exact.
    """
    dyn, static = eqx.partition(args, eqx.is_array)
    t = jnp.asarray(t, dtype=float)
    return _newton_impl(resid, static, jnp.asarray(z0, dtype=float), x, t, dyn)


_PAD = 4  # units are padded with inert ones (mu = 0, Jm = inf) to a multiple of this: fewer compilations


def _units(mu, Jm, eta):
    mu = np.atleast_1d(np.asarray(mu, dtype=float)).reshape(-1)
    Jm = np.atleast_1d(np.asarray(Jm, dtype=float)).reshape(-1)
    eta = np.atleast_1d(np.asarray(eta, dtype=float)).reshape(-1)
    if not (mu.shape == Jm.shape == eta.shape):
        raise ValueError(f"mu, Jm, eta need one entry per viscous unit: got {mu.shape}, {Jm.shape}, {eta.shape}")
    if np.any(mu <= 0) or np.any(Jm <= 0) or np.any(eta <= 0):
        raise ValueError("mu, Jm, eta of every viscous unit must be > 0")
    return mu, Jm, eta


def _padded(mu, Jm, eta):
    """Pad to a multiple of _PAD with inert units: mu = 0 (no stress, zero rate), Jm = inf (H = 1), eta = 1."""
    n = mu.size
    m = max(_PAD, -(-n // _PAD) * _PAD)
    pad = lambda a, v: np.concatenate([a, np.full(m - n, v)])
    return pad(mu, 0.0), pad(Jm, np.inf), pad(eta, 1.0)


def _stiffness(t0, t1, mu, eta):
    """Time span over the smallest small-strain relaxation time eta_s/(2 mu_s) (0 without units)."""
    return 0.0 if mu.size == 0 else float((t1 - t0) / np.min(eta / (2.0 * mu)))


def _diffeqsolve(field, y0, t0, ts, args, solver, rtol, atol, max_steps):
    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(field),
        solver,
        t0=t0,
        t1=ts[-1],
        dt0=None,
        y0=y0,
        args=args,
        saveat=diffrax.SaveAt(ts=ts),
        # Steps land on the output times: dense interpolation of a stiff (fast-relaxing) unit
        # between large implicit steps is far less accurate than the step end values.
        # dtmin: a state with no admissible equilibrium (NaN rates) fails fast instead of
        # exhausting max_steps with ever smaller rejected steps. It sits at round-off (1e-16 of
        # the span): a step clipped to an output time can leave a remainder of a few 1e-16 s
        # before that time (seen at 3 Hz, 120 outputs per second: 1e-13 made the solve fail).
        stepsize_controller=diffrax.PIDController(
            rtol=rtol, atol=atol, step_ts=ts, dtmin=1e-16 * (ts[-1] - t0), force_dtmin=False
        ),
        max_steps=max_steps,
        throw=False,
    )
    return sol.ys, sol.result == diffrax.RESULTS.successful, sol.stats["num_steps"]


def _check_run(ok, nsteps, max_steps, what, ts=None, states=None):
    if not bool(ok):
        where = ""
        if ts is not None and states is not None:
            fin = np.all(np.isfinite(np.asarray(states).reshape(len(ts), -1)), axis=1)
            where = (f" before t = {ts[int(np.argmin(fin))]} s" if not fin.all() else "")
        raise ReferenceSolveError(
            f"{what}: time integration failed{where} after {int(nsteps)} steps (max_steps = {max_steps}); "
            "the state probably left the admissible set (no equilibrium past pull-in, or the Gent "
            "limit 1 - (I1 - 3)/Jm <= 0 reached), or the problem is too stiff for the step budget "
            "(raise max_steps, or pass an implicit diffrax solver with rtol ~ 1e-8)"
        )


def _times(t, t0):
    t = np.atleast_1d(np.asarray(t, dtype=float))
    if t.ndim != 1 or np.any(np.diff(t) < 0):
        raise ValueError("t must be a 1-D non-decreasing array of times (s)")
    if t[0] < t0:
        raise ValueError(f"requested time {t[0]} precedes the start time t0 = {t0}")
    return t


def _bucket(ts):
    """Pad the output times (repeating the last) to a multiple of 16: fewer compilations."""
    m = max(16, -(-ts.size // 16) * 16)
    return jnp.asarray(np.concatenate([ts, np.full(m - ts.size, ts[-1])]))


def _nan_unless(ok, v):
    return jnp.where(ok, v, jnp.nan)


# ---------------------------------------------------------------------------
# 2. Homogeneous equal-biaxial block with N viscous units
# ---------------------------------------------------------------------------


def _block_gent_energy(x, p):
    """W/mu_inf: the equilibrium branch's equal-biaxial Gent energy at the in-plane stretch x."""
    return -0.5 * p["Jm_inf"] * jnp.log(1.0 - (2.0 * x**2 + x**-4 - 3.0) / p["Jm_inf"])


def _block_resid(lam, state, t, args):
    """[sum of elastic terms - eps (phi/L)^2] / mu_inf of the equal-biaxial block (NaN if inadmissible).

    ``state``: xi (the units' stretches), or (xi, lam_max) with Mullins softening (lam_max the
    largest stretch so far: W is increasing in the stretch, so the largest energy is W(lam_max))."""
    p, phi_fn = args
    xi, lam_max = state if isinstance(state, tuple) else (state, None)
    phi = phi_fn(t)
    # the equilibrium branch at the stretch x = lam lam_pre from the film's natural state (a
    # kinematic pre-stretch): d/dlam Gent(x) / (2 mu_inf lam^3) = (lam_pre^2 lam^-2 - lam_pre^-4 lam^-8) / H_inf
    # (the same arithmetic as without it when lam_pre = 1)
    lp = p["lam_pre"]
    x = lam * lp
    Hinf = 1.0 - (2.0 * x**2 + x**-4 - 3.0) / p["Jm_inf"]
    Hs = 1.0 - (2.0 * lam**2 * xi**-2 + lam**-4 * xi**4 - 3.0) / p["Jm"]
    r = (lp**2 * lam**-2 - lp**-4 * lam**-8) / Hinf
    if lam_max is not None:
        # Ogden-Roxburgh: the Gent term's stress times eta = 1 - d erf((W_max - W)/m), eta held
        W = p["mu_inf"] * _block_gent_energy(x, p)
        W_max = jnp.maximum(p["mu_inf"] * _block_gent_energy(lam_max * lp, p), W)
        r = r * (1.0 - p["mullins_d"] * jax.scipy.special.erf((W_max - W) / p["mullins_m"]))
    r = r + jnp.sum(p["mu"] / p["mu_inf"] * (lam**-2 * xi**-2 - lam**-8 * xi**4) / Hs)
    # electrostatic term, with the first-order electrostriction eps (1 + b (lam_z - 1)), lam_z = lam^-2:
    # d/dlam [-eps/2 (1 + b (lam^-2 - 1)) E^2 lam^4] / (2 lam^3) = -eps E^2 (1 - b + b lam^-2 / 2)
    b = p["eps_b"]
    r = r - p["eps"] / p["mu_inf"] * (phi / p["L"]) ** 2 * (1.0 - b + 0.5 * b * lam**-2)
    # equal-biaxial in-plane dead load (nominal stress s on the lateral faces): work 2 s (lam - 1)
    r = r - p["s_pre"] / p["mu_inf"] * lam**-3
    ok = (lam > 0) & (Hinf > 0) & jnp.all(Hs > 0)
    return _nan_unless(ok, r)


def _block_rate(lam, xi, t, args):
    """dxi_s/dt = mu_s/(3 eta_s H_s) (lam^2 xi_s^-1 - lam^-4 xi_s^5)."""
    p, _ = args
    Hs = 1.0 - (2.0 * lam**2 * xi**-2 + lam**-4 * xi**4 - 3.0) / p["Jm"]
    return p["mu"] / (3.0 * p["eta"] * Hs) * (lam**2 / xi - lam**-4 * xi**5)


def _block_lam(state, t, args):
    # warm start: the stretch at which the most relaxed unit would carry no stress (lam = xi),
    # not below the reference state: exact when all units are relaxed, 1 when they are frozen
    xi = state[0] if isinstance(state, tuple) else state
    lam = _newton(_block_resid, jnp.maximum(1.0, jnp.max(xi)), xi, t, args)
    if not isinstance(state, tuple):
        return lam
    # Mullins: eta < 1 only below lam_max, so the softened root lies between the virgin root
    # (just computed: softer means stretched further) and lam_max, where eta = 1 (the residual
    # bends sharply below lam_max: bracketed Newton)
    return _newton(_block_resid, jnp.stack([lam, jnp.maximum(state[1], lam)]), state, t, args)


def _block_field(t, xi, args):
    return _block_rate(_block_lam(xi, t, args), xi, t, args)


_LAM_MAX_BAND = 1e-7
"""lam_max follows a rising lam from within this band below it (a step in the switch would
stall the adaptive Runge-Kutta steps, whose stages put lam_max ahead of lam)."""


def _block_field_mullins(t, state, args):
    """(dxi/dt, dlam_max/dt): lam_max follows lam while lam is at its largest and rising
    (dlam/dt by the implicit function theorem at fixed lam_max), switched on linearly over
    ``_LAM_MAX_BAND`` below lam_max; else it stays."""
    xi, lam_max = state
    lam = _block_lam(state, t, args)
    dxi = _block_rate(lam, xi, t, args)
    _, dlam = jax.jvp(lambda x_, t_: _block_lam((x_, lam_max), t_, args), (xi, t), (dxi, jnp.ones_like(t)))
    on = jnp.clip(1.0 + (lam - lam_max) / _LAM_MAX_BAND, 0.0, 1.0)
    return dxi, on * jnp.maximum(dlam, 0.0)


@eqx.filter_jit
def _block_solve(t0, ts, args, solver, rtol, atol, max_steps, integrate, mullins=False):
    xi0 = jnp.ones(args[0]["mu"].shape)
    y0, field = ((xi0, jnp.ones(())), _block_field_mullins) if mullins else (xi0, _block_field)
    if integrate:
        ys, ok, nsteps = _diffeqsolve(field, y0, t0, ts, args, solver, rtol, atol, max_steps)
    else:
        ys = jax.tree_util.tree_map(lambda y: jnp.ones(ts.shape + y.shape), y0)
        ok, nsteps = jnp.asarray(True), jnp.asarray(0)
    lam = jax.vmap(lambda y, tt: _block_lam(y, tt, args))(ys, ts)
    return lam, ys[0] if mullins else ys, ok, nsteps


def homogeneous_block_response(
    t, phi_fn, L, mu_inf, Jm_inf, eps, mu, Jm, eta, rtol=1e-10, atol=1e-12, *, t0=0.0, solver=None,
    max_steps=1_000_000, return_xi=False, eps_b=0.0, prestress=0.0, prestretch=1.0, mullins_d=0.0, mullins_m=1e4,
):
    r"""Equal-biaxial stretch lam(t) of the incompressible viscoelastic Gent block (N >= 0 units).

    Kinematics lam_x = lam_y = lam, lam_z = lam^-2; Cv_s = diag(xi_s^2, xi_s^2, xi_s^-4);
    nominal field E = phi(t)/L along z; inertia neglected. Derived from psi (module
    docstring)::

        equilibrium:  mu_inf (lam_p^2 lam^-2 - lam_p^-4 lam^-8) / H_inf,  x = lam lam_p
                      + sum_s mu_s (lam^-2 xi_s^-2 - lam^-8 xi_s^4)/H_s
                      = eps (phi/L)^2 (1 - b + b lam^-2/2) + s lam^-3
        evolution:    dxi_s/dt = mu_s/(3 eta_s H_s) (lam^2 xi_s^-1 - lam^-4 xi_s^5)
        H_inf = 1 - (2 x^2 + x^-4 - 3)/Jm_inf
        H_s   = 1 - (2 lam^2 xi_s^-2 + lam^-4 xi_s^4 - 3)/Jm_s

    with xi_s(t0) = 1 (Cv = I at rest). For one unit this is exactly the paper notes' system.
    With Mullins softening (``mullins_d`` > 0) the equilibrium branch's term is multiplied by
    eta = 1 - d erf((W(lam_max) - W(lam))/m), W the branch's equal-biaxial Gent energy
    (W = -mu_inf Jm_inf/2 ln H_inf) and lam_max the largest stretch so far (W increases with
    the stretch for lam lam_p >= 1: the block under voltage only expands in plane).

    Method (index-1 DAE): an ODE in the viscous stretches xi only; at every right-hand-side
    evaluation the algebraic equilibrium is solved for lam by a scalar Newton iteration
    (step-limited, converged to round-off), warm-started at max(1, max_s xi_s), the stretch
    at which the most relaxed unit is stress-free (exact when all units are relaxed, the
    reference state when they are frozen; a few iterations). This keeps the constraint exact
    at every evaluation, whereas an index-reduced ODE in (lam, xi) (differentiated
    constraint) drifts off the equilibrium by the accumulated integration error. lam is
    differentiable in xi, t and the parameters through the implicit function theorem
    (custom JVP), so implicit diffrax solvers may be passed as ``solver``.

    Default solver: Tsit5 (explicit, 5th order). It is stability-limited for units much
    faster than the loading (cost ~ span / (eta/2mu) steps, still fine for
    eta/(2 mu) = 1.5e-6 s over 3 s). diffrax's ESDIRK solvers (Kvaerno3/4/5) were tried
    for such stiff units (diffrax 0.7.2, Eq. 41 loading, eta/(2 mu) = 1.5e-6 s): they
    stall (rejected steps without end) at rtol = 1e-10 and work at rtol = 1e-8 (Kvaerno5:
    same lam to 8 digits as Tsit5), so pass one only with such a tolerance.

    Args:
      t: output times (s), non-decreasing, >= t0.
      phi_fn: JAX-traceable voltage history phi(t) (V), e.g. ``eq41(phi_m)``.
      L: thickness (m); mu_inf (Pa), Jm_inf (-), eps (F/m): equilibrium branch.
      mu, Jm, eta: per-unit shear modulus (Pa), Gent limit (-), viscosity (Pa s);
        scalars or length-N sequences (N = 0 allowed: pass ``()``).
      rtol, atol: tolerances of the adaptive step-size controller (on xi).
      return_xi: also return xi(t) (len(t), N).
      eps_b: first-order electrostriction b (-): permittivity eps (1 + b (lam_z - 1)) with
        lam_z = lam^-2 the stretch along the field (default 0, the paper's model).
      prestress: nominal in-plane dead-load stress s (Pa) on the four lateral faces (default 0).
      prestretch: equal-biaxial kinematic pre-stretch lam_p (-) of the equilibrium branch
        (default 1): its natural state is lam_p^-1 in plane, the viscous units' the reference.
      mullins_d, mullins_m: Ogden-Roxburgh softening (-, Pa; default off): lam_max joins the
        ODE's state, rising with lam while lam is at its largest.
    Returns:
      lam(t) as a numpy array (and xi(t) if requested).
    Raises:
      ReferenceSolveError (a ValueError) when no admissible equilibrium exists along the
      history (pull-in, Gent limit) or the integration fails.
    """
    mu, Jm, eta = _units(mu, Jm, eta)
    n = mu.size
    ts = _times(t, t0)
    mup, Jmp, etap = _padded(mu, Jm, eta)
    p = {k: jnp.asarray(v, float) for k, v in dict(mu_inf=mu_inf, Jm_inf=Jm_inf, eps=eps, L=L, mu=mup, Jm=Jmp, eta=etap,
                                                   eps_b=eps_b, s_pre=prestress, lam_pre=prestretch,
                                                   mullins_d=mullins_d, mullins_m=mullins_m).items()}
    args = (p, phi_fn)
    integrate = bool(ts[-1] > t0)  # N = 0 runs through the same (padded, inert) path: one compilation
    solver = solver or diffrax.Tsit5()
    mullins = bool(mullins_d > 0)  # the softening's state only where it is on: the same program otherwise
    lam, xis, ok, nsteps = _block_solve(jnp.asarray(t0, float), _bucket(ts), args, solver, rtol, atol, max_steps,
                                        integrate, mullins)
    lam, xis = np.asarray(lam)[: ts.size], np.asarray(xis)[: ts.size]
    _check_run(ok, nsteps, max_steps, "homogeneous_block_response", ts, xis)
    if not np.all(np.isfinite(lam)):
        k = int(np.argmin(np.isfinite(lam)))
        raise ReferenceSolveError(
            f"homogeneous_block_response: no admissible equilibrium at t = {ts[k]} s (phi = "
            f"{float(phi_fn(ts[k]))} V): pull-in or Gent limit"
        )
    return (lam, xis[:, :n]) if return_xi else lam


# ---------------------------------------------------------------------------
# 3. Stretch-controlled uniaxial tension
# ---------------------------------------------------------------------------
#
# Mechanical only: F = diag(lam, lam^-1/2, lam^-1/2), Cv_s = diag(a^2, a^-1, a^-1).
#   I1 = lam^2 + 2/lam, I1e = lam^2 a^-2 + 2 a/lam.
#   Lateral faces traction free: sigma_2 = sigma_3 = 0 fixes the pressure, and
#   P11 = (sigma_1 - sigma_2)/lam = d W/d lam along the path, W(lam) = psi(uniaxial):
#     P11 = mu_inf (lam - lam^-2)/H_inf + sum_s mu_s (lam a_s^-2 - a_s lam^-2)/H_s
#   Flow rule, 11-component: 2 a da/dt = A (lam^2 - I1e a^2/3) = (2A/3)(lam^2 - a^3/lam):
#     da_s/dt = 2 mu_s/(3 eta_s H_s) (lam^2 a_s^-1 - lam^-1 a_s^2)
#   (the 22-component gives the same equation). Linearised: da/dt = (2 mu/eta)(lam - a).


def _uni_stress(lam, a, p):
    Hinf = 1.0 - (lam**2 + 2.0 / lam - 3.0) / p["Jm_inf"]
    Hs = 1.0 - (lam**2 / a**2 + 2.0 * a / lam - 3.0) / p["Jm"]
    P = p["mu_inf"] * (lam - lam**-2) / Hinf + jnp.sum(p["mu"] * (lam / a**2 - a / lam**2) / Hs, axis=-1)
    ok = (Hinf > 0) & jnp.all(Hs > 0, axis=-1)
    return _nan_unless(ok, P)


def _uni_field(t, a, args):
    p, lam_fn = args
    lam = lam_fn(t)
    Hs = 1.0 - (lam**2 / a**2 + 2.0 * a / lam - 3.0) / p["Jm"]
    Hs = _nan_unless(Hs > 0, Hs)
    return 2.0 * p["mu"] / (3.0 * p["eta"] * Hs) * (lam**2 / a - a**2 / lam)


# With a voltage across direction 3 (nominal field E = phi/thickness):
# F = diag(lam, l2, l3), l3 = 1/(lam l2); Cv_s = diag(c1, c2, c3), c3 = 1/(c1 c2), carried as
# g = (ln c1, ln c2). Electric term -eps/2 E^2 C^-1_33 = -eps/2 E^2 lam^2 l2^2. Writing
#   s_i = mu_inf l_i^2/H_inf + sum_s mu_s l_i^2/(c_si H_s)   (l_i dW_mech/dl_i)
# the lateral equilibrium dW/dl2 = 0 (faces 2 and 3 traction free) reads
#   s_2 - s_3 - eps E^2 / l3^2 = 0,  i.e. sigma_2 = sigma_3 (= 0) with the Maxwell stress,
# and the nominal stress P11 = dW/dlam at fixed l2 is
#   P11 = (s_1 - s_3 - eps E^2 / l3^2)/lam.
# Flow rule: d ln c_i/dt = A (l_i^2/c_i - I1e/3), A = 2 mu_s/(eta_s H_s).


def _uv_parts(lam, l2, g, p):
    l = jnp.stack([lam, l2, 1.0 / (lam * l2)])
    lg = jnp.concatenate([g, -jnp.sum(g, axis=-1, keepdims=True)], axis=-1)  # (N, 3) ln c
    Hinf = 1.0 - (jnp.sum(l**2) - 3.0) / p["Jm_inf"]
    r = l**2 * jnp.exp(-lg)  # (N, 3): l_i^2 / c_i
    I1e = jnp.sum(r, axis=-1)
    Hs = 1.0 - (I1e - 3.0) / p["Jm"]
    s = p["mu_inf"] * l**2 / Hinf + jnp.sum((p["mu"] / Hs)[:, None] * r, axis=0)
    ok = (l2 > 0) & (Hinf > 0) & jnp.all(Hs > 0)
    return l, s, r, I1e, Hs, ok


def _uv_resid(l2, g, t, args):
    p, lam_fn, phi_fn = args
    lam = lam_fn(t)
    E = phi_fn(t) / p["thickness"]
    l, s, _, _, _, ok = _uv_parts(lam, l2, g, p)
    return _nan_unless(ok, (s[1] - s[2] - p["eps"] * E**2 / l[2] ** 2) / p["mu_inf"])


def _uv_l2(g, t, args):
    # warm start: the symmetric (zero-voltage, isotropic-Cv) lateral stretch lam^-1/2
    return _newton(_uv_resid, jnp.asarray(args[1](t), float) ** -0.5, g, t, args)


def _uv_field(t, g, args):
    p, lam_fn, _ = args
    l2 = _uv_l2(g, t, args)
    _, _, r, I1e, Hs, _ = _uv_parts(lam_fn(t), l2, g, p)
    A = 2.0 * p["mu"] / (p["eta"] * Hs)
    return A[:, None] * (r[:, :2] - I1e[:, None] / 3.0)


def _uv_stress(l2, g, t, args):
    p, lam_fn, phi_fn = args
    lam = lam_fn(t)
    E = phi_fn(t) / p["thickness"]
    l, s, _, _, _, ok = _uv_parts(lam, l2, g, p)
    return _nan_unless(ok, (s[0] - s[2] - p["eps"] * E**2 / l[2] ** 2) / lam)


@eqx.filter_jit
def _uni_solve(t0, ts, args, solver, rtol, atol, max_steps, integrate):
    p, lam_fn = args
    a0 = jnp.ones(p["mu"].shape)
    if integrate:
        a, ok, nsteps = _diffeqsolve(_uni_field, a0, t0, ts, args, solver, rtol, atol, max_steps)
    else:
        a, ok, nsteps = jnp.ones(ts.shape + a0.shape), jnp.asarray(True), jnp.asarray(0)
    lam = jax.vmap(lam_fn)(ts)
    P = jax.vmap(lambda l_, a_: _uni_stress(l_, a_, p))(lam, a)
    return P, a, ok, nsteps


@eqx.filter_jit
def _uv_solve(t0, ts, args, solver, rtol, atol, max_steps, integrate):
    g0 = jnp.zeros((args[0]["mu"].shape[0], 2))
    if integrate:
        gs, ok, nsteps = _diffeqsolve(_uv_field, g0, t0, ts, args, solver, rtol, atol, max_steps)
    else:
        gs, ok, nsteps = jnp.zeros(ts.shape + g0.shape), jnp.asarray(True), jnp.asarray(0)
    l2 = jax.vmap(lambda g, tt: _uv_l2(g, tt, args))(gs, ts)
    P = jax.vmap(lambda z, g, tt: _uv_stress(z, g, tt, args))(l2, gs, ts)
    return P, l2, gs, ok, nsteps


def homogeneous_uniaxial_response(
    t, lam_fn, mu_inf, Jm_inf, mu, Jm, eta, eps=0.0, phi_fn=None, thickness=None, *,
    rtol=1e-10, atol=1e-12, t0=0.0, solver=None, max_steps=1_000_000, return_state=False,
):
    r"""Nominal stress P11(t) (Pa) of stretch-controlled uniaxial tension of an incompressible strip.

    Gent equilibrium branch + N viscous Gent units, Cv_s = I at t0 (a step in lam at t0
    is an instantaneous, elastic response). Lateral faces are traction free (the pressure
    is eliminated).

    Mechanical only (``phi_fn`` None): lam1 = lam(t), lam2 = lam3 = lam^-1/2,
    Cv_s = diag(a_s^2, a_s^-1, a_s^-1)::

        P11 = mu_inf (lam - lam^-2)/H_inf + sum_s mu_s (lam a_s^-2 - a_s lam^-2)/H_s
        da_s/dt = 2 mu_s/(3 eta_s H_s) (lam^2 a_s^-1 - lam^-1 a_s^2)
        H_inf = 1 - (lam^2 + 2/lam - 3)/Jm_inf,  H_s = 1 - (lam^2 a_s^-2 + 2 a_s/lam - 3)/Jm_s

    Linearised, da/dt = (2 mu_s/eta_s)(lam - a): relaxation time eta_s/(2 mu_s).
    Default solver: Tsit5, or Kvaerno5 when a unit is stiff on the time span (span over
    eta_s/(2 mu_s) above 2000); with C^1 stretch histories Kvaerno5 handles eta -> 0 at
    rtol = 1e-10 here (this ODE has no inner Newton solve).

    With a voltage phi(t) across direction 3 (reference thickness ``thickness``, nominal
    field E = phi/thickness) the symmetry lam2 = lam3 is lost and is *handled*: lam3 =
    1/(lam lam2), Cv_s = diag(c1, c2, 1/(c1 c2)) and lam2 solves the lateral equilibrium
    (faces 2 and 3 traction free, Maxwell stress included)::

        s_2 - s_3 - eps E^2 lam3^-2 = 0,   P11 = (s_1 - s_3 - eps E^2 lam3^-2)/lam
        s_i = mu_inf l_i^2/H_inf + sum_s mu_s l_i^2/(c_si H_s)
        d ln c_si/dt = 2 mu_s/(eta_s H_s) (l_i^2/c_si - I1e_s/3)

    (an index-1 DAE, integrated like :func:`homogeneous_block_response`: ODE in ln c with
    Newton for lam2 in every evaluation, warm-started at lam^-1/2; default solver Tsit5).

    Args:
      t: output times (s); lam_fn: JAX-traceable stretch history lam(t) (-), e.g.
        ``ramp_hold(lam_max, t_ramp)``.
      mu_inf (Pa), Jm_inf (-); mu (Pa), Jm (-), eta (Pa s): per viscous unit (N >= 0).
      eps (F/m), phi_fn (JAX-traceable, V), thickness (m): optional electrical loading.
      return_state: also return the internal state (a_s (len(t), N), or
        (lam2 (len(t),), ln c_1,2 (len(t), N, 2))).
    Returns:
      P11(t) as a numpy array (Pa).
    """
    mu, Jm, eta = _units(mu, Jm, eta)
    n = mu.size
    ts = _times(t, t0)
    mup, Jmp, etap = _padded(mu, Jm, eta)
    p = {k: jnp.asarray(v, float) for k, v in dict(mu_inf=mu_inf, Jm_inf=Jm_inf, eps=eps, mu=mup, Jm=Jmp, eta=etap).items()}
    tsj = _bucket(ts)
    k = ts.size
    t0j = jnp.asarray(t0, float)
    what = "homogeneous_uniaxial_response"
    integrate = bool(ts[-1] > t0)  # N = 0 runs through the same (padded, inert) path: one compilation
    if phi_fn is None:
        if solver is None:
            solver = diffrax.Kvaerno5() if _stiffness(t0, ts[-1], mu, eta) > 2000.0 else diffrax.Tsit5()
        P, a, ok, nsteps = _uni_solve(t0j, tsj, (p, lam_fn), solver, rtol, atol, max_steps, integrate)
        state = np.asarray(a)[:k, :n]
        _check_run(ok, nsteps, max_steps, what, ts, np.asarray(a)[:k])
    else:
        if thickness is None or not thickness > 0:
            raise ValueError(f"{what}: a voltage needs the reference thickness (got thickness = {thickness})")
        p["thickness"] = jnp.asarray(thickness, float)
        solver = solver or diffrax.Tsit5()
        P, l2, gs, ok, nsteps = _uv_solve(t0j, tsj, (p, lam_fn, phi_fn), solver, rtol, atol, max_steps, integrate)
        state = (np.asarray(l2)[:k], np.asarray(gs)[:k, :n])
        _check_run(ok, nsteps, max_steps, what, ts, np.asarray(gs)[:k])
    P = np.asarray(P)[:k]
    if not np.all(np.isfinite(P)):
        k = int(np.argmin(np.isfinite(P)))
        raise ReferenceSolveError(f"{what}: inadmissible state at t = {ts[k]} s (Gent limit or no lateral equilibrium)")
    return (P, state) if return_state else P
