"""Forward models for fitting, built from scenarios (the ``dejax fit`` verb is in ``fitting.cli``).

* ``UniaxialForward``: stretch-controlled uniaxial test (``dejax.scenarios.uniaxial``,
  1 element by default); ``data`` = dict(times (N+1,), knots_t, knots_lam, t_obs,
  [volt_t, volt_v]); predicts the nominal stress at ``t_obs``.
* ``BlockForward``: the DE block under a voltage history; predicts
  ``lateral_stretch`` (or any block output) at ``t_obs``.
* ``RolledForward``: the rolled tube (small mesh); predicts x_P (m) at ``t_obs``.
* ``uniaxial_target(...)``, ``hossain_target(peak, rate, ...)``: Targets for fitting.fit.
* ``from_experiment(exp)``: (forward, params0, free, bounds, targets, holdout, options)
  from a ``fitting.data.Experiment``.

Every trace of one forward is simulated on the same number of steps N (dt =
T / N varies between traces) so that compiled code is shared.
"""
from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from dejax import integrate as it
from dejax import parameters, scenarios

from .fit import Target, fit

__all__ = ["Interp", "UniaxialForward", "BlockForward", "RolledForward", "uniaxial_target", "hossain_target",
           "from_experiment", "run_experiment"]


class Interp(eqx.Module):
    """t -> interp(t, times, values): a history whose knots may be traced arrays."""

    times: jax.Array
    values: jax.Array

    def __call__(self, t):
        return jnp.interp(jnp.asarray(t, dtype=float), self.times, self.values)


def _check_ok(sol, pred):
    return jnp.where(sol.status == 0, pred, jnp.nan)


CHANNEL_UNITS = {"stretch": "1", "displacement": "m", "stress": "Pa"}
"""SI units of the response channels a fit compares (after the trace's unit conversion)."""

FIT_STEP_CONTROL = None
"""Forward models of fits take the user's steps without cut-back: a differentiated run
with cut-back replays its sub-steps (a second forward pass and a second compiled
program), which fits, with hundreds of gradient evaluations, cannot afford yet."""


# The forwards are equinox Modules with static fields only: equal configurations compare and
# hash equal, so fit's compiled functions are reused (fit caches them per forward).


class UniaxialForward(eqx.Module):
    """Stress (Pa) of a stretch-controlled uniaxial test at the observation times.

    n_units: viscous units; lz: thickness (m) when a voltage acts across it;
    voltage: whether ``data`` carries a voltage history; output: "stress".
    Quasi-static (the scenario's default scheme); full Newton (reuse=False), relative
    residual ``tol``, up to 40 iterations.
    """

    n_units: int = eqx.field(static=True, converter=int)
    voltage: bool = eqx.field(static=True, default=False, converter=bool)
    lz: float = eqx.field(static=True, default=1e-3, converter=float)
    output: str = eqx.field(static=True, default="stress")
    tol: float = eqx.field(static=True, default=1e-9, converter=float)
    max_iter: int = eqx.field(static=True, default=40, converter=int)
    reuse: bool = eqx.field(static=True, default=False, converter=bool)

    def problem(self, params, data):
        mat = parameters.from_flat(params, self.n_units)
        volt = Interp(data["volt_t"], data["volt_v"]) if self.voltage else None
        p = scenarios.uniaxial(Interp(data["knots_t"], data["knots_lam"]), mat, voltage=volt, lz=self.lz,
                               damping=params.get("c_d", 0.0))
        return p

    def simulate(self, params, data):
        p = self.problem(params, data)
        return it.simulate(p.model, p.loading, data["times"], p.output_fn, p.scheme(),
                           it.NewtonOptions(tol=self.tol, max_iter=self.max_iter, reuse=self.reuse),
                           control=FIT_STEP_CONTROL)

    def __call__(self, params, data):
        sol = self.simulate(params, data)
        return _check_ok(sol, jnp.interp(data["t_obs"], data["times"], sol.outputs[self.output]))


class BlockForward(eqx.Module):
    """An output of the DE block (default lateral_stretch) under a voltage history."""

    n_units: int = eqx.field(static=True, converter=int)
    L: float = eqx.field(static=True, default=1e-3, converter=float)
    output: str = eqx.field(static=True, default="lateral_stretch")
    rho_inf: float = eqx.field(static=True, default=0.8, converter=float)

    def simulate(self, params, data):
        mat = parameters.from_flat(params, self.n_units)
        p = scenarios.block(L=self.L, material=mat, voltage=Interp(data["volt_t"], data["volt_v"]),
                            damping=params.get("c_d", 0.0))
        return it.simulate(p.model, p.loading, data["times"], p.output_fn, it.GeneralizedAlpha(self.rho_inf),
                           control=FIT_STEP_CONTROL)

    def __call__(self, params, data):
        sol = self.simulate(params, data)
        return _check_ok(sol, jnp.interp(data["t_obs"], data["times"], sol.outputs[self.output]))


class RolledForward(eqx.Module):
    """Axial displacement x_P (m) of the rolled tube under a voltage history."""

    n_units: int = eqx.field(static=True, converter=int)
    h: float = eqx.field(static=True, converter=float)
    r: float = eqx.field(static=True, converter=float)
    L: float = eqx.field(static=True, converter=float)
    shape: tuple = eqx.field(static=True, default=(1, 4, 1), converter=lambda s: tuple(int(n) for n in s))
    rho_inf: float = eqx.field(static=True, default=0.8, converter=float)
    output: str = eqx.field(static=True, default="x_P")

    def simulate(self, params, data):
        mat = parameters.from_flat(params, self.n_units)
        p = scenarios.rolled(mat, h=self.h, r=self.r, L=self.L, shape=self.shape,
                             voltage=Interp(data["volt_t"], data["volt_v"]), damping=params.get("c_d", 0.0))
        return it.simulate(p.model, p.loading, data["times"], p.output_fn, it.GeneralizedAlpha(self.rho_inf),
                           control=FIT_STEP_CONTROL)

    def __call__(self, params, data):
        sol = self.simulate(params, data)
        return _check_ok(sol, jnp.interp(data["t_obs"], data["times"], sol.outputs[self.output]))


# ----------------------------------------------------------------------------- targets


def _subsample(n: int, max_points: int | None) -> np.ndarray:
    if max_points is None or n <= max_points:
        return np.arange(n)
    return np.unique(np.round(np.linspace(0, n - 1, max_points)).astype(int))


def turning_points(times, values, rel: float = 1e-3) -> np.ndarray:
    """Times (s) where a piecewise-linear history (knots ``times``, ``values``) reverses
    direction, ignoring moves below ``rel`` of its range (digitizing jitter)."""
    t, v = np.asarray(times, dtype=float), np.asarray(values, dtype=float)
    if t.size < 3:
        return np.zeros(0)
    tol = rel * max(float(np.ptp(v)), 1e-300)
    out, ext, direction = [], 0, 0  # ext: index of the extreme so far; direction: +1 rising, -1 falling
    for i in range(1, t.size):
        d = v[i] - v[ext]
        if direction == 0:
            if abs(d) > tol:
                direction, ext = int(np.sign(d)), i
        elif direction * d > 0:  # further the same way: a new extreme
            ext = i
        elif -direction * d > tol:  # reversed by more than the jitter
            out.append(t[ext])
            direction, ext = -direction, i
    return np.asarray(out)


def step_grid(t_end: float, n_steps: int, nodes=()) -> np.ndarray:
    """(n_steps + 1,) time grid over [0, t_end] through the interior ``nodes`` (s): uniform
    between consecutive nodes, the steps shared out in proportion to the segments' lengths
    (at least one each). A kink of the loading on a grid node keeps the time scheme's order
    (between nodes the history is smooth); off the grid it costs first-order error."""
    cuts = np.unique(np.concatenate([[0.0, float(t_end)], [x for x in np.asarray(nodes, float) if 0 < x < t_end]]))
    lengths = np.diff(cuts)
    n = np.maximum(1, np.floor(n_steps * lengths / t_end).astype(int))
    while n.sum() < n_steps:  # largest remaining step first
        n[np.argmax(lengths / n)] += 1
    while n.sum() > n_steps and np.any(n > 1):
        i = np.argmin(np.where(n > 1, lengths / n, np.inf))
        n[i] -= 1
    parts = [np.linspace(a, b, k + 1)[1:] for a, b, k in zip(cuts[:-1], cuts[1:], n)]
    return np.concatenate([[0.0], *parts])


STRETCH_PER_STEP = 5e-3
"""Default stretch travelled per step of a uniaxial fit (the grid has a node at every
turning point): the stress of the example fit's traces within 0.15 % of their amplitude of
a 16x finer grid (max), 0.03 % RMS."""


def uniaxial_target(name, time, stretch, stress, n_steps: int, voltage=None, max_points=None, knots=None,
                    weight=1.0) -> Target:
    """Target for ``UniaxialForward``: the measured stress at the measured times.

    The prescribed stretch history interpolates ``knots`` = (times, stretches) if
    given, else the measured (time, stretch) pairs. The simulation runs on ``n_steps``
    steps over [0, time[-1]], uniform between the history's turning points (grid nodes).
    """
    time, stretch, stress = (np.asarray(a, dtype=float) for a in (time, stretch, stress))
    kt, kl = (time, stretch) if knots is None else (np.asarray(knots[0], float), np.asarray(knots[1], float))
    keep = np.concatenate([[True], np.diff(kt) > 0])  # strictly increasing knots
    kt, kl = kt[keep], kl[keep]
    idx = _subsample(time.size, max_points)
    data = dict(times=jnp.asarray(step_grid(float(time[-1]), n_steps, turning_points(kt, kl))),
                knots_t=jnp.asarray(kt), knots_lam=jnp.asarray(kl), t_obs=jnp.asarray(time[idx]))
    if voltage is not None:
        data["volt_t"] = jnp.asarray(time[keep] if knots is None else time)
        data["volt_v"] = jnp.asarray(np.asarray(voltage, float)[keep] if knots is None else voltage)
    return Target(name, stress[idx], data, t=time[idx], x=stretch[idx], weight=weight, ylabel="nominal stress (Pa)",
                  xlabel="stretch", unit="Pa")


def triangle_knots(time, stretch):
    """(times, stretches) of the ideal loading-unloading triangle through the start, peak and end."""
    i = int(np.argmax(stretch))
    return np.array([time[0], time[i], time[-1]]), np.array([stretch[0], stretch[i], stretch[-1]])


def hossain_target(peak: float, rate: float, n_steps: int, max_points=None) -> Target:
    """Target of one Hossain et al. (2012) VHB 4910 curve, ideal triangle stretch history."""
    from .datasets import load_hossain2012

    c = load_hossain2012(peak, rate)
    return uniaxial_target(f"hossain_{peak:g}_{rate:g}", c.time, c.stretch, c.stress, n_steps,
                           max_points=max_points, knots=triangle_knots(c.time, c.stretch))


# ----------------------------------------------------------------------------- experiment files


def from_experiment(exp, n_steps: int | None = None, max_points: int | None = None):
    """(forward, params0, free, bounds, targets, holdout, options) for a fitting.data.Experiment."""
    params0 = {k: v for k, v in exp.parameters().items() if parameters.PATTERN.match(k)}
    params0["c_d"] = float(exp.solver.get("damping", 0.0))
    free = list(exp.fit.free)
    for k in free:
        if not parameters.PATTERN.match(k):
            raise ValueError(f"free parameter {k!r} is not supported by dejax fit (material parameters and c_d only)")
    if "c_d" in free and params0["c_d"] <= 0:
        params0["c_d"] = 1.0
    bounds = {k: tuple(v) for k, v in exp.fit.bounds.items()}
    opts = dict(exp.fit.options)
    if any(tr.time is None for tr in exp.traces):
        raise ValueError("every trace needs a time column for dejax fit")
    if exp.scenario not in FIT_TARGETS:
        raise ValueError(f"dejax fit: scenario {exp.scenario!r} is not supported (uniaxial, block, rolled)")
    fwd, pairs = FIT_TARGETS[exp.scenario](exp, n_steps, max_points)
    targets = [tg for tr, tg in pairs if tr.role == "fit"]
    holdout = [tg for tr, tg in pairs if tr.role != "fit"]
    if not targets:
        raise ValueError("the experiment has no trace with role = 'fit'")
    return fwd, params0, free, bounds, targets, holdout, opts


def _uniaxial_targets(exp, n_steps, max_points):
    """UniaxialForward and (trace, Target) pairs of a uniaxial experiment: the stress at the
    measured times, one number of steps for every trace (one compiled simulation)."""
    fwd = UniaxialForward(exp.n_units, voltage=any(tr.voltage() is not None for tr in exp.traces),
                          lz=float(exp.geometry.get("h", 1e-3)))
    pairs = []
    for tr in exp.traces:
        lam = tr["stretch"]
        dl = np.sum(np.abs(np.diff(lam)))
        N = int(n_steps) if n_steps is not None else max(int(np.ceil(dl / STRETCH_PER_STEP)), 50)
        v = tr.voltage()
        if fwd.voltage and v is None:
            v = np.zeros_like(tr.time)
        pairs.append((tr, uniaxial_target(tr.name, tr.time, lam, tr["stress"], N, voltage=v if fwd.voltage else None,
                                          max_points=max_points, weight=tr.weight)))
    N = max(int(tg.data["times"].shape[0]) - 1 for _, tg in pairs)
    for _, tg in pairs:
        nodes = turning_points(tg.data["knots_t"], tg.data["knots_lam"])
        tg.data["times"] = jnp.asarray(step_grid(float(tg.data["times"][-1]), N, nodes))
    return fwd, pairs


def _driven_targets(fwd, channel):
    """(trace, Target) pairs builder of a voltage-driven scenario: ``channel`` of each trace
    at its samples, the simulation on one number of steps for every trace (from [solver] dt,
    else 200)."""

    def build(exp, n_steps, max_points):
        dt = exp.solver.get("dt")
        Ts = [float(tr.time[-1]) for tr in exp.traces]
        N = int(n_steps) if n_steps is not None else max(int(np.ceil(T / dt)) if dt else 200 for T in Ts)
        pairs = []
        for tr in exp.traces:
            y = tr[channel]
            v = tr.voltage()
            if v is None:
                raise ValueError(f"trace {tr.name!r}: needs a voltage channel or a loading table")
            idx = _subsample(y.size, max_points)
            data = dict(times=jnp.linspace(0.0, float(tr.time[-1]), N + 1), volt_t=jnp.asarray(tr.time),
                        volt_v=jnp.asarray(v), t_obs=jnp.asarray(tr.time[idx]))
            pairs.append((tr, Target(tr.name, y[idx], data, t=tr.time[idx], x=np.asarray(v)[idx], weight=tr.weight,
                                     ylabel=f"{channel} ({CHANNEL_UNITS[channel].replace('1', '-')})",
                                     xlabel="voltage (V)", unit=CHANNEL_UNITS[channel])))
        return fwd(exp), pairs

    return build


def _block_forward(exp):
    g = exp.geometry
    return BlockForward(exp.n_units, L=float(g.get("L", g.get("lx", 1e-3))), rho_inf=float(exp.solver.get("rho_inf", 0.8)))


def _rolled_forward(exp):
    g = exp.geometry
    return RolledForward(exp.n_units, g["h"], g["r"], g["L"], shape=tuple(g.get("mesh", (1, 4, 1))),
                         rho_inf=float(exp.solver.get("rho_inf", 0.8)))


FIT_TARGETS = {
    "uniaxial": _uniaxial_targets,
    "block": _driven_targets(_block_forward, "stretch"),
    "rolled": _driven_targets(_rolled_forward, "displacement"),
}
"""Scenario name -> ``(exp, n_steps, max_points) -> (forward, [(trace, Target)])``: the
scenarios ``dejax fit`` supports."""


def run_experiment(path, out=None, adam_steps=None, lbfgs_steps=None, n_steps=None, max_points=None,
                   verbose=True, plots=True, optimizer=None):
    """Load an experiment TOML, fit it, write outputs; return the FitResult.

    ``optimizer``: "lm" or "adam-lbfgs" (default: the file's ``[fit] optimizer``, else "lm";
    "adam-lbfgs" when ``adam_steps`` or ``lbfgs_steps`` is given). ``[fit] max_iter`` bounds
    the evaluations of lm and the iterations of adam-lbfgs (half Adam, half L-BFGS)."""
    from .data import load_experiment

    exp = load_experiment(path)
    fwd, params0, free, bounds, targets, holdout, opts = from_experiment(exp, n_steps=n_steps, max_points=max_points)
    max_iter = int(opts.get("max_iter", 40))
    if optimizer is None:
        steps_given = adam_steps is not None or lbfgs_steps is not None
        optimizer = opts.get("optimizer", "adam-lbfgs" if steps_given else "lm")
    a = adam_steps if adam_steps is not None else max_iter // 2
    b = lbfgs_steps if lbfgs_steps is not None else max_iter - a
    res = fit(fwd, params0, free, bounds, targets, holdout, adam_steps=a, lbfgs_steps=b,
              adam_lr=float(opts.get("learning_rate", 0.1)), verbose=verbose, method=optimizer, max_evals=max_iter)
    if out is not None:
        res.save(out, plots=plots)
    return res
