"""The forward model of a gap diagnosis: a baseline simulation with candidate effects
(``fitting.effects``) switched on, predicting the traces' responses.

* ``Forward(problem, output, ...)``: ``predict(effects, trace)`` and ``predict_many(jobs)``
  (the measurement: the sensor effects applied to ``raw``), ``residuals(effects_list,
  traces)``; one compiled ``simulate`` for the baseline and every candidate (effects only
  swap leaves), each simulation cached per trace and model-effect values, the simulations
  of a call run side by side on a thread per CPU core; ``n_sims`` counts them.
* ``residuals_at(fwd, names, traces)``: the residuals as a function of the normalized
  parameters z of the effects ``names`` (``effects.param_list``), several points at once;
  ``fd_jacobian``: their forward-difference Jacobian in z (step ``FD_STEP``).
* ``forward_from_experiment(exp)``: the forward and traces of an experiment file (every scenario);
  ``block_forward``, ``synthetic_traces``: synthetic studies of the block;
  ``simulated_responses``, ``simulate_experiment``: synthetic measurements of any experiment.
"""
from __future__ import annotations

import dataclasses
import os
import threading
from concurrent.futures import ThreadPoolExecutor
from typing import Callable, Mapping, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from dejax import integrate as it
from dejax import loads

from . import effects as fx
from .experiment import SCENARIO_OUTPUT, block_length, experiment_problem, simulate_trace
from .traces import Trace

__all__ = ["Forward", "FD_STEP", "residuals_at", "fd_jacobian", "forward_from_experiment", "block_forward",
           "synthetic_traces", "simulated_responses", "simulate_experiment"]


SIM_THREADS = max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1))
"""Threads that run a call's simulations side by side (``Forward.raw_many``): the usable CPU cores."""


_initial_state = eqx.filter_jit(it.initial_state)


@eqx.filter_jit
def _measure(sensor, t, y):
    """``sensor(t, y)``: the measurement of the output y (one compiled program per sensor
    structure and trace length, not one per operation)."""
    return sensor(t, y)


class Forward:
    """Baseline + effects -> predicted outputs, reusing one compiled simulate.

    problem: a dejax Problem built with ``effects.augment_material(material)``;
    output: the output name (e.g. "lateral_stretch"); transform: optional y -> y' applied
    to the raw output before the sensor (e.g. stretch -> displacement).

    Newton: modified Newton (a reused factorization, Anderson-mixed corrections) by
    default, 4-5x cheaper per step than full Newton on the block and equal to it within
    1e-11 (lags of 10-20 ms, a fast unit, 100x added mass, at dt = 5e-4 and 1.25e-2 s); a
    run that fails with it is rerun with full Newton. Tolerance 1e-6 on the residual relative
    to the step's first (predicted) iterate, already small: the D1 block's lateral stretch
    within 7e-11 of a run at 1e-11 (signal 2e-2), with 3.5 instead of 4.3 iterations per step
    at 1e-8. A failed run is scored with output 1e3 after the failure (a huge residual), not
    raised."""

    def __init__(self, problem, output: str = "lateral_stretch", rho_inf: float | None = None,
                 newton: it.NewtonOptions = it.NewtonOptions(tol=1e-6, max_iter=60, reuse=True),
                 pad_to: int | None = None, transform=None, drive: Callable | None = None):
        self.problem = problem
        self.pieces0 = fx.make_pieces(problem)
        self.output = output
        self.rho_inf = rho_inf  # None: the scenario's (the uniaxial test steps quasi-statically)
        self.drive = drive_voltage if drive is None else drive
        self.newton = newton
        self.pad_to = pad_to
        self.transform = transform
        self._cache: dict = {}
        self.n_sims = 0
        self._count = threading.Lock()

    @property
    def scheme(self):
        """The time scheme of its runs (``experiment.simulate_trace``): quasi-static for the
        uniaxial test, else generalized-alpha at ``rho_inf`` (default the scenario's)."""
        return self.problem.scheme(self.rho_inf)

    @staticmethod
    def _key(effects: Mapping, trace: Trace):
        items = []
        for name in sorted(effects):
            if fx.get(name).kind == "model":
                items.append((name, tuple(sorted((k, round(float(v), 15)) for k, v in effects[name].items()))))
        return (trace.name, tuple(items))

    def _launch(self, effects: Mapping, trace: Trace):
        """Start the simulation of ``trace`` with the model effects of ``effects`` (JAX
        dispatches it asynchronously); returns what ``_finish`` turns into the output."""
        model_fx = {k: v for k, v in effects.items() if fx.get(k).kind == "model"}
        p = fx.apply_effects(self.pieces0, model_fx)
        n = len(trace.time) - 1
        pad = max(self.pad_to or n, n)
        loading = pad_knots(self.drive(p.loading, trace), n, pad)
        with self._count:
            self.n_sims += 1
        state0 = self._start_state(p.model, loading, float(trace.time[0]))
        return p.model, loading, pad, state0, self._simulate(p.model, loading, trace.time, self.newton, state0, pad)

    def _simulate(self, model, loading, times, newton, state0, pad):
        return simulate_trace(self.problem, times, newton, model=model, loading=loading, rho_inf=self.rho_inf,
                              state0=state0, pad_to=pad)

    def _start_state(self, model, loading, t0: float):
        """The state at t0: with a dead load (pre-stress), static equilibrium under it, the
        viscous units not yet relaxed (Cv = I: the load has just been applied, as in the
        reduced model's truth), at rest; else the reference state (``integrate.initial_state``).
        Always given to ``simulate`` (with the same pytree of strongly typed arrays), so a
        pre-loaded run shares the baseline's compiled program."""
        if not np.any(np.asarray(model.dead_load)):
            st = _initial_state(model, loading, jnp.asarray(t0, dtype=float))
        else:
            pre = it.simulate(model, loading, np.array([t0, t0 + 1e-9]), self.problem.output_fn, it.QuasiStatic(),
                              self.newton, control=None)
            st = pre.final  # its element pressures belong to the pre-load: keep them (at rest, t = t0)
            z = jnp.zeros_like(st.q)
            st = eqx.tree_at(lambda s: (s.t, s.v, s.qdd, s.a), st, (jnp.asarray(t0, dtype=float), z, z, z))
        return jax.tree_util.tree_map(lambda a: jnp.asarray(a, dtype=a.dtype), st)  # dtype given: not weakly typed

    def _finish(self, effects: Mapping, trace: Trace, launched) -> np.ndarray:
        model, loading, pad, state0, sol = launched
        if not sol.ok and self.newton.reuse and int(sol.status) == int(it.Status.NEWTON_FAILED):
            sol = self._simulate(model, loading, trace.time, dataclasses.replace(self.newton, reuse=False), state0, pad)
            with self._count:
                self.n_sims += 1
        y = np.asarray(sol.outputs[self.output], dtype=float)
        if not sol.ok:  # failed run: report a huge residual rather than crash the ranking
            y = np.where(np.isfinite(y), y, 0.0)
            y[int(sol.fail_step) + 1:] = 1e3
        if self.transform is not None:
            y = np.asarray(self.transform(y))
        return y

    def raw_many(self, jobs: Sequence[tuple]) -> list[np.ndarray]:
        """Model outputs (before the sensor transform) of ``jobs`` = [(effects, trace)], each
        on its trace's time grid. The simulations not cached run on a pool of threads, one per
        CPU core (``SIM_THREADS``): XLA:CPU runs the programs dispatched from one thread one
        after the other, and releases the GIL while it runs (four 4,000-step block runs on 2
        cores: 7.5 s dispatched together from one thread, 5.3 s from two threads)."""
        if len(self._cache) > 2000:
            self._cache.clear()
        todo = {}
        for effects, trace in jobs:
            key = self._key(effects, trace)
            if key not in self._cache and key not in todo:
                todo[key] = (effects, trace)

        def run(job):
            effects, trace = job
            return self._finish(effects, trace, self._launch(effects, trace))

        workers = min(len(todo), SIM_THREADS)
        if workers > 1:
            with ThreadPoolExecutor(workers) as pool:
                outs = list(pool.map(run, todo.values()))
        else:
            outs = [run(job) for job in todo.values()]
        self._cache.update(zip(todo, outs))
        return [self._cache[self._key(e, t)] for e, t in jobs]

    def raw(self, effects: Mapping, trace: Trace) -> np.ndarray:
        """Model output (before the sensor transform) on the trace's time grid."""
        return self.raw_many([(effects, trace)])[0]

    def predict_many(self, jobs: Sequence[tuple]) -> list[np.ndarray]:
        """Predicted measurements of ``jobs`` = [(effects, trace)] (simulations overlapped)."""
        ys = self.raw_many(jobs)
        out = []
        for (effects, trace), y in zip(jobs, ys):
            # the effects acting on the sensor (sensor effects; mu_drift on a stress output)
            sensor_fx = {k: v for k, v in effects.items() if fx.get(k).acts_on_sensor}
            if sensor_fx:
                s = fx.apply_effects(self.pieces0, sensor_fx).sensor
                y = np.asarray(_measure(s, jnp.asarray(trace.time), jnp.asarray(y)))
            out.append(y)
        return out

    def predict(self, effects: Mapping, trace: Trace) -> np.ndarray:
        return self.predict_many([(effects, trace)])[0]

    def residuals(self, effects_list: Sequence[Mapping], traces: Sequence[Trace]) -> list[np.ndarray]:
        """Residuals (model - measured, concatenated over ``traces``) of each effects dict, the
        simulations of all of them started together."""
        preds = self.predict_many([(e, tr) for e in effects_list for tr in traces])
        k = len(traces)
        return [np.concatenate([p - tr.y for p, tr in zip(preds[i * k:(i + 1) * k], traces)])
                for i in range(len(effects_list))]


def _command(loading: it.Loading, trace: Trace):
    """``trace``'s commanded voltage history beside its slew-limited version
    (``effects.SlewSwitch``; ``effects.slew_limited``, linear between four points per sample
    interval), switched on where the loading's EffectiveVoltage has a slew rate that limits
    (``effects.slew_active``): the same pytree either way, so one compiled simulation serves
    the baseline and the slew-limited candidates."""
    volt = trace.voltage_history
    if volt is None:
        return None
    rate = getattr(loading.voltages[0], "slew_rate", fx.SLEW_OFF)
    if fx.slew_active(rate):
        return fx.SlewSwitch(volt, loads.PiecewiseLinear(*fx.slew_limited(volt, float(rate), trace.time)),
                             jnp.asarray(True))
    grid = fx.slew_grid(trace.time)
    return fx.SlewSwitch(volt, loads.PiecewiseLinear(grid, np.zeros_like(grid)), jnp.asarray(False))


def pad_knots(loading: it.Loading, n: int, pad: int) -> it.Loading:
    """``loading`` with every piecewise-linear history (a trace's measured voltage or stretch,
    a slewed command) extended past its last knot by knots holding its last value, to the
    length it would have on ``pad`` steps instead of the trace's ``n`` (k n + 1 knots ->
    k pad + 1; else the next power of two): the same values on the trace, and one compiled
    program for every trace of a forward (a program per trace length otherwise)."""

    def extend(h):
        if not isinstance(h, loads.PiecewiseLinear):
            return h
        m = int(h.times.shape[0])
        target = (m - 1) // n * pad + 1 if n > 0 and (m - 1) % n == 0 else 1 << (m - 1).bit_length()
        if target <= m:
            return h
        t = np.asarray(h.times)
        span = max(float(t[-1] - t[0]), 1.0)
        extra = t[-1] + span * np.arange(1, target - m + 1)
        return loads.PiecewiseLinear(np.concatenate([t, extra]),
                                     jnp.concatenate([h.values, jnp.full(target - m, h.values[-1])]))

    return jax.tree_util.tree_map(extend, loading, is_leaf=lambda x: isinstance(x, loads.PiecewiseLinear))


def drive_voltage(loading: it.Loading, trace: Trace) -> it.Loading:
    """The loading under ``trace``'s commanded voltage (the first voltage channel's history)."""
    return eqx.tree_at(lambda l: l.voltages[0].base, loading, _command(loading, trace))


def drive_stretch(loading: it.Loading, trace: Trace) -> it.Loading:
    """The uniaxial loading under ``trace``'s measured stretch (linear between samples) and,
    when the scenario has a voltage, its voltage (zero without a voltage column)."""
    loading = eqx.tree_at(lambda l: l.motions[0].stretch, loading,
                          loads.PiecewiseLinear(trace.time, trace.channels["stretch"]))
    if not loading.voltages:
        return loading
    volt = _command(loading, trace)
    return eqx.tree_at(lambda l: l.voltages[0].base, loading, loads.Constant(0.0) if volt is None else volt)


# ----------------------------------------------------------------------------- residuals in normalized parameters


def residuals_at(fwd: Forward, names: Sequence[str], traces: Sequence[Trace],
                 fixed: Mapping | None = None) -> Callable[[Sequence[np.ndarray]], list[np.ndarray]]:
    """``resid_many(zs) -> [residuals]``: the residuals of ``traces`` with the effects
    ``names`` at each normalized point z of ``zs`` (``effects.values_at``; the effects of
    ``fixed`` held), the simulations of all points started together."""
    return lambda zs: fwd.residuals([fx.values_at(names, z, fixed) for z in zs], traces)


FD_STEP = 1e-3
"""Finite-difference step of the diagnosis's Jacobians, in the normalized parameters z in
[0, 1] (one-sided, into the box)."""


def fd_steps(z, h: float = FD_STEP, overrides=None) -> np.ndarray:
    """The steps of ``fd_jacobian`` at z: h, -h where z + h leaves [0, 1], ``overrides`` ({j: step})."""
    steps = np.where(z + h <= 1.0, h, -h)
    for j, s in (overrides or {}).items():
        steps[j] = s
    return steps


def fd_jacobian(resid_many, z, r, h: float = FD_STEP, overrides=None, zero=()) -> np.ndarray:
    """(m, k) forward differences at z (steps ``fd_steps``); ``resid_many(list of z) -> list
    of residuals`` evaluates the points together; the columns ``zero`` (indices known to
    leave the residuals as they are) are zeros, not evaluated."""
    steps = fd_steps(z, h, overrides)
    skip = set(zero)
    cols = [j for j in range(z.size) if j not in skip]
    points = []
    for j in cols:
        zz = z.copy()
        zz[j] += steps[j]
        points.append(zz)
    J = np.zeros((r.size, z.size))
    for j, rj in zip(cols, resid_many(points) if points else []):
        J[:, j] = (rj - r) / steps[j]
    return J


# ----------------------------------------------------------------------------- experiment files


DIAGNOSE_MESH = {"torsional": (12, 2, 2)}
"""Meshes of the diagnosis where an experiment names none and differs from
``experiment.DEFAULT_MESH`` (the torsional strip: coarser, for the many simulations of a diagnosis)."""


def forward_from_experiment(exp) -> tuple[Forward, list[Trace]]:
    """Forward model and traces (the experiment's, with their response channel) of an
    Experiment of any scenario, each simulated on its trace's time grid:

    * block: response ``stretch`` (lateral stretch) or ``displacement`` ((stretch - 1) L, m);
    * rolled: response ``displacement`` or ``x_P`` (axial displacement of point P, m; geometry
      h, r, L, mesh (default 1 x 4 x 1, as fit and run), probe "P_outer" (or "outer") for the
      top face's outer edge, else P, its inner edge);
    * torsional: response ``angle`` (twist, rad) of the free end (geometry h, L,
      W, twist (turns), mesh (default 12 x 2 x 2));
    * uniaxial: response ``stress`` (nominal, Pa) under the trace's measured ``stretch``
      (quasi-static), with its voltage where the experiment has one (geometry L, W, h)."""
    from dejax.material import Material

    channels = {"block": ("stretch", "displacement"), "rolled": ("displacement", "x_P"),
                "torsional": ("angle", "twist_angle"), "uniaxial": ("stress",)}
    if exp.scenario not in channels:
        raise NotImplementedError(f"diagnose: unknown scenario '{exp.scenario}' (known: {', '.join(channels)})")
    g = exp.geometry
    mat = fx.augment_material(Material(**exp.material_kwargs()))
    uniaxial = exp.scenario == "uniaxial"
    traces = []
    channel = None
    for tr in exp.traces:
        ch = next((c for c in channels[exp.scenario] if c in tr.channels), None)
        if ch is None:
            raise ValueError(f"trace '{tr.name}': needs a {' or '.join(repr(c) for c in channels[exp.scenario])} "
                             f"channel for the {exp.scenario} scenario")
        if channel not in (None, ch):
            raise ValueError("all traces must carry the same response channel")
        channel = ch
        if uniaxial and "stretch" not in tr.channels:
            raise ValueError(f"trace '{tr.name}': a uniaxial trace needs its 'stretch' channel "
                             "(the prescribed history)")
        if not uniaxial and tr.voltage_history is None:
            raise ValueError(f"trace '{tr.name}': no voltage column and no loading table")
        traces.append(dataclasses.replace(tr, response=ch))
    pad = max(len(t) for t in traces) - 1
    volts = [tr.voltage_history for tr in traces]
    common = dict(gauss_order=int(exp.solver.get("gauss_order", 3)), damping=float(exp.solver.get("damping", 0.0)))
    volt = next((v for v in volts if v is not None), None)
    stretch = loads.PiecewiseLinear(traces[0].time, traces[0].channels["stretch"]) if uniaxial else None
    prob = experiment_problem(exp.scenario, g, mat, volt, stretch, mesh=DIAGNOSE_MESH.get(exp.scenario), **common)
    output, transform, drive = SCENARIO_OUTPUT[exp.scenario], None, (drive_stretch if uniaxial else None)
    if exp.scenario == "block" and channel == "displacement":
        L = block_length(g)
        transform = lambda y, L=L: (y - 1.0) * L  # noqa: E731
    fwd = Forward(prob, output, rho_inf=exp.solver.get("rho_inf"), pad_to=pad, transform=transform, drive=drive)
    return fwd, traces


# ----------------------------------------------------------------------------- synthetic studies


def block_forward(material=None, L: float = 1e-3, pad_to: int | None = None) -> Forward:
    """Forward model of the 1-element DE block (paper Sec. 4 material by default) with two
    dormant viscous units, output lateral_stretch."""
    from dejax import scenarios as sc

    mat = fx.augment_material(sc.block_material() if material is None else material)
    prob = sc.block(L=L, material=mat, voltage=loads.Sine(12e3, 1.0))
    return Forward(prob, "lateral_stretch", pad_to=pad_to)


def synthetic_traces(fwd: Forward, conditions, truth: Mapping, noise: float, seed: int = 0,
                     n_cycles: float = 3.0, samples_per_cycle: int = 40, channel: str = "stretch") -> list[Trace]:
    """Traces of the block made with the effects ``truth`` ({name: values}) plus white noise,
    their response ``channel`` (the forward's output), under a sine loading.
    conditions: sequence of (name, role, phi_max V, freq Hz)."""
    placeholders = []
    for name, role, phi, f in conditions:
        n = int(round(n_cycles * samples_per_cycle))
        t = np.linspace(0.0, n_cycles / f, n + 1)
        placeholders.append(Trace(t, {channel: np.zeros_like(t)}, role, {"phi_max": phi, "freq": f}, name=name,
                                  loading={"kind": "sine", "phi_max": phi, "freq": f}, response=channel))
    ys = simulated_responses(fwd, placeholders, truth, noise, seed)
    return [dataclasses.replace(tr, channels={channel: y}) for tr, y in zip(placeholders, ys)]


def simulated_responses(fwd: Forward, traces: Sequence[Trace], truth: Mapping, noise: float,
                        seed: int = 0) -> list[np.ndarray]:
    """Synthetic measurements of ``traces``: each one's response predicted with the effects
    ``truth`` ({name: values}) plus white noise of standard deviation ``noise`` (the
    response's unit), drawn in trace order from one generator seeded ``seed``."""
    rng = np.random.default_rng(seed)
    return [np.asarray(fwd.predict(truth, tr)) + noise * rng.standard_normal(len(tr.time)) for tr in traces]


def simulate_experiment(path, truth: Mapping, noise: float, seed: int = 0) -> tuple[list[Trace], list[np.ndarray]]:
    """The traces of the experiment file ``path`` (any scenario) and their synthetic
    measurements (``simulated_responses``): what the example generators of
    ``data/examples/make_*_diagnose.py`` write, each in its own CSV layout."""
    from .data import load_experiment

    fwd, traces = forward_from_experiment(load_experiment(path))
    return traces, simulated_responses(fwd, traces, truth, noise, seed)
