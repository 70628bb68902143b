"""Generalized-alpha time stepping with Newton iterations (paper Sec. 3, Eqs. 31-35, 40).

The scheme (Arnold & Bruls form used by the paper) carries q, v = dq/dt, the
acceleration qdd and the algorithmic acceleration a:

    (1 - alpha_m) a_{n+1} + alpha_m a_n = (1 - alpha_f) qdd_{n+1} + alpha_f qdd_n
    q_{n+1} = q_n + h v_n + h^2 (1/2 - beta) a_n + h^2 beta a_{n+1}
    v_{n+1} = v_n + h (1 - gamma) a_n + h gamma a_{n+1}

and the equations of motion hold at t_{n+1}:

    M qdd_{n+1} + c_d M v_{n+1} + Q_int(q_{n+1}, Cv_{n+1}) - Q_ext(t_{n+1}) = 0   (Eq. 28)

with Cv_{n+1} the backward-Euler viscous update at F(q_{n+1}) (Eq. 37). Newton
solves for the free coordinates of q_{n+1}; the iteration matrix is
beta' M + gamma' c_d M + K with beta' = (1 - alpha_m)/((1 - alpha_f) beta h^2),
gamma' = gamma/(beta h) (Eq. 35).

In the mixed form (``model.build_model(volumetric="mixed")``, the default) the element
pressure unknowns p are solved with q and condensed element by element. ``QuasiStatic``
drops the inertia terms. Newton is globalized by a line search on the scaled residual
norm beside the admissibility safeguard, converges on the relative residual (1e-6, the
paper's tolerance), and a step that fails is cut back (``StepControl``: dt/2 down to
dt_min = 1e-6 s, growing back after easy sub-steps; outputs stay on the user's grid).

Derivatives: the converged step solution is differentiated implicitly
(``jax.custom_jvp``: K dz = -dR), never through the Newton iterations; the rule
is linear in the tangents, so reverse mode (``jax.grad``) works by transposition. A
differentiated run replays its accepted sub-steps as a fixed grid (``_run``'s jvp), so
derivatives hold through cut-backs.
"""
from __future__ import annotations

import dataclasses
import enum
import time as _time
import warnings
from typing import Callable

import equinox as eqx
import jax
from jax.ad_checkpoint import checkpoint_name
import jax.numpy as jnp
import numpy as np

from . import model as mdl
from . import linsolve
from .linsolve import DenseSolver, LinearSolver
from .material import FlowStep, bulk_modulus
from .model import Model
from .tensor import det3


GENT_LOCK_MARGIN = 1e-3
"""A converged state whose Gent margin H = 1 - (I1bar - 3)/Jm falls to this value (stress
amplified 1000-fold by 1/H) has reached the limiting stretch: reported as GENT_LIMIT. A
nearly incompressible body may otherwise slip past the isochoric limit by a large volume
change at GPa pressures, which is no physical state of an elastomer."""


class Status(enum.IntEnum):
    """Outcome of a step or a run, in the manner of diffrax's ``RESULTS``: each member is an
    integer code (carried through ``lax.scan``, stored by sweeps and benchmarks; 0 = success)
    with its human-readable ``message``, the one text ``SimulationError`` and the command
    line's failure reports give. Results files store the name (``fail_status``)."""

    def __new__(cls, code: int, message: str):
        member = int.__new__(cls, code)
        member._value_ = code
        member.message = message
        return member

    OK = 0, "completed"
    NEWTON_FAILED = 1, ("Newton iterations did not converge (diverging solve; possible electromechanical "
                        "instability or too large a time step)")
    GENT_LIMIT = 2, f"the Gent limiting stretch was reached (1 - (I1bar - 3)/Jm <= {GENT_LOCK_MARGIN:g})"
    NONFINITE = 3, "the state became non-finite (NaN or inf)"
    INVERTED = 4, "an element inverted (det F <= 0)"
    INSTABILITY = 5, ("an equilibrium instability (electromechanical pull-in or snap-through): the static tangent "
                      "lost positive definiteness, so Newton failed at the smallest step")


class SimulationError(RuntimeError):
    """A run failed: the message says what failed (``status.message``) and at which time."""

    def __init__(self, status: Status, time: float, step: int, detail: str = ""):
        self.status = Status(status)
        self.time = float(time)
        self.step = int(step)
        msg = f"simulation failed at t = {self.time:.6g} s (step {self.step}): {self.status.message}"
        super().__init__(msg + (f"; {detail}" if detail else ""))


FLOW_UPDATES = ("bdf2", "backward-euler")


def _check_flow_update(name: str) -> None:
    if name not in FLOW_UPDATES:
        raise ValueError(f"flow_update must be one of {FLOW_UPDATES}, got {name!r}")


@dataclasses.dataclass(frozen=True)
class GeneralizedAlpha:
    """Generalized-alpha parameters from the spectral radius at infinity (Eqs. 31-32).

    flow_update: time discretization of the viscous flow rule, "bdf2" (second order, the
    default) or "backward-euler" (the paper's Eq. 39, first order)."""

    rho_inf: float = 0.8
    flow_update: str = "bdf2"

    inertial = True

    def __post_init__(self):
        if not 0.0 <= self.rho_inf <= 1.0:
            raise ValueError(f"rho_inf must lie in [0, 1], got {self.rho_inf}")
        _check_flow_update(self.flow_update)

    @property
    def alpha_m(self) -> float:
        return (2.0 * self.rho_inf - 1.0) / (self.rho_inf + 1.0)

    @property
    def alpha_f(self) -> float:
        return self.rho_inf / (self.rho_inf + 1.0)

    @property
    def gamma(self) -> float:
        return 0.5 + self.alpha_f - self.alpha_m

    @property
    def beta(self) -> float:
        return 0.25 * (self.gamma + 0.5) ** 2

    def kinematics(self, s: "State", h, q):
        """(qdd_{n+1}, v_{n+1}, a_{n+1}) implied by q_{n+1} (Eqs. 31-32)."""
        b, g, am, af = self.beta, self.gamma, self.alpha_m, self.alpha_f
        a1 = (q - s.q - h * s.v - h * h * (0.5 - b) * s.a) / (h * h * b)
        qdd1 = ((1.0 - am) * a1 + am * s.a - af * s.qdd) / (1.0 - af)
        v1 = s.v + h * (1.0 - g) * s.a + h * g * a1
        return qdd1, v1, a1

    def matrix_coefficients(self, h):
        """(beta', gamma'): the iteration matrix is beta' M + gamma' c_d M + K (Eq. 35)."""
        bp = (1.0 - self.alpha_m) / ((1.0 - self.alpha_f) * self.beta * h * h)
        return bp, self.gamma / (self.beta * h)

    def predict(self, s: "State", h, predictor: str):
        """Starting iterate of a step: "paper" (Eq. 33), "velocity" (q_n + h v_n) or "constant"."""
        if predictor == "paper":
            b, am, af = self.beta, self.alpha_m, self.alpha_f
            a0 = (af * s.qdd - am * s.a) / (1.0 - am)
            return s.q + h * s.v + h * h * (0.5 - b) * s.a + h * h * b * a0
        if predictor == "velocity":
            return s.q + h * s.v
        return s.q


@dataclasses.dataclass(frozen=True)
class QuasiStatic:
    """Quasi-static stepping: no inertia and no damping force; equilibrium at each time.

    Velocities are backward differences (q_{n+1} - q_n) / h, accelerations zero; the viscous
    update as ``GeneralizedAlpha.flow_update``. For material tests and slow ramps."""

    flow_update: str = "bdf2"

    inertial = False

    def __post_init__(self):
        _check_flow_update(self.flow_update)

    def kinematics(self, s: "State", h, q):
        zero = jnp.zeros_like(q)
        return zero, (q - s.q) / h, zero

    def matrix_coefficients(self, h):
        return 0.0, 0.0

    def predict(self, s: "State", h, predictor: str):
        return s.q + h * s.v if predictor in ("velocity", "paper") else s.q


@dataclasses.dataclass(frozen=True)
class NewtonOptions:
    """Newton controls.

    criterion: "residual" (default, the paper's terms): converged when the scaled residual
      norm ||r|| <= tol ||r_0|| (r_0 at the step's first iterate) or ||r|| reaches the
      round-off floor; r stacks the reduced forces times the coordinate scale (element
      size for positions, 1 for gradients) and, in the mixed form, the element volume
      residuals times the bulk modulus, so every entry is an energy (J).
      "correction": converged when max |dz_i| / scale_i <= tol (a strain-like measure).
    tol: 1e-6 (relative residual) by default.
    line_search: backtrack a fresh Newton direction until ||r|| decreases (Armijo), on top
      of the admissibility safeguard (every iterate keeps det F > 0 and stays inside the
      Gent limits); at most ``max_backtracks`` halvings.
    reuse: modified Newton: keep the factorized iteration matrix over iterations and
      steps, and refactor only when an iteration contracts the residual by less than
      ``refactor_rate`` or a stale direction does not decrease it (or at the first use, or
      after a change of step size). False: full Newton (refactor every iteration).
    anderson: memory of the Anderson acceleration of modified Newton (0 = off): with a
      reused factorization, each correction is combined with the last ``anderson``
      iterates' corrections (type-II Anderson mixing of the fixed-point map x -> x + dx
      of the factorization in use; history reset at every refactorization). A fresh
      factorization's direction is never mixed. Measured on the tube 4x8x1 (dt 5e-4 s,
      two cycles): 5.03 instead of 5.52 iterations per step at tol 1e-6, 3.40 instead of
      4.10 at 1e-4, the same x_P.
    predictor: starting iterate of each step: "velocity" (q_n + h v_n, the default: robust
      for quasi-static ramps with large steps), "paper" (Eq. 33, uses the acceleration) or
      "constant" (q_n). The converged solution does not depend on it.
    """

    tol: float = 1e-6
    max_iter: int = 25
    reuse: bool = True
    refactor_rate: float = 0.2
    anderson: int = 2
    predictor: str = "velocity"
    criterion: str = "residual"
    line_search: bool = True
    max_backtracks: int = 8

    def __post_init__(self):
        if self.predictor not in ("paper", "velocity", "constant"):
            raise ValueError(f"predictor must be 'paper', 'velocity' or 'constant', got {self.predictor!r}")
        if self.criterion not in ("residual", "correction"):
            raise ValueError(f"criterion must be 'residual' or 'correction', got {self.criterion!r}")
        if not self.tol > 0:
            raise ValueError(f"Newton tolerance must be > 0, got {self.tol}")
        if not (isinstance(self.anderson, int) and self.anderson >= 0):
            raise ValueError(f"anderson (memory) must be an integer >= 0, got {self.anderson!r}")


@dataclasses.dataclass(frozen=True)
class StepControl:
    """Step cut-back and growth (paper Sec. 3: dt down to 1e-6 s when needed).

    A step whose Newton iteration fails (or turns non-finite) is retried with half the
    step, recursively down to ``dt_min`` (s); after a sub-step that converges within
    ``grow_iterations`` iterations the next one is twice as long, up to the user's step.
    Outputs stay on the user's time grid; only a failure at ``dt_min`` is a failure.
    ``max_substeps``: sub-steps a differentiated run may take in all (default: the user
    steps plus half as many, at least 128 more; with ``tol`` 8 per user step plus 128);
    past it the derivatives are NaN.
    ``dt_min >= dt`` turns cut-back off.

    ``tol`` (error control, generalized-alpha only; None = off): a converged sub-step is
    also rejected, and retried at half its length (down to ``dt_min``, where it is kept),
    when its local error estimate (``local_error``: strain-like, displacement error over
    element size) exceeds ``tol``;
    it grows (doubles, up to the user's step) only when the estimate would stay below
    ``tol`` at twice the length (its h^3 growth, with a safety factor of 2). The user's
    grid is then an output grid and an upper bound of the step: give a coarse grid and a
    tolerance instead of a fine dt. Sub-steps stay the user's step over a power of two,
    so the factorization is reused while the step length holds.
    """

    dt_min: float = 1e-6
    grow_iterations: int = 5
    max_substeps: int | None = None
    tol: float | None = None

    def __post_init__(self):
        if not self.dt_min > 0:
            raise ValueError(f"dt_min must be > 0, got {self.dt_min}")
        if self.tol is not None and not self.tol > 0:
            raise ValueError(f"StepControl.tol (local error tolerance) must be > 0, got {self.tol}")


class Loading(eqx.Module):
    """Electrode voltages and prescribed motions as functions of time.

    voltages: tuple of histories t -> V, one per electrode channel of the mesh.
    motions: tuple of histories t -> u, one per prescribed-motion channel.
    """

    voltages: tuple = ()
    motions: tuple = ()

    def phi(self, t):
        return jnp.stack([jnp.asarray(h(t), dtype=float) for h in self.voltages]) if self.voltages else jnp.zeros(0)

    def u(self, t):
        return jnp.stack([jnp.asarray(h(t), dtype=float) for h in self.motions]) if self.motions else jnp.zeros(0)


class State(eqx.Module):
    """Time-stepping state: t (s), q, v, qdd, a (n_dofs,), Cv (n_el, n_gp, n_units, 3, 3),
    p (n_el, n_p) element pressure unknowns (Pa; mixed form, None = 0); Cv_prev and h_prev
    (s): the viscous state one step back and that step's size (h_prev = 0: no history), for
    the BDF2 flow-rule update (None: backward Euler); wmax (n_el, n_gp): the Mullins
    history, the largest equilibrium Gent energy each point has seen (J/m^3; None = 0)."""

    t: jax.Array
    q: jax.Array
    v: jax.Array
    qdd: jax.Array
    a: jax.Array
    Cv: jax.Array
    p: jax.Array | None = None
    Cv_prev: jax.Array | None = None
    h_prev: jax.Array | None = None
    wmax: jax.Array | None = None


def initial_acceleration(model: Model, rhs, dense_limit: int = 4000):
    """Solve T^T M T a = rhs (n_free,): dense up to ``dense_limit`` unknowns, above it by
    matrix-free conjugate gradients (the reduced mass matrix is SPD); the squared dof
    scale (element size for positions, 1 for gradients) is the inverse of its diagonal up
    to a constant, the preconditioner (tube 4x8x1: condition 2.9e9 -> 1.3e4)."""
    if model.structure.n_free <= dense_limit:
        return linsolve.spd_solve(mdl.assemble_dense(model, mdl.mass_elements(model)), rhs)
    op = lambda x: mdl.reduce(model, mdl.mass_apply(model, mdl.expand(model, x)))
    s2 = mdl.dof_scale(model) ** 2
    return jax.scipy.sparse.linalg.cg(op, rhs, M=lambda r: r * s2, tol=1e-12, maxiter=2000)[0]


def initial_state(model: Model, loading: Loading | None = None, t0: float = 0.0, q=None, v=None) -> State:
    """State at t0: reference (or given) coordinates and velocities, Cv = I, p = 0, the
    Mullins history at the start's energy, and the acceleration consistent with the
    equations of motion (M qdd = Q_ext - Q_int - C v)."""
    q = model.q0 if q is None else jnp.asarray(q, dtype=float)
    v = jnp.zeros_like(q) if v is None else jnp.asarray(v, dtype=float)
    Cv = mdl.initial_viscous_state(model)
    p = mdl.initial_pressure(model)
    loading = Loading() if loading is None else loading
    phi = loading.phi(t0) if model.field_dirs.shape[0] else jnp.zeros(0)
    E = mdl.nominal_field(model, phi)
    wmax = mdl.mullins_history(model, q)  # the start's own energy: no softening yet
    f_int = mdl.internal_force_at(model, q, E, Cv, p, wmax)  # at the start's own viscous state (no flow step)
    rhs = mdl.reduce(model, mdl.external_force(model) - f_int - model.damping * mdl.mass_apply(model, v))
    qdd_f = initial_acceleration(model, rhs)
    qdd = mdl.expand(model, qdd_f)
    return State(t=jnp.asarray(t0, dtype=float), q=q, v=v, qdd=qdd, a=qdd, Cv=Cv, p=p, Cv_prev=Cv,
                 h_prev=jnp.asarray(0.0), wmax=wmax)


# ----------------------------------------------------------------------------- one step


class _StepContext(eqx.Module):
    """Everything a step's residual depends on besides the unknowns (differentiable);
    flow: the flow-rule step data per Gauss point (``model.flow_step``)."""

    state: State
    t1: jax.Array
    phi1: jax.Array
    u1: jax.Array
    f_ext: jax.Array
    flow: FlowStep


def _step_terms(model: Model, scheme, ctx: _StepContext, z):
    """Shared part of the residual at q_{n+1}(z): (q, E, h, M qdd + c_d M v - Q_ext)."""
    q = mdl.full_coordinates(model, z, ctx.u1)
    E = mdl.nominal_field(model, ctx.phi1)
    h = ctx.t1 - ctx.state.t
    if not scheme.inertial:
        return q, E, h, -ctx.f_ext
    qdd1, v1, _ = scheme.kinematics(ctx.state, h, q)
    return q, E, h, mdl.mass_apply(model, qdd1 + model.damping * v1) - ctx.f_ext


def _reduced_residual(model: Model, r_inertia, fe, g, p):
    """(ru, g) of Eq. (28) from the step's inertia and external terms and the element forces
    fe (n_el, 32, 3) and volume residuals g (None in the displacement form: empty)."""
    g = jnp.zeros_like(p) if g is None else g
    return mdl.reduce(model, r_inertia + mdl.scatter_slots(model, fe)), g


def _residual(model: Model, scheme, ctx: _StepContext, z, p):
    """Eq. (28) at q_{n+1}(z), p: reduced forces (n_free,), element volume residuals
    (n_el, n_p; empty in the displacement form) and the updated Cv."""
    q, E, h, r_inertia = _step_terms(model, scheme, ctx, z)
    fe, g, Cv1 = mdl.element_forces(model, q, E, ctx.flow, h, p, ctx.state.wmax)
    return (*_reduced_residual(model, r_inertia, fe, g, p), Cv1)


def _matrix_terms(model: Model, scheme, ctx: _StepContext, z):
    """(q, E, h, c, r) of the iteration matrix at z: coordinates, field, step, the mass
    coefficient c = beta' + gamma' c_d (None without inertia) and the residual's inertia and
    external terms r (``_step_terms``)."""
    q, E, h, r_inertia = _step_terms(model, scheme, ctx, z)
    bp, gp = scheme.matrix_coefficients(h)
    return q, E, h, (bp + gp * model.damping if scheme.inertial else None), r_inertia


def _system(model: Model, scheme, ctx: _StepContext, z, p):
    """Element iteration system at (z, p): ElementSystem with Ke = beta' M + gamma' c_d M + K."""
    q, E, h, c, _ = _matrix_terms(model, scheme, ctx, z)
    return mdl.element_system(model, q, E, ctx.flow, h, p, ctx.state.wmax, mass_coefficient=c)


def _newton_system(model: Model, scheme, ctx: _StepContext, z, p):
    """(matrices, (ru, g, Cv)): what Newton factorizes at (z, p), ``(Ke,)`` or in the mixed
    form ``(Kc, kup, kpp)`` with the pressures condensed (``model.condensed_system``), and
    the residual there (as ``_residual``'s) from the same element evaluation."""
    q, E, h, c, r_inertia = _matrix_terms(model, scheme, ctx, z)
    if not model.structure.mixed:
        s = mdl.element_system(model, q, E, ctx.flow, h, p, ctx.state.wmax, mass_coefficient=c)
        return (s.Ke,), (*_reduced_residual(model, r_inertia, s.fe, None, p), s.Cv_new)
    s = mdl.condensed_system(model, q, E, ctx.flow, h, p, ctx.state.wmax, mass_coefficient=c)
    return (s.Kc, s.kup, s.kpp), (*_reduced_residual(model, r_inertia, s.fe, s.g, p), s.Cv_new)


def _shear_scale(model: Model):
    """mu_inf + sum mu_s (Pa): the stiffness scale of the deformation modes."""
    mat = model.material
    return mat.mu_inf + jnp.sum(mat.mu)


def _residual_norm(model: Model, ru, g):
    """Scaled residual norm (J): sqrt(sum (r_i scale_i)^2 + sum (mu g_e)^2).

    Forces are weighted by the coordinate scale and volume residuals by the shear modulus
    (the stress scale of the solution), so every entry is an energy; any positive
    weighting keeps the Newton direction a descent direction of this norm."""
    r2 = jnp.sum((ru * mdl.dof_scale(model)) ** 2)
    if model.structure.mixed:
        r2 = r2 + jnp.sum((_shear_scale(model) * g) ** 2)
    return jnp.sqrt(r2)


def _residual_floor(model: Model, mass_coefficient=0.0):
    """Round-off floor of the scaled residual norm (J): 64 eps x stress scale x element volume
    x sqrt(unknowns); the stress scale is the shear modulus, plus the bulk modulus in the
    penalty (displacement) form, where K (J - 1) is formed in floating point, plus the
    inertia term beta' rho ell^2 of the step (small steps make it dominate)."""
    v_el = jnp.sum(model.dV) / model.dV.shape[0]
    inertia = mass_coefficient * model.material.rho * v_el ** (2.0 / 3.0)
    stiff = _shear_scale(model) + (0.0 if model.structure.mixed else bulk_modulus(model.material)) + inertia
    return 64 * np.finfo(float).eps * stiff * v_el * np.sqrt(model.structure.n_free + model.dV.shape[0])


def _condensed_rhs(model: Model, ru, g, kup, kpp):
    """-(reduced condensed force): -(ru - T^T kup g / kpp) (n_free,)."""
    if not model.structure.mixed:
        return -ru
    corr = mdl.scatter_slots(model, mdl.pressure_force(kup, kpp, g).reshape(-1, 32, 3))
    return -(ru - mdl.reduce(model, corr))


class _Anderson(eqx.Module):
    """History of the Anderson mixing: differences of the last iterates dX and of their
    corrections dF (memory, n), how many are valid (-1: the previous (x, f) is not one
    either), and the previous iterate x and its plain correction f."""

    dX: jax.Array
    dF: jax.Array
    count: jax.Array
    x: jax.Array
    f: jax.Array


def _anderson_empty(memory: int, n: int) -> _Anderson:
    return _Anderson(jnp.zeros((memory, n)), jnp.zeros((memory, n)), jnp.asarray(-1), jnp.zeros(n), jnp.zeros(n))


def _anderson_mix(h: _Anderson, x, f, w, reset):
    """(mixed correction, new history) at iterate x with plain correction f; weights w (n,)
    of the least-squares norm; ``reset``: start a new history here (plain correction)."""
    memory = h.dX.shape[0]
    have_prev = (h.count >= 0) & ~reset
    dX = jnp.where(have_prev, jnp.roll(h.dX, 1, axis=0).at[0].set(x - h.x), 0.0)
    dF = jnp.where(have_prev, jnp.roll(h.dF, 1, axis=0).at[0].set(f - h.f), 0.0)
    count = jnp.where(have_prev, jnp.minimum(h.count + 1, memory), 0)
    valid = jnp.arange(memory) < count
    A = jnp.where(valid[:, None], dF * w, 0.0)
    G = A @ A.T
    lam = 1e-10 * jnp.max(jnp.diag(G)) + 1e-300
    G = jnp.where(valid[:, None] & valid[None, :], G, 0.0) + jnp.diag(jnp.where(valid, lam, 1.0))
    gamma = jnp.where(valid, linsolve.spd_solve(G, A @ (f * w)), 0.0)  # G: SPD by the regularization
    step = f - gamma @ (dX + dF)
    return step, _Anderson(dX, dF, count, x, f)


def _make_newton(scheme, opts: NewtonOptions, solver: LinearSolver):
    """Newton solve of one step: ``newton(model, ctx, z0, p0, fac, valid) -> (z, p,
    iterations, factorizations, converged, fac, Cv)``; fac is the factorization in use at
    the end (handed to the next step), Cv the viscous state at the solution (from its
    residual evaluation, not recomputed). Derivatives of z, p and Cv are implicit
    (custom_jvp)."""

    def factor(model, ctx, z, p):
        """(fac, (ru, g, Cv)): the iteration matrix's factorization at (z, p) and the
        residual there, whose forces come with the tangent."""
        matrices, residual = _newton_system(model, scheme, ctx, z, p)
        return (solver.factor(model, matrices[0]), *matrices[1:]), residual

    def direction(model, fac, ru, g):
        if not model.structure.mixed:
            return solver.solve_factored(model, fac[0], -ru), jnp.zeros_like(g)
        _, kup, kpp = fac
        dz = solver.solve_factored(model, fac[0], _condensed_rhs(model, ru, g, kup, kpp))
        return dz, mdl.pressure_correction(model, g, kup, kpp, mdl.expand(model, dz))

    def _solve(model, ctx, z0, p0, fac, valid):
        scale = mdl.dof_scale(model)
        floor = _residual_floor(model, scheme.matrix_coefficients(ctx.t1 - ctx.state.t)[0])

        def trial(z, p, dz, dp, a):
            zt, pt = z + a * dz, p + a * dp
            ok = _admissible(model, ctx, zt)
            ru, g, Cv = _residual(model, scheme, ctx, zt, pt)
            res = _residual_norm(model, ru, g)
            ok = ok & jnp.isfinite(res)
            return zt, pt, ru, g, Cv, jnp.where(ok, res, jnp.inf), ok

        def line_search(z, p, dz, dp, res, fresh, given):
            """Backtrack from a = 1: admissibility always; Armijo decrease for a fresh direction.
            (One traced trial: the loop starts at a = 2 with an unacceptable placeholder.)
            ``given`` = (known, (ru, g, Cv, res, ok)): where ``known`` (traced), the result at
            a = 1 (the start pass's residual from the system's forces), and no trial runs."""
            c1 = 1e-4

            def cond(c):
                a, k, out = c
                zt, pt, ru, g, Cv, rt, ok = out
                bad = (~ok) | (opts.line_search & fresh & (rt > (1.0 - c1 * a) * res))
                return bad & (k <= opts.max_backtracks)

            def body(c):
                a, k, _ = c
                a = 0.5 * a
                return a, k + 1, trial(z, p, dz, dp, a)

            known, (ru, g, Cv, rg, okg) = given
            # the placeholder's arrays are overwritten by the first trial unless it is known
            placeholder = (z, p, ru, g, Cv, jnp.where(known, rg, jnp.inf), known & okg)
            a0, k0 = jnp.where(known, 1.0, 2.0), jnp.where(known, opts.max_backtracks + 1, 0)
            a, _, out = jax.lax.while_loop(cond, body, (a0, k0, placeholder))
            return a, out

        n_z, n_p = z0.size, p0.size
        weights = jnp.concatenate([1.0 / scale, jnp.full(n_p, 1.0 / _shear_scale(model))])

        def body(c):
            z, p, ru, g, Cv, res, res_prev, res0, it, nfac, fac, valid, fresh, conv, alive, aa = c
            # the first pass (it = -1) only evaluates the residual at the starting iterate,
            # through the same traced trial as the line search (one residual in the program),
            # except where the first iteration factorizes anyway (no valid factorization,
            # or full Newton): then it factorizes there and takes the residual from the
            # system's forces (one residual evaluation fewer; an inadmissible start is left
            # to the trial, which reports it). A start already at the residual's floor (a
            # model at rest) is then factorized as well: with full Newton one factorization
            # per such step, where modified Newton keeps it for the steps that follow
            start = it < 0
            slow = (it >= 1) & (res > opts.refactor_rate * res_prev)
            first = (~valid) if opts.reuse else jnp.asarray(True)
            early = start & first & jax.lax.cond(start & first, lambda: _admissible(model, ctx, z),
                                                 lambda: jnp.asarray(False))
            # fresh: the factorization in hand was made at the current iterate
            need = (((~valid) | slow) if opts.reuse else jnp.asarray(True)) & ~start & ~fresh
            fac, (ru_f, g_f, Cv_f) = jax.lax.cond(need | early, lambda: factor(model, ctx, z, p),
                                                  lambda: (fac, (ru, g, Cv)))
            exact = need | fresh  # the direction is Newton's at this iterate
            dz, dp = jax.lax.cond(start, lambda: (jnp.zeros_like(z), jnp.zeros_like(p)),
                                  lambda: direction(model, fac, ru, g))
            if opts.anderson and opts.reuse:
                x = jnp.concatenate([z, p.reshape(-1)])
                step, aa_new = _anderson_mix(aa, x, jnp.concatenate([dz, dp.reshape(-1)]), weights, exact | start)
                aa_new = eqx.tree_at(lambda h: h.count, aa_new, jnp.where(start, -1, aa_new.count))
                dz, dp = step[:n_z], step[n_z:].reshape(p.shape)
            res_f = _residual_norm(model, ru_f, g_f)
            given = (early, (ru_f, g_f, Cv_f, res_f, jnp.isfinite(res_f)))
            a, (zt, pt, rut, gt, Cvt, rest, ok) = line_search(z, p, dz, dp, res, exact, given)
            # a stale factorization whose step does not reduce the residual is not applied:
            # the iterate is kept and the next iteration refactors
            accept = ok & (exact | start | (rest < res))
            if opts.anderson and opts.reuse:
                aa = jax.tree.map(lambda n_, o_: jnp.where(accept, n_, o_), aa_new, aa)
            z, p = jnp.where(accept, zt, z), jnp.where(accept, pt, p)
            ru, g, Cv = jnp.where(accept, rut, ru), jnp.where(accept, gt, g), jnp.where(accept, Cvt, Cv)
            res_new = jnp.where(accept, rest, res)
            res0 = jnp.where(start, rest, res0)
            if opts.criterion == "residual":
                conv = accept & (((res_new <= opts.tol * res0) & ~start) | (res_new <= floor))
            else:
                conv = accept & ~start & (jnp.max(jnp.abs(a * dz) / scale) <= opts.tol)
            # a fresh direction that cannot be applied ends the iteration (failed step), and
            # so does a starting iterate that is inadmissible or non-finite
            alive = jnp.where(start, accept, accept | ~exact)
            return (z, p, ru, g, Cv, res_new, jnp.where(accept & ~start, res, res_prev), res0, it + 1,
                    nfac + (need | early).astype(int), fac, jnp.where(start, valid | early, accept),
                    early & accept, conv, alive, aa)

        def cond(c):
            *_, it, _, _, _, _, conv, alive, _ = c
            return (~conv) & (it < opts.max_iter) & alive

        inf = jnp.asarray(jnp.inf)
        c0 = (z0, p0, jnp.zeros_like(z0), jnp.zeros_like(p0), ctx.state.Cv, inf, inf, inf, jnp.asarray(-1),
              jnp.asarray(0), fac, jnp.asarray(valid), jnp.asarray(False), jnp.asarray(False), jnp.asarray(True),
              _anderson_empty(max(opts.anderson, 1), n_z + n_p))
        z, p, _, _, Cv, _, _, _, it, nfac, fac, _, _, conv, _, _ = jax.lax.while_loop(cond, body, c0)
        it = jnp.maximum(it, 0)
        return z, p, it, nfac, conv, fac, Cv

    @jax.custom_jvp
    def newton(model, ctx, z0, p0, fac, valid):
        return _solve(model, ctx, z0, p0, fac, valid)

    @newton.defjvp
    def newton_jvp(primals, tangents):
        model, ctx, z0, p0, fac, valid = primals
        dmodel, dctx = tangents[0], tangents[1]
        out = newton(model, ctx, z0, p0, fac, valid)
        # named, so that a rematerialized step (reverse mode) linearizes at the kept solution
        # instead of running its Newton iterations again; the rule returns the named values
        # (named again outside, they would be kept twice). A derivative along data that no
        # step's Newton sees (read by the outputs alone) leaves them unnamed: its reverse
        # pass is right but runs the steps' Newton iterations again
        z, p = (checkpoint_name(x, STEP_SOLUTION) for x in out[:2])
        _, (dru, dg, dCv) = jax.jvp(lambda m, c: _residual(m, scheme, c, z, p), (model, ctx), (dmodel, dctx))
        sys = _system(model, scheme, ctx, z, p)
        dz, dp = _implicit_solve(model, solver, sys, dru, dg)
        # Cv's change along (dz, dp) by the flow rule's derivative that the tangent already
        # holds (Cv_new does not depend on p), rather than a second jvp of the residual
        dCv = dCv + mdl.flow_tangent(model, sys.Cv_F, mdl.expand(model, dz))
        return (z, p, *out[2:]), (dz, dp, *(_zero_tangent(x) for x in out[2:6]), dCv)

    return newton


DERIVATIVE_SPARSE_FROM = 500
"""Reduced unknowns from which a step's implicit derivative factorizes its exact tangent
with MKL Pardiso (Cholesky, one host call for every tangent lane) where the forward run
uses the dense solver, on the CPU when pypardiso is installed (``_derivative_solver``)."""


def _derivative_solver(model: Model, solver: LinearSolver) -> LinearSolver:
    """The solver of the implicit derivative: the forward run's, except that a dense solver
    hands the exact tangent to MKL Pardiso from ``DERIVATIVE_SPARSE_FROM`` unknowns on the
    CPU. The forward run factorizes once per many steps (modified Newton) and solves at
    every iteration, where the dense triangular solves are cheapest; the derivative
    factorizes a fresh tangent at every step, where the sparse Cholesky is cheaper
    (tube 4x8x1, 720 unknowns: factorization and solve 2.7-2.9 ms against 7.2-7.8 ms dense,
    12 solves 1.0-1.2 ms against 0.5 ms; G1 at 100 steps 18.5-18.9 s against 25.5-25.7 s
    projected, derivatives equal to 1.1e-15, ``python bench/derivative_solver.py``). Below
    ~400 unknowns the dense factorization is as fast and its solves cheaper."""
    if (isinstance(solver, DenseSolver) and model.structure.n_free >= DERIVATIVE_SPARSE_FROM
            and jax.default_backend() == "cpu" and linsolve.pardiso_available()):
        return linsolve.SparseSolver("pardiso")
    return solver


def _implicit_solve(model: Model, solver: LinearSolver, sys, dru, dg):
    """Solve the step's linearized equations J (dz, dp) = -(dru, dg) exactly (differentiable,
    transposable): a condensed solve refined against the exact saddle-point operator, by one
    sweep for finite K and three for K = inf (condensed with K_aug); with
    ``_derivative_solver(model, solver)``."""
    solver = _derivative_solver(model, solver)
    if not model.structure.mixed:
        return solver.solve(model, sys.Ke, -dru), jnp.zeros_like(dg)
    kpp = mdl.newton_kpp(model, sys.kpp)
    Kc = mdl.condense(sys.Ke, sys.kup, kpp)

    def approx(bu, bg):  # solves the system with kpp in place of the exact pressure block
        dz = solver.solve(model, Kc, _condensed_rhs(model, -bu, -bg, sys.kup, kpp))
        return dz, mdl.pressure_correction(model, -bg, sys.kup, kpp, mdl.expand(model, dz))

    dz, dp = approx(-dru, -dg)
    # K = inf: three sweeps of refinement against the exact operator; finite K: one, for the
    # round-off of the condensed solve (K/mu ~ 1e5 makes the condensed matrix ill-conditioned)
    for _ in range(3 if model.structure.incompressible else 1):
        ru, g = _apply_system(model, sys, dz, dp)
        ez, ep = approx(-dru - ru, -dg - g)
        dz, dp = dz + ez, dp + ep
    return dz, dp


def _apply_system(model: Model, sys, dz, dp):
    """The exact linearized operator (K dz + T^T kup dp, kup . dq + kpp dp) of the mixed form."""
    dq = mdl.expand(model, dz)
    dqe = mdl.element_coordinates(model, dq).reshape(sys.Ke.shape[0], 96)
    fu = jnp.einsum("eab,eb->ea", sys.Ke, dqe) + jnp.einsum("eka,ek->ea", sys.kup, dp)
    ru = mdl.reduce(model, mdl.scatter_slots(model, fu.reshape(-1, 32, 3)))
    return ru, jnp.einsum("eka,ea->ek", sys.kup, dqe) + jnp.einsum("ekl,el->ek", sys.kpp, dp)


def _admissible(model: Model, ctx: _StepContext, z) -> jax.Array:
    """True if every Gauss point has det F > 0 and lies inside the Gent limits (viscous
    branches judged with the step's starting Cv)."""
    q = mdl.full_coordinates(model, z, ctx.u1)
    F = mdl.deformation_gradients(model, q)
    J = jax.vmap(jax.vmap(det3))(F)
    H = mdl.gent_margins(model, q, ctx.state.Cv)
    return jnp.all(J > 0) & jnp.all(H > 0)


def _zero_tangent(x):
    """A zero tangent for any pytree (float0 for integer leaves)."""
    def leaf(a):
        a = jnp.asarray(a)
        if jnp.issubdtype(a.dtype, jnp.integer) or a.dtype == bool:
            return np.zeros(a.shape, dtype=jax.dtypes.float0)
        return jnp.zeros_like(a)

    return jax.tree_util.tree_map(leaf, x)


def make_step(scheme=GeneralizedAlpha(), opts: NewtonOptions = NewtonOptions(), solver: LinearSolver | None = None):
    """Return ``step(model, loading, state, t1, fac, valid) -> (state1, iterations,
    factorizations, status, fac1)``: one step (no cut-back) from state.t to t1.
    ``scheme``: GeneralizedAlpha or QuasiStatic; ``solver``: a ``linsolve.LinearSolver``
    (default DenseSolver)."""
    solver = DenseSolver() if solver is None else solver
    newton = _make_newton(scheme, opts, solver)

    def step(model: Model, loading: Loading, state: State, t1, fac, valid):
        s = model.structure
        t1 = jnp.asarray(t1, dtype=float)
        h = t1 - state.t
        ctx = _StepContext(
            state=state,
            t1=t1,
            phi1=loading.phi(t1) if model.field_dirs.shape[0] else jnp.zeros(0),
            u1=loading.u(t1) if model.prescribed_dirs.shape[0] else jnp.zeros(0),
            f_ext=mdl.external_force(model),
            flow=mdl.flow_step(model, state, h, scheme.flow_update),
        )
        q_pred = scheme.predict(state, h, opts.predictor)
        p0 = mdl.initial_pressure(model) if state.p is None else state.p
        z, p1, it, nfac, conv, fac, Cv1 = newton(model, ctx, q_pred[s.free], p0, fac, valid)
        # named so that a rematerialized scan (reverse mode) keeps the converged step rather
        # than repeating its Newton iterations (z and p1 are named by Newton's jvp rule)
        Cv1 = checkpoint_name(Cv1, STEP_SOLUTION)
        fac = jax.lax.stop_gradient(fac)  # no tangent carried for the factorization
        q1 = mdl.full_coordinates(model, z, ctx.u1)
        qdd1, v1, a1 = scheme.kinematics(state, h, q1)
        new = State(t=t1, q=q1, v=v1, qdd=qdd1, a=a1, Cv=Cv1, p=p1,
                    Cv_prev=None if state.Cv_prev is None else state.Cv, h_prev=None if state.h_prev is None else h,
                    wmax=mdl.mullins_history(model, q1, state.wmax))
        F = mdl.deformation_gradients(model, q1)
        finite = jnp.all(jnp.isfinite(q1)) & jnp.all(jnp.isfinite(Cv1)) & jnp.all(jnp.isfinite(p1))
        inverted = jnp.any(jax.vmap(jax.vmap(det3))(F) <= 0)
        gent = jnp.min(mdl.gent_margins(model, q1, Cv1)) <= GENT_LOCK_MARGIN
        # a step that did not converge is reported as such (its last iterate's state says
        # nothing reliable about Gent limits or inversion)
        status = jnp.where(
            ~finite,
            int(Status.NONFINITE),
            jnp.where(
                ~conv,
                int(Status.NEWTON_FAILED),
                jnp.where(inverted, int(Status.INVERTED), jnp.where(gent, int(Status.GENT_LIMIT), 0)),
            ),
        )
        # kept as well: the step's state is selected by it, and recomputing it would run the
        # Newton iterations again (and keep each step's factorization for them)
        status = checkpoint_name(status, STEP_SOLUTION)
        return new, it, nfac, status, fac

    step.solver = solver
    step.scheme = scheme
    return step


# ----------------------------------------------------------------------------- runs


class Carry(eqx.Module):
    """Scan carry: state, status, first failed user step, step offset (chunked runs), the
    iteration-matrix factorization reused across steps (with its validity flag and the step
    size it was made for), the next trial sub-step, the smallest accepted sub-step, and
    the accepted sub-step times so far (the schedule a differentiated run replays)."""

    state: State
    status: jax.Array
    fail_step: jax.Array
    step_offset: jax.Array
    fac: object
    fac_valid: jax.Array
    h_fac: jax.Array
    h_next: jax.Array
    h_smallest: jax.Array
    schedule: jax.Array
    n_sub: jax.Array
    last_good: State


def _empty_fac(model: Model, solver: LinearSolver):
    if not model.structure.mixed:
        return (solver.empty(model),)
    n_el, n_p = model.dV.shape[0], model.structure.n_pressure
    return solver.empty(model), jnp.zeros((n_el, n_p, 96)), -jnp.broadcast_to(jnp.eye(n_p), (n_el, n_p, n_p))


def initial_carry(model: Model, state: State, solver: LinearSolver, max_substeps: int = 0) -> Carry:
    inf = jnp.asarray(jnp.inf)
    return Carry(state, jnp.asarray(0), jnp.asarray(-1), jnp.asarray(0), _empty_fac(model, solver), jnp.asarray(False),
                 inf, inf, inf, jnp.zeros(max_substeps), jnp.asarray(0), state)


def _same_step(h, h_fac):
    return jnp.abs(h - h_fac) <= 1e-9 * h


_RETRY = (int(Status.NEWTON_FAILED), int(Status.NONFINITE))


def local_error(model: Model, scheme, s0: State, s1: State, h) -> jax.Array:
    """Local error estimate of a generalized-alpha step from s0 to s1 of length h (s):
    max over the free coordinates of |(beta - 1/6) h^2 (a_1 - a_0)| / scale, the
    displacement error of the step's Newmark update against a linear acceleration over the
    step (Zienkiewicz and Xie 1991), ``a`` the algorithmic acceleration of Eqs. (31-32)
    and scale the element size for positions, 1 for gradients (``model.dof_scale``):
    a strain-like number."""
    free = model.structure.free
    e = (scheme.beta - 1.0 / 6.0) * h * h * (s1.a[free] - s0.a[free])
    return jnp.max(jnp.abs(e) / mdl.dof_scale(model))


def make_user_step(step, control: StepControl):
    """Return ``user_step(model, loading, carry, t1) -> (carry, iterations, factorizations,
    cutbacks)``: advance from carry.state.t to t1 in sub-steps, halving a failed sub-step
    (or, with ``control.tol``, an inaccurate one) down to ``control.dt_min`` and doubling
    after easy ones (up to t1 - t_n). Cut-backs count both."""
    scheme = step.scheme
    if control.tol is not None and not scheme.inertial:
        raise ValueError("StepControl.tol (error control) needs the generalized-alpha scheme: its local error "
                         "estimate is made from the accelerations")

    def user_step(model, loading, c: Carry, t1):
        t0 = c.state.t
        dt = t1 - t0
        can_cut = control.dt_min < dt

        def cond(x):
            c, *_ = x
            return (c.state.t < t1) & (c.status == 0)

        def body(x):
            c, its, nfac, ncut = x
            # the nominal sub-step h_nom stays the user's step over a power of two (a step
            # shortened to land on t1 does not set the next one); a remainder below 1e-6 h is
            # round-off of the sub-step times and joins this sub-step
            h_nom = jnp.minimum(c.h_next, dt)
            h = jnp.minimum(h_nom, t1 - c.state.t)
            t_new = jnp.where(t1 - (c.state.t + h) <= 1e-6 * h, t1, c.state.t + h)
            h = t_new - c.state.t
            new, it, nf, st, fac = step(model, loading, c.state, t_new, c.fac, c.fac_valid & _same_step(h, c.h_fac))
            converged = st == 0
            can_halve = can_cut & (0.5 * h >= control.dt_min)
            if control.tol is None:
                ok, accurate_at_double = converged, True
            else:  # an inaccurate sub-step is retried at half its length while it can be
                err = local_error(model, scheme, c.state, new, h) / control.tol
                ok = converged & ((err <= 1.0) | ~can_halve)
                accurate_at_double = 8.0 * err <= 0.5
            retry = ((~converged) & can_halve & ((st == _RETRY[0]) | (st == _RETRY[1]))) | (converged & ~ok)
            state = jax.tree_util.tree_map(lambda a, b: jnp.where(ok, a, b), new, c.state)
            grow = ok & (it <= control.grow_iterations) & accurate_at_double
            h_next = jnp.where(ok, jnp.where(grow, 2.0 * h_nom, h_nom), 0.5 * h)
            k = jnp.minimum(c.n_sub, c.schedule.shape[0] - 1)
            schedule = jnp.where(ok, c.schedule.at[k].set(t_new), c.schedule)
            c = Carry(state, jnp.where(ok | retry, 0, st), c.fail_step, c.step_offset, fac, converged, h,
                      jnp.minimum(h_next, dt), jnp.where(ok, jnp.minimum(c.h_smallest, h), c.h_smallest), schedule,
                      c.n_sub + ok.astype(int), state)
            return c, its + it, nfac + nf, ncut + (~ok).astype(int)

        zero = jnp.asarray(0)
        c, its, nfac, ncut = jax.lax.while_loop(cond, body, (c, zero, zero, zero))
        return c, its, nfac, ncut

    return user_step


# the name of each step's converged unknowns (z, p, Cv) and status: what a rematerialized scan keeps
STEP_SOLUTION = "dejax_step_solution"


def make_scan(step, output_fn: Callable, control: StepControl | None = None, remat: bool = False):
    """Return ``run(model, loading, carry, times, active) -> (carry, (outputs, iterations,
    factorizations, cutbacks, last_substep))``: lax.scan over the time grid ``times`` (n,),
    skipping inactive entries (padding) and every step after a failure. With ``control``
    each grid step is taken in sub-steps with cut-back (``make_user_step``); without it,
    in one step (a failure is final). ``remat``: each step is rematerialized in reverse
    mode (``jax.checkpoint`` keeping only the carry, the converged unknowns and the status),
    so a reverse pass stores O(state) per step instead of the step's linearization (element
    matrices, factorization): its memory then grows with the number of steps times the
    state size, at the cost of one more assembly and factorization per step."""
    user_step = make_user_step(step, control) if control is not None else None

    def run(model, loading, carry: Carry, times, active):
        def body(c: Carry, xs):
            t1, k, on = xs

            def do(c):
                if user_step is not None:
                    c1, it, nfac, ncut = user_step(model, loading, c, t1)
                    failed = c1.status != 0
                    # after a failure the state stays at the last user-grid time
                    state = jax.tree_util.tree_map(lambda a, b: jnp.where(failed, a, b), c.state, c1.state)
                    # (last_good keeps the last converged sub-step: the state nearest a failure)
                    c1 = eqx.tree_at(lambda x: (x.state, x.fail_step), c1, (state, jnp.where(failed, k, c.fail_step)))
                    return c1, (it, nfac, ncut)
                h = t1 - c.state.t
                new, it, nfac, st, fac = step(model, loading, c.state, t1, c.fac, c.fac_valid & _same_step(h, c.h_fac))
                failed = st != 0
                state = jax.tree_util.tree_map(lambda a, b: jnp.where(failed, a, b), c.state, new)
                c1 = Carry(state, st, jnp.where(failed, k, c.fail_step), c.step_offset, fac, ~failed, h, c.h_next,
                           jnp.where(failed, c.h_smallest, jnp.minimum(c.h_smallest, h)), c.schedule,
                           c.n_sub + (~failed).astype(int), state)
                return c1, (it, nfac, jnp.asarray(0))

            def skip(c):
                zero = jnp.asarray(0)
                return c, (zero, zero, zero)

            c, (it, nfac, ncut) = jax.lax.cond((c.status == 0) & on, do, skip, c)
            return c, (output_fn(model, loading, c.state), it, nfac, ncut, c.n_sub - 1)

        if remat:
            body = jax.checkpoint(body, policy=jax.checkpoint_policies.save_only_these_names(STEP_SOLUTION))
        steps = jnp.arange(times.shape[0]) + carry.step_offset
        return jax.lax.scan(body, carry, (times, steps, active))

    return run


@dataclasses.dataclass
class Solution:
    """What ``simulate`` returns.

    time: (n+1,) s; outputs: name -> (n+1, ...) arrays (row 0 = initial state);
    iterations: (n,) Newton iterations per step (all sub-steps); factorizations: (n,)
    iteration-matrix factorizations per step; cutbacks: (n,) failed sub-steps retried with
    half the step; dt_smallest: the smallest step used (s); status: Status; fail_time (s)
    and fail_step (-1 if none); final: the last State on the time grid (the last converged
    one after a failure); last_converged: the last converged sub-step (after a failure the
    state nearest it, at last_converged.t); detail: what a failure analysis found (see
    ``dejax.stability.classify_failure``).
    """

    time: jax.Array
    outputs: dict
    iterations: jax.Array
    factorizations: jax.Array
    status: jax.Array
    fail_step: jax.Array
    final: State
    cutbacks: jax.Array | None = None
    dt_smallest: jax.Array | None = None
    last_converged: State | None = None
    detail: str = ""

    @property
    def ok(self) -> bool:
        return int(self.status) == 0

    @property
    def fail_time(self) -> float:
        k = int(self.fail_step)
        return float(self.time[k + 1]) if k >= 0 else float("nan")

    @property
    def n_cutbacks(self) -> int:
        return 0 if self.cutbacks is None else int(np.sum(np.asarray(self.cutbacks)))

    def error(self, note: str = "") -> SimulationError | None:
        """The SimulationError of a failed run (None after a success): what failed, when, then
        ``note`` and ``detail`` (the failure analysis)."""
        if self.ok:
            return None
        detail = "; ".join(d for d in (note, self.detail, "the initial acceleration (M qdd = Q at the start) is not finite"
                                       if self.start_not_finite else "") if d)
        return SimulationError(Status(int(self.status)), self.fail_time, int(self.fail_step) + 1, detail)

    @property
    def start_not_finite(self) -> bool:
        """A concrete run that failed its first step from a non-finite initial acceleration
        (False under tracing: a traced run cannot be inspected)."""
        start = self.last_converged
        if isinstance(self.status, jax.core.Tracer) or getattr(start, "qdd", None) is None:
            return False
        return (int(self.status) != 0 and int(self.fail_step) == 0
                and not bool(np.all(np.isfinite(np.asarray(start.qdd)))))

    def check(self) -> "Solution":
        """Raise SimulationError naming what failed and when; return self otherwise."""
        err = self.error()
        if err is not None:
            raise err
        return self


jax.tree_util.register_pytree_node(
    Solution,
    lambda s: ((s.time, s.outputs, s.iterations, s.factorizations, s.status, s.fail_step, s.final, s.cutbacks,
                s.dt_smallest, s.last_converged), s.detail),
    lambda detail, c: Solution(*c, detail=detail),
)


def _explicit_mesh_context():
    """The current abstract mesh, set explicitly for the tracing inside (no mesh: the empty
    one). JAX keys its trace caches on the mesh context, and the contexts its own
    transformations set while re-evaluating a program (the empty mesh) differ from the unset
    one of a first trace: the material law traced in Newton's loop was traced again for the
    step's derivative, and so were three of the per-point laws (a cache miss each,
    ``jax_explain_cache_misses``). Set once around a run, every trace of it shares one key:
    tracing G1's derivative program 13.1 -> 10.8 s."""
    return jax.sharding.use_abstract_mesh(jax.sharding.get_abstract_mesh())


def time_grid(t_end: float, dt: float, t0: float = 0.0) -> np.ndarray:
    """(n+1,) uniform grid from t0 to t_end with n = ceil((t_end - t0)/dt - 1e-9) steps."""
    if not (dt > 0):
        raise ValueError(f"time step dt must be > 0, got {dt}")
    if not (t_end > t0):
        raise ValueError(f"end time t_end = {t_end} must exceed the start time {t0}")
    n = int(np.ceil((t_end - t0) / dt - 1e-9))
    return np.linspace(t0, t_end, n + 1)


def _default_max_substeps(n: int, control: StepControl) -> int:
    """Sub-steps a differentiated run of n user steps may replay: n + max(128, n / 2), and
    8 n + 128 with error control (its sub-steps are the rule, not the exception)."""
    return 8 * n + 128 if control.tol is not None else n + max(128, n // 2)


def simulate(model: Model, loading: Loading, times, output_fn: Callable, scheme=GeneralizedAlpha(),
             newton: NewtonOptions = NewtonOptions(), solver: LinearSolver | None = None, state0: State | None = None,
             pad_to: int | None = None, control: StepControl | None = StepControl()) -> Solution:
    """Integrate over the time grid ``times`` (n+1,) in one jitted ``lax.scan``.

    Pure and differentiable (jax.jvp / jax.grad / jax.vmap) in ``model`` and
    ``loading`` arrays. ``output_fn(model, loading, state) -> dict`` is recorded at
    every grid time; it is a static argument (use a hashable callable object to share
    compiled code between calls). ``scheme``: GeneralizedAlpha (default) or QuasiStatic.
    ``control``: step cut-back (StepControl; None = off). ``pad_to`` (>= n) pads the scan
    with skipped steps so that runs of different lengths share one compilation; steps of
    zero length (a grid padded by repeating its last time) are skipped as well. The
    returned Solution carries the status; call ``.check()`` to raise on failure.

    Derivatives: each step is differentiated implicitly (its custom_jvp). Without
    ``control`` the scan of steps is differentiated as it stands (one forward pass); with
    it, the primal takes sub-steps where Newton needs them and a differentiated run replays
    the accepted sub-steps as a fixed grid (one more forward pass), so jvp and grad hold
    through cut-backs.
    """
    times = np.asarray(times, dtype=float) if not isinstance(times, jax.core.Tracer) else times
    n = times.shape[0] - 1
    m = n if pad_to is None else int(pad_to)
    if m < n:
        raise ValueError(f"pad_to = {m} is smaller than the number of steps {n}")
    if control is not None and control.max_substeps is not None and control.max_substeps < m:
        raise ValueError(f"StepControl.max_substeps = {control.max_substeps} is below the number of steps {m}")
    xp = np if isinstance(times, np.ndarray) else jnp  # a concrete grid: no compiled program for these few lines
    tt = xp.concatenate([times[1:], xp.full(m - n, times[-1])])
    # steps of zero length are skipped too: a grid padded by repeating its last time (so
    # that traces of different lengths share one compilation) runs only its real steps
    active = (xp.arange(m) < n) & (tt > xp.concatenate([times[:1], tt[:-1]]))
    args = (model, loading, jnp.asarray(times[0], dtype=float), jnp.asarray(tt), jnp.asarray(active), state0)
    kw = dict(output_fn=output_fn, scheme=scheme, newton=newton, solver=solver, control=control)
    with _explicit_mesh_context():
        sol = _simulate_jit(*args, **kw)
    if state0 is None and sol.start_not_finite:
        warnings.warn("the run's initial acceleration came out non-finite and its first step failed: running it "
                      "once more (a nondeterministic fault seen with jaxlib 0.10.2 on the CPU, the same program "
                      "right when run again)", RuntimeWarning, stacklevel=2)
        with _explicit_mesh_context():
            sol = _simulate_jit(*args, **kw)
    if m == n:  # nothing padded: nothing to cut (an eager slice would be one more compiled program)
        return dataclasses.replace(sol, time=jnp.asarray(times))
    outputs = jax.tree_util.tree_map(lambda a: a[: n + 1], sol.outputs)
    return Solution(jnp.asarray(times), outputs, sol.iterations[:n], sol.factorizations[:n], sol.status, sol.fail_step,
                    sol.final, sol.cutbacks[:n], sol.dt_smallest, sol.last_converged)


@eqx.filter_jit
def _simulate_jit(model, loading, t0, times, active, state0, *, output_fn, scheme, newton, solver, control):
    s0 = initial_state(model, loading, t0) if state0 is None else state0
    # without cut-back the scan itself is differentiated (each step implicitly, through its
    # custom_jvp); with cut-back the run's own rule replays the accepted sub-steps
    run = _run_fixed if control is None else _run
    res = run(model, loading, s0, times, active, output_fn=output_fn, scheme=scheme, newton=newton, solver=solver,
              control=control)
    out0 = output_fn(model, loading, s0)
    outputs = jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a[None], b]), out0, res["outputs"])
    return Solution(times, outputs, res["iterations"], res["factorizations"], res["status"], res["fail_step"],
                    res["final"], res["cutbacks"], res["dt_smallest"], res["last_good"])


def _run_fixed(model, loading, s0, times, active, *, output_fn, scheme, newton, solver, control):
    """Run over the grid ``times`` (m,), with cut-back where ``control`` allows; without
    ``control`` it is differentiated as it stands (a scan of implicitly differentiated steps)."""
    step = make_step(scheme, newton, solver)
    budget = 0 if control is None else (control.max_substeps or _default_max_substeps(times.shape[0], control))
    carry = initial_carry(model, s0, step.solver, budget)
    run = make_scan(step, output_fn, control, remat=True)
    carry, (outs, its, nfac, ncut, last) = run(model, loading, carry, times, active)
    return dict(outputs=outs, iterations=its, factorizations=nfac, cutbacks=ncut, status=carry.status,
                fail_step=carry.fail_step, final=carry.state, dt_smallest=carry.h_smallest, schedule=carry.schedule,
                n_sub=carry.n_sub, last=last, last_good=carry.last_good)


@eqx.filter_custom_jvp
def _run(model, loading, s0, times, active, *, output_fn, scheme, newton, solver, control):
    """``_run_fixed`` with cut-back: its derivative replays the accepted sub-steps as a
    fixed grid (the sub-step loop is a while loop, which reverse mode cannot differentiate)."""
    return _run_fixed(model, loading, s0, times, active, output_fn=output_fn, scheme=scheme, newton=newton,
                      solver=solver, control=control)


@_run.def_jvp
def _run_jvp(primals, tangents, *, output_fn, scheme, newton, solver, control):
    model, loading, s0, times, active = primals
    res = _run(model, loading, s0, times, active, output_fn=output_fn, scheme=scheme, newton=newton, solver=solver,
               control=control)
    if control is None:
        grid, on, rows = times, active, jnp.arange(times.shape[0])
        overflow = jnp.asarray(False)
    else:  # replay the accepted sub-steps (a fixed grid) and pick the user's grid times from it
        sched = jax.lax.stop_gradient(res["schedule"])
        budget = sched.shape[0]
        overflow = res["n_sub"] > budget
        on = jnp.arange(budget) < res["n_sub"]
        grid = jnp.where(on, sched, sched[jnp.maximum(res["n_sub"] - 1, 0)])
        rows = jnp.clip(res["last"], 0, budget - 1)
    step = make_step(scheme, newton, solver)
    run = make_scan(step, output_fn, remat=True)

    def replay(model, loading, s0):
        carry = initial_carry(model, s0, step.solver, 0)
        carry, (outs, *_) = run(model, loading, carry, grid, on)
        return jax.tree_util.tree_map(lambda a: a[rows], outs), carry.state, carry.status

    (_, _, replay_status), (d_outs, d_final, _) = eqx.filter_jvp(replay, (model, loading, s0), tangents[:3])
    # a replay whose Newton fails where the run converged (its factorization history differs)
    # would freeze the tangents at the failure: NaN says so instead of a wrong derivative
    bad = overflow | (replay_status != 0)
    nan_if = lambda t: jax.tree_util.tree_map(lambda a: jnp.where(bad, jnp.nan, a), t)
    t_res = _zero_tangent(res)
    t_res["outputs"] = nan_if(d_outs)
    t_res["final"] = nan_if(d_final)
    t_res["last_good"] = t_res["final"]  # the same state unless the run failed
    return res, t_res


@eqx.filter_jit
def _outputs_at(output_fn, model, loading, state):
    """``output_fn(model, loading, state)`` as one compiled program (eager, each operation of
    the output function would be compiled on its own)."""
    return output_fn(model, loading, state)


def run_chunked(model: Model, loading: Loading, times, output_fn: Callable, scheme=GeneralizedAlpha(),
                newton: NewtonOptions = NewtonOptions(), solver: LinearSolver | None = None, chunk: int = 500,
                progress: Callable | None = None, snapshot_times=(), control: StepControl | None = StepControl()):
    """``simulate`` in jitted chunks of ``chunk`` steps (primal only): progress reports
    and full states at chunk ends. Every chunk has the same compiled length (the last one
    is padded), so there is one compilation.

    Args:
      progress: optional ``progress(steps_done, n_steps, t, wall_seconds)`` after each chunk;
        after a failure steps_done counts the converged steps (t: the last converged grid time).
      snapshot_times: times (s) at which to keep the full State (taken at the first chunk
        end at or after each time; pass ``chunk`` dividing the snapshot spacing for exact times).
    Returns:
      (Solution, snapshots: dict step -> State, compile_seconds, run_seconds).
    """
    times = np.asarray(times, dtype=float)
    n = times.size - 1
    chunk = max(1, min(int(chunk), n))
    step = make_step(scheme, newton, solver)
    run = eqx.filter_jit(make_scan(step, output_fn, control))
    s0 = eqx.filter_jit(initial_state)(model, loading, jnp.asarray(times[0]))
    carry = initial_carry(model, s0, step.solver, 1 if control is not None else 0)
    snap_idx = sorted({int(np.argmin(np.abs(times - ts))) for ts in snapshot_times})
    snapshots = {0: s0} if 0 in snap_idx else {}
    outs, its, facs, cuts = [], [], [], []

    def chunk_args(k):
        m = min(chunk, n - k)
        tt = np.full(chunk, times[k + m])
        tt[:m] = times[k + 1 : k + 1 + m]
        active = np.arange(chunk) < m
        return m, jnp.asarray(tt), jnp.asarray(active)

    tic = _time.perf_counter()
    m, tt, act = chunk_args(0)
    compiled = run.lower(model, loading, carry, tt, act).compile()
    compile_s = _time.perf_counter() - tic
    t_start = _time.perf_counter()
    k = 0
    while k < n:
        m, tt, act = chunk_args(k)
        carry, (o, it, nf, nc, _) = compiled(model, loading, carry, tt, act)
        outs.append(jax.tree_util.tree_map(lambda a: a[:m], o))
        its.append(it[:m])
        facs.append(nf[:m])
        cuts.append(nc[:m])
        k += m
        carry = eqx.tree_at(lambda c: c.step_offset, carry, carry.step_offset + m)
        for j in snap_idx:
            if k - m < j <= k and j not in snapshots:
                snapshots[j] = carry.state
        if progress is not None:  # after a failure: the steps that converged, not the chunk end
            jax.block_until_ready(carry.state.q)
            done = k if int(carry.status) == 0 else max(int(carry.fail_step), 0)
            progress(done, n, float(times[done]), _time.perf_counter() - t_start)
        if int(carry.status) != 0:
            break
    jax.block_until_ready(carry.state.q)
    run_s = _time.perf_counter() - t_start
    out0 = _outputs_at(output_fn, model, loading, s0)
    outputs = jax.tree_util.tree_map(lambda a, *b: jnp.concatenate([a[None], *b]), out0, *outs)
    iterations = jnp.concatenate(its)
    sol = Solution(jnp.asarray(times[: iterations.shape[0] + 1]), outputs, iterations, jnp.concatenate(facs),
                   carry.status, carry.fail_step, carry.state, jnp.concatenate(cuts), carry.h_smallest, carry.last_good)
    return sol, snapshots, compile_s, run_s
