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

Derivatives: the converged step solution is differentiated implicitly
(``jax.custom_jvp``: K dz = -dR), never through the Newton iterations; the rule
is linear in the tangents, so reverse mode (``jax.grad``) works by transposition.
"""
from __future__ import annotations

import dataclasses
import enum
import time as _time
from typing import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from . import model as mdl
from .linsolve import DenseSolver
from .material import det3
from .model import Model


class Status(enum.IntEnum):
    """Outcome of a step or a run."""

    OK = 0
    NEWTON_FAILED = 1
    GENT_LIMIT = 2
    NONFINITE = 3
    INVERTED = 4

    def describe(self) -> str:
        return {
            Status.OK: "completed",
            Status.NEWTON_FAILED: "Newton iterations did not converge (diverging solve; possible "
            "electromechanical instability or too large a time step)",
            Status.GENT_LIMIT: "the Gent limiting stretch was reached (1 - (I1bar - 3)/Jm <= 0)",
            Status.NONFINITE: "the state became non-finite (NaN or inf)",
            Status.INVERTED: "an element inverted (det F <= 0)",
        }[self]


class SimulationError(RuntimeError):
    """A run failed: the message says what failed and at which time."""

    def __init__(self, status: Status, time: float, step: int, detail: str = ""):
        self.status = Status(status)
        self.time = float(time)
        self.step = int(step)
        msg = f"simulation failed at t = {self.time:.6g} s (step {self.step}): {self.status.describe()}"
        super().__init__(msg + (f"; {detail}" if detail else ""))


@dataclasses.dataclass(frozen=True)
class GeneralizedAlpha:
    """Generalized-alpha parameters from the spectral radius at infinity (Eqs. 31-32)."""

    rho_inf: float = 0.8

    def __post_init__(self):
        if not 0.0 <= self.rho_inf <= 1.0:
            raise ValueError(f"rho_inf must lie in [0, 1], got {self.rho_inf}")

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


@dataclasses.dataclass(frozen=True)
class NewtonOptions:
    """Newton controls.

    Converged when max |dz_i| / scale_i <= tol, with scale_i the element size for
    positions and 1 for gradient coordinates (a strain-like measure).

    reuse: modified Newton: keep the factorized iteration matrix over iterations and
      steps, and refactor only when an iteration contracts the correction by less than
      ``refactor_rate`` (or at the first use). False: full Newton (refactor every iteration).
    predictor: starting iterate of each step: "velocity" (q_n + h v_n, the default: robust
      for quasi-static ramps with large steps, where the acceleration-based predictor and a
      reused factorization were seen to fail), "paper" (Eq. 33, uses the acceleration) or
      "constant" (q_n). The converged solution does not depend on it.
    """

    tol: float = 1e-9
    max_iter: int = 25
    reuse: bool = True
    refactor_rate: float = 0.2
    predictor: str = "velocity"

    def __post_init__(self):
        if self.predictor not in ("paper", "velocity", "constant"):
            raise ValueError(f"predictor must be 'paper', 'velocity' or 'constant', got {self.predictor!r}")


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
    """Time-stepping state: t (s), q, v, qdd, a (n_dofs,), Cv (n_el, n_gp, n_units, 3, 3)."""

    t: jax.Array
    q: jax.Array
    v: jax.Array
    qdd: jax.Array
    a: jax.Array
    Cv: jax.Array


def _initial_state_jit(model, loading, t0):
    return initial_state(model, loading, t0)


_initial_state_jit = eqx.filter_jit(_initial_state_jit)


def initial_state(model: Model, loading: Loading | None = None, t0: float = 0.0, q=None, v=None) -> State:
    """State at t0: reference (or given) coordinates and velocities, Cv = I, and the
    acceleration consistent with the equations of motion (M qdd = Q_ext - Q_int - C v)."""
    s = model.structure
    q = model.q0 if q is None else jnp.asarray(q, dtype=float)
    v = jnp.zeros_like(q) if v is None else jnp.asarray(v, dtype=float)
    Cv = mdl.initial_viscous_state(model)
    loading = Loading() if loading is None else loading
    phi = loading.phi(t0) if model.field_dirs.shape[0] else jnp.zeros(0)
    E = mdl.nominal_field(model, phi)
    f_int, _ = mdl.internal_force(model, q, E, Cv, 1.0)
    rhs = mdl.reduce(model, mdl.gravity_force(model) - f_int - model.damping * mdl.mass_apply(model, v))
    Mff = mdl.assemble_dense(model, mdl.mass_elements(model)) if s.n_free <= 4000 else None
    if Mff is not None:
        qdd_f = jnp.linalg.solve(Mff, rhs)
    else:  # large: start from rest (rhs is zero at a reference state without load)
        qdd_f = jnp.zeros(s.n_free)
    qdd = mdl.expand(model, qdd_f)
    return State(t=jnp.asarray(t0, dtype=float), q=q, v=v, qdd=qdd, a=qdd, Cv=Cv)


# ----------------------------------------------------------------------------- one step


class _StepContext(eqx.Module):
    """Everything a step's residual depends on besides the unknown z (differentiable)."""

    state: State
    t1: jax.Array
    phi1: jax.Array
    u1: jax.Array
    f_ext: jax.Array


def _kinematics(scheme: GeneralizedAlpha, ctx: _StepContext, q):
    """(qdd_{n+1}, v_{n+1}, a_{n+1}) implied by q_{n+1}."""
    s = ctx.state
    h = ctx.t1 - s.t
    b, g, am, af = scheme.beta, scheme.gamma, scheme.alpha_m, scheme.alpha_f
    a1 = (q - s.q - h * s.v - h * h * (0.5 - b) * s.a) / (h * h * b)
    qdd1 = ((1.0 - am) * a1 + am * s.a - af * s.qdd) / (1.0 - af)
    v1 = s.v + h * (1.0 - g) * s.a + h * g * a1
    return qdd1, v1, a1


def _step_terms(model: Model, scheme, ctx: _StepContext, z):
    """Shared part of the residual at q_{n+1}(z): (q, E, h, M qdd + c_d M v - Q_ext)."""
    q = mdl.full_coordinates(model, z, ctx.u1)
    qdd1, v1, _ = _kinematics(scheme, ctx, q)
    E = mdl.nominal_field(model, ctx.phi1)
    h = ctx.t1 - ctx.state.t
    return q, E, h, mdl.mass_apply(model, qdd1 + model.damping * v1) - ctx.f_ext


def _residual(model: Model, scheme, ctx: _StepContext, z):
    """Free part of Eq. (28) at q_{n+1}(z): (n_free,), and the updated Cv."""
    q, E, h, r_inertia = _step_terms(model, scheme, ctx, z)
    f_int, Cv1 = mdl.internal_force(model, q, E, ctx.state.Cv, h)
    return mdl.reduce(model, r_inertia + f_int), Cv1


def _iteration_matrix(model: Model, scheme, ctx: _StepContext, z):
    """(R, element iteration matrices beta' M + gamma' c_d M + K) at z."""
    q, E, h, r_inertia = _step_terms(model, scheme, ctx, z)
    fe, Ke, _ = mdl.element_tangents(model, q, E, ctx.state.Cv, h)
    R = r_inertia + mdl.scatter_slots(model, fe)
    bp = (1.0 - scheme.alpha_m) / ((1.0 - scheme.alpha_f) * scheme.beta * h * h)
    gp = scheme.gamma / (scheme.beta * h)
    Ke = Ke + (bp + gp * model.damping) * mdl.mass_elements(model)
    return mdl.reduce(model, R), Ke


def _make_newton(scheme: GeneralizedAlpha, opts: NewtonOptions, solver):
    """Newton solve of one step, z* = newton(model, ctx, z0, fac, valid).

    Returns (z*, iterations, factorizations, err, fac): fac is the factorization in use
    at the end (handed to the next step). Derivatives of z* are implicit (custom_jvp).
    """

    def _solve(model, ctx, z0, fac, valid):
        scale = jnp.asarray(model.structure.dof_scale)

        def body(c):
            z, err, err_prev, it, nfac, finite, fac, valid = c
            slow = (it >= 1) & (err > opts.refactor_rate * err_prev)
            need = (~valid) | slow if opts.reuse else jnp.asarray(True)

            def refactor(z):
                R, Ke = _iteration_matrix(model, scheme, ctx, z)
                return R, solver.factor(model, Ke)

            def keep(z):
                return _residual(model, scheme, ctx, z)[0], fac

            R, fac = jax.lax.cond(need, refactor, keep, z)
            dz = _backtrack(model, ctx, z, solver.solve_factored(model, fac, -R))
            e = jnp.max(jnp.abs(dz) / scale)
            ok = jnp.all(jnp.isfinite(dz)) & jnp.isfinite(e)
            # a stale factorization that diverges (or yields non-finite values) is not
            # applied: the iterate is kept and the next iteration refactors
            reject = (~need) & ((~ok) | ((it >= 1) & (e > err)))
            z = jnp.where(reject | ~ok, z, z + dz)
            e = jnp.where(reject, err, e)
            finite = ok | reject
            return z, e, jnp.where(reject, err_prev, err), it + 1, nfac + need.astype(int), finite, fac, ~reject

        def cond(c):
            _, err, _, it, _, finite, _, _ = c
            return (err > opts.tol) & (it < opts.max_iter) & finite

        inf = jnp.asarray(jnp.inf)
        c0 = (z0, inf, inf, jnp.asarray(0), jnp.asarray(0), jnp.asarray(True), fac, jnp.asarray(valid))
        z, err, _, it, nfac, finite, fac, _ = jax.lax.while_loop(cond, body, c0)
        err = jnp.where(finite, err, jnp.inf)
        return z, it, nfac, err, fac

    @jax.custom_jvp
    def newton(model, ctx, z0, fac, valid):
        return _solve(model, ctx, z0, fac, valid)

    @newton.defjvp
    def newton_jvp(primals, tangents):
        model, ctx, z0, fac, valid = primals
        dmodel, dctx = tangents[0], tangents[1]
        out = newton(model, ctx, z0, fac, valid)
        z = out[0]
        _, dR = jax.jvp(lambda m, c: _residual(m, scheme, c, z)[0], (model, ctx), (dmodel, dctx))
        _, Ke = _iteration_matrix(model, scheme, ctx, z)
        dz = solver.solve(model, Ke, -dR)
        return out, (dz, *(_zero_tangent(x) for x in out[1:]))

    return newton


def _admissible(model: Model, ctx: _StepContext, z) -> jax.Array:
    """True if every Gauss point has det F > 0 and lies inside the Gent limits (viscous
    branches judged with the step's starting Cv)."""
    q = mdl.full_coordinates(model, z, ctx.u1)
    F = mdl.deformation_gradients(model, q)
    J = jax.vmap(jax.vmap(det3))(F)
    H = mdl.gent_margins(model, q, ctx.state.Cv)
    return jnp.all(J > 0) & jnp.all(H > 0)


def _backtrack(model: Model, ctx: _StepContext, z, dz, max_halvings: int = 12):
    """Halve the Newton correction until the new iterate is admissible (safeguarded Newton:
    keeps iterates out of inverted or past-Gent-limit states where the energy is undefined)."""

    def cond(c):
        a, k = c
        return (~_admissible(model, ctx, z + a * dz)) & (k < max_halvings)

    a, _ = jax.lax.while_loop(cond, lambda c: (0.5 * c[0], c[1] + 1), (jnp.asarray(1.0), 0))
    return a * dz


def _zero_tangent(x):
    """A zero tangent for any pytree (float0 for integer leaves)."""
    def leaf(a):
        a = jnp.asarray(a)
        if jnp.issubdtype(a.dtype, jnp.integer) or a.dtype == bool:
            return np.zeros(a.shape, dtype=jax.dtypes.float0)
        return jnp.zeros_like(a)

    return jax.tree_util.tree_map(leaf, x)


def make_step(scheme: GeneralizedAlpha = GeneralizedAlpha(), opts: NewtonOptions = NewtonOptions(), solver=None):
    """Return ``step(model, loading, state, t1, fac, valid) -> (state1, iterations,
    factorizations, status, fac1)``. ``solver``: a linsolve solver (default DenseSolver)."""
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
            f_ext=mdl.gravity_force(model),
        )
        # predictor (Eq. 33)
        b, am, af = scheme.beta, scheme.alpha_m, scheme.alpha_f
        a0 = (af * state.qdd - am * state.a) / (1.0 - am)
        if opts.predictor == "paper":
            q_pred = state.q + h * state.v + h * h * (0.5 - b) * state.a + h * h * b * a0
        elif opts.predictor == "velocity":
            q_pred = state.q + h * state.v
        else:
            q_pred = state.q
        z, it, nfac, err, fac = newton(model, ctx, q_pred[s.free], fac, valid)
        q1 = mdl.full_coordinates(model, z, ctx.u1)
        qdd1, v1, a1 = _kinematics(scheme, ctx, q1)
        E = mdl.nominal_field(model, ctx.phi1)
        _, Cv1 = mdl.internal_force(model, q1, E, state.Cv, h)
        new = State(t=t1, q=q1, v=v1, qdd=qdd1, a=a1, Cv=Cv1)
        F = mdl.deformation_gradients(model, q1)
        finite = jnp.all(jnp.isfinite(q1)) & jnp.all(jnp.isfinite(Cv1))
        inverted = jnp.any(jnp.linalg.det(F) <= 0)
        gent = jnp.min(mdl.gent_margins(model, q1, Cv1)) <= 0
        # a step that did not converge is reported as such (its last iterate's state says
        # nothing reliable about Gent limits or inversion)
        status = jnp.where(
            ~finite,
            int(Status.NONFINITE),
            jnp.where(
                err > opts.tol,
                int(Status.NEWTON_FAILED),
                jnp.where(inverted, int(Status.INVERTED), jnp.where(gent, int(Status.GENT_LIMIT), 0)),
            ),
        )
        return new, it, nfac, status, fac

    step.solver = solver
    return step


# ----------------------------------------------------------------------------- runs


class Carry(eqx.Module):
    """Scan carry: state, status, first failed step, step offset (chunked runs), and the
    iteration-matrix factorization reused across steps (with its validity flag)."""

    state: State
    status: jax.Array
    fail_step: jax.Array
    step_offset: jax.Array
    fac: object
    fac_valid: jax.Array


def initial_carry(model: Model, state: State, solver) -> Carry:
    return Carry(state, jnp.asarray(0), jnp.asarray(-1), jnp.asarray(0), solver.empty(model), jnp.asarray(False))


def make_scan(step, output_fn: Callable):
    """Return ``run(model, loading, carry, times, active) -> (carry, (outputs, iterations,
    factorizations))``: lax.scan of ``step`` over the time grid ``times`` (n,), skipping
    inactive entries (padding) and every step after a failure."""

    def run(model, loading, carry: Carry, times, active):
        def body(c: Carry, xs):
            t1, k, on = xs

            def do(c):
                new, it, nfac, st, fac = step(model, loading, c.state, t1, c.fac, c.fac_valid)
                failed = st != 0
                state = jax.tree_util.tree_map(lambda a, b: jnp.where(failed, a, b), c.state, new)
                return Carry(state, st, jnp.where(failed, k, c.fail_step), c.step_offset, fac, ~failed), (it, nfac)

            def skip(c):
                return c, (jnp.asarray(0), jnp.asarray(0))

            c, (it, nfac) = jax.lax.cond((c.status == 0) & on, do, skip, c)
            return c, (output_fn(model, loading, c.state), it, nfac)

        steps = jnp.arange(times.shape[0]) + carry.step_offset
        return jax.lax.scan(body, carry, (times, steps, active))

    return run


@dataclasses.dataclass
class Solution:
    """What ``simulate`` returns.

    time: (n+1,) s; outputs: name -> (n+1, ...) arrays (row 0 = initial state);
    iterations: (n,) Newton iterations per step; factorizations: (n,) iteration-matrix
    factorizations per step; status: Status; fail_time (s) and
    fail_step (-1 if none); final: the last State (the last converged one after a failure).
    """

    time: jax.Array
    outputs: dict
    iterations: jax.Array
    factorizations: jax.Array
    status: jax.Array
    fail_step: jax.Array
    final: State

    @property
    def ok(self) -> bool:
        return int(self.status) == 0

    @property
    def fail_time(self) -> float:
        k = int(self.fail_step)
        return float(self.time[k + 1]) if k >= 0 else float("nan")

    def check(self) -> "Solution":
        """Raise SimulationError naming what failed and when; return self otherwise."""
        if not self.ok:
            raise SimulationError(Status(int(self.status)), self.fail_time, int(self.fail_step) + 1)
        return self


jax.tree_util.register_pytree_node(
    Solution,
    lambda s: ((s.time, s.outputs, s.iterations, s.factorizations, s.status, s.fail_step, s.final), None),
    lambda _, c: Solution(*c),
)


def time_grid(t_end: float, dt: float, t0: float = 0.0) -> np.ndarray:
    """(n+1,) uniform grid from t0 to t_end with n = ceil((t_end - t0)/dt - 1e-9) steps."""
    if not (dt > 0):
        raise ValueError(f"time step dt must be > 0, got {dt}")
    if not (t_end > t0):
        raise ValueError(f"end time t_end = {t_end} must exceed the start time {t0}")
    n = int(np.ceil((t_end - t0) / dt - 1e-9))
    return np.linspace(t0, t_end, n + 1)


def simulate(
    model: Model,
    loading: Loading,
    times,
    output_fn: Callable,
    scheme: GeneralizedAlpha = GeneralizedAlpha(),
    newton: NewtonOptions = NewtonOptions(),
    solver=None,
    state0: State | None = None,
    pad_to: int | None = None,
) -> Solution:
    """Integrate over the time grid ``times`` (n+1,) in one jitted ``lax.scan``.

    Pure and differentiable (jax.jvp / jax.grad / jax.vmap) in ``model`` and
    ``loading`` arrays. ``output_fn(model, loading, state) -> dict`` is recorded at
    every grid time; it is a static argument (use a hashable callable object to share
    compiled code between calls). ``pad_to`` (>= n) pads the scan with skipped steps so
    that runs of different lengths share one compilation. The returned Solution carries
    the status; call ``.check()`` to raise on failure.
    """
    times = np.asarray(times, dtype=float) if not isinstance(times, jax.core.Tracer) else times
    n = times.shape[0] - 1
    m = n if pad_to is None else int(pad_to)
    if m < n:
        raise ValueError(f"pad_to = {m} is smaller than the number of steps {n}")
    tt = jnp.concatenate([jnp.asarray(times[1:], dtype=float), jnp.full(m - n, times[-1])])
    active = jnp.arange(m) < n
    sol = _simulate_jit(model, loading, jnp.asarray(times[0], dtype=float), tt, active, output_fn, scheme, newton, solver, state0)
    outputs = jax.tree_util.tree_map(lambda a: a[: n + 1], sol.outputs)
    return Solution(jnp.asarray(times), outputs, sol.iterations[:n], sol.factorizations[:n], sol.status, sol.fail_step,
                    sol.final)


@eqx.filter_jit
def _simulate_jit(model, loading, t0, times, active, output_fn, scheme, newton, solver, state0):
    step = make_step(scheme, newton, solver)
    run = make_scan(step, output_fn)
    s0 = initial_state(model, loading, t0) if state0 is None else state0
    carry, (outs, its, nfac) = run(model, loading, initial_carry(model, s0, step.solver), times, active)
    out0 = output_fn(model, loading, s0)
    outputs = jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a[None], b]), out0, outs)
    return Solution(times, outputs, its, nfac, carry.status, carry.fail_step, carry.state)


def run_chunked(
    model: Model,
    loading: Loading,
    times,
    output_fn: Callable,
    scheme: GeneralizedAlpha = GeneralizedAlpha(),
    newton: NewtonOptions = NewtonOptions(),
    solver=None,
    chunk: int = 500,
    progress: Callable | None = None,
    snapshot_times=(),
):
    """``simulate`` in jitted chunks of ``chunk`` steps: progress reports and full states at
    chunk ends. Every chunk has the same compiled length (the last one is padded), so
    there is one compilation.

    Args:
      progress: optional ``progress(steps_done, n_steps, t, wall_seconds)``.
      snapshot_times: times (s) at which to keep the full State (taken at the first chunk
        end at or after each time; pass ``chunk`` dividing the snapshot spacing for exact times).
    Returns:
      (Solution, snapshots: dict step -> State, compile_seconds, run_seconds).
    """
    times = np.asarray(times, dtype=float)
    n = times.size - 1
    chunk = max(1, min(int(chunk), n))
    step = make_step(scheme, newton, solver)
    run = eqx.filter_jit(make_scan(step, output_fn))
    s0 = _initial_state_jit(model, loading, jnp.asarray(times[0]))
    carry = initial_carry(model, s0, step.solver)
    snap_idx = sorted({int(np.argmin(np.abs(times - ts))) for ts in snapshot_times})
    snapshots = {0: s0} if 0 in snap_idx else {}
    outs, its, facs = [], [], []

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
        carry, (o, it, nf) = compiled(model, loading, carry, tt, act)
        outs.append(jax.tree_util.tree_map(lambda a: a[:m], o))
        its.append(it[:m])
        facs.append(nf[:m])
        k += m
        carry = Carry(
            carry.state, carry.status, carry.fail_step, carry.step_offset + m, carry.fac, carry.fac_valid)
        for j in snap_idx:
            if k - m < j <= k and j not in snapshots:
                snapshots[j] = carry.state
        if progress is not None:
            jax.block_until_ready(carry.state.q)
            progress(k, n, float(times[k]), _time.perf_counter() - t_start)
        if int(carry.status) != 0:
            break
    jax.block_until_ready(carry.state.q)
    run_s = _time.perf_counter() - t_start
    out0 = output_fn(model, loading, s0)
    outputs = jax.tree_util.tree_map(lambda a, *b: jnp.concatenate([a[None], *b]), out0, *outs)
    iterations = jnp.concatenate(its)
    sol = Solution(jnp.asarray(times[: iterations.shape[0] + 1]), outputs, iterations, jnp.concatenate(facs),
                   carry.status, carry.fail_step, carry.state)
    return sol, snapshots, compile_s, run_s
