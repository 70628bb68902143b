"""The problem of an experiment file, and the forward models of fits (the ``dejax fit`` verb
is in ``fitting.cli``).

* ``experiment_problem(scenario, geometry, material, voltage, stretch)``: the scenario's
  Problem from an experiment's ``[geometry]``: the one builder behind ``dejax run``, the
  forwards of ``dejax fit`` (below) and the diagnosis's (``fitting.forward``).
* ``UniaxialForward``: stretch-controlled uniaxial test (``dejax.scenarios.uniaxial``,
  1 element by default); ``data`` = dict(times (N+1,), knots_t, knots_lam, t_obs,
  [volt_t, volt_v]); predicts the nominal stress at ``t_obs``.
* ``BlockForward``: the DE block under a voltage history; predicts
  ``lateral_stretch`` (or any block output) at ``t_obs``.
* ``RolledForward``: the rolled tube (small mesh); predicts x_P (m) at ``t_obs``.
  The three share one protocol: ``forward(params, data)`` -> the predicted response at
  ``data["t_obs"]``, differentiable in the material parameters ``params``.
* ``uniaxial_target(...)``, ``hossain_target(peak, rate, ...)``: traces for fitting.fit (a
  ``fitting.traces.Trace`` with its response, the forward's ``data`` and plot labels).
* ``from_experiment(exp)``: (forward, params0, free, bounds, targets, holdout, options)
  from a ``fitting.data.Experiment``: its traces at the observation times, with ``data``.
* ``experiment_run(exp, trace)``: the ``Problem`` of ``dejax run experiment.toml``: the
  experiment's scenario, material and geometry under one trace's loading, with its
  ``[solver]`` settings.

Every trace of one forward is simulated on the same number of steps N (dt =
T / N varies between traces) so that compiled code is shared.
"""
from __future__ import annotations

import dataclasses
from typing import ClassVar, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from dejax import integrate as it
from dejax import loads, parameters, scenarios
from dejax.material import Material

from .fit import fit
from .traces import Trace
from .units import CHANNELS, SI_UNIT

__all__ = ["Interp", "experiment_problem", "block_length", "DEFAULT_MESH", "SCENARIO_OUTPUT", "simulate_trace",
           "UniaxialForward", "BlockForward",
           "RolledForward", "uniaxial_target", "hossain_target",
           "from_experiment", "run_experiment", "experiment_run", "RunSetup"]


class Interp(eqx.Module):
    """t -> interp(t, times, values): a history whose knots may be traced arrays."""

    times: jax.Array
    values: jax.Array

    def __call__(self, t):
        return jnp.interp(jnp.asarray(t, dtype=float), self.times, self.values)


DEFAULT_MESH = {"block": (1, 1, 1), "rolled": (1, 4, 1), "torsional": (48, 8, 2), "uniaxial": (1, 1, 1)}
"""Mesh (elements per direction) of an experiment's scenario where ``[geometry] mesh`` is absent."""
SCENARIO_OUTPUT = {"block": "lateral_stretch", "rolled": "x_P", "torsional": "twist_angle", "uniaxial": "stress"}
"""Scenario -> the output ``dejax run`` of an experiment reports at the end and a diagnosis
compares with the traces' response."""


def block_length(geometry) -> float:
    """The block's edge length (m) from ``[geometry]``: ``L``, else ``lx``, else 1 mm."""
    return float(geometry.get("L", geometry.get("lx", 1e-3)))


def experiment_problem(scenario: str, geometry, material, voltage=None, stretch=None, mesh=None,
                       **common) -> scenarios.Problem:
    """The Problem an experiment file describes: what ``dejax run``, ``dejax fit`` and
    ``dejax diagnose`` simulate, built in this one place.

    scenario: "block", "rolled", "torsional" or "uniaxial"; geometry: the ``[geometry]``
    keys (``fitting.schema.GEOMETRY_KEYS``; lengths in m, twist in turns, rolled ``probe``
    "P_outer"/"outer" for the top face's outer edge, else P, its inner edge); material: a
    ``Material`` (its leaves may be traced: fits differentiate through them); voltage: the
    voltage history (t -> V; None: none); stretch: the uniaxial test's prescribed stretch
    history; mesh: the mesh where the geometry names none (default ``DEFAULT_MESH``);
    common: the builders' solver keywords (gauss_order, damping, volumetric).
    ValueError for an unknown scenario."""
    g = geometry
    shape = tuple(int(n) for n in g.get("mesh", mesh or DEFAULT_MESH.get(scenario, ())))
    if scenario == "block":
        return scenarios.block(L=block_length(g), shape=shape, material=material,
                               voltage=voltage, **common)
    if scenario == "rolled":
        point = "P_outer" if g.get("probe") in ("P_outer", "outer") else "P"
        return scenarios.rolled(material, h=float(g["h"]), r=float(g["r"]), L=float(g["L"]), shape=shape, point=point,
                                voltage=voltage, **common)
    if scenario == "torsional":
        h = float(g["h"])
        p = scenarios.torsional(material=material, thickness=h, length_ratio=float(g["L"]) / h,
                                width_ratio=float(g["W"]) / h, turns=float(g.get("twist", 1.0)), shape=shape, **common)
        return dataclasses.replace(p, loading=it.Loading(voltages=(voltage,)))
    if scenario == "uniaxial":
        return scenarios.uniaxial(stretch, material, voltage=voltage, lx=float(g.get("L", 1e-3)),
                                  ly=float(g.get("W", 1e-3)), lz=float(g.get("h", 1e-3)), shape=shape, **common)
    raise ValueError(f"unknown scenario {scenario!r} (known: {', '.join(DEFAULT_MESH)})")


FIT_STEP_CONTROL = None
"""Forward models of fits and of the diagnosis take the trace's steps without cut-back: a
differentiated run with cut-back replays its sub-steps (a second forward pass and a second
compiled program), which fits, with hundreds of gradient evaluations, cannot afford yet."""


def simulate_trace(problem: scenarios.Problem, times, newton: it.NewtonOptions, *, model=None, loading=None,
                   rho_inf: float | None = None, state0=None, pad_to: int | None = None) -> it.Solution:
    """One trace of an experiment on its time grid ``times`` (N+1,) s: the one way the
    forwards of fits (``UniaxialForward``, ``BlockForward``, ``RolledForward``) and of the
    diagnosis (``fitting.forward.Forward``) simulate.

    ``problem``'s scheme (quasi-static for the uniaxial test, else generalized-alpha at
    ``rho_inf``, default the scenario's), its output function, the trace's steps as they are
    (``FIT_STEP_CONTROL``: no cut-back); ``model`` and ``loading`` (default the problem's)
    carry the trace's histories and the swapped leaves of fitted parameters or effects;
    ``state0``, ``pad_to`` as in ``integrate.simulate``. Differentiable (jvp, grad) in the
    arrays of ``model`` and ``loading``; returns the Solution (its status says whether it
    converged)."""
    return it.simulate(problem.model if model is None else model, problem.loading if loading is None else loading,
                       times, problem.output_fn, problem.scheme(rho_inf), newton, state0=state0, pad_to=pad_to,
                       control=FIT_STEP_CONTROL)


# The forwards are equinox Modules with static fields only: equal configurations compare and
# hash equal, so fit's compiled functions are reused (fit caches them per forward).


class _AtObservations(eqx.Module):
    """A forward of fits: the Problem of ``experiment_problem`` for ``scenario`` with the
    material of ``params`` (``parameters.from_flat``; damping ``c_d``) and the histories of
    ``data``, simulated on ``data["times"]`` and read at the observation times
    ``data["t_obs"]`` (its output ``output``; NaN where the simulation failed).
    Subclasses name the scenario and give ``geometry()``; ``newton()``: the Newton options
    (default ``integrate.NewtonOptions()``)."""

    scenario: ClassVar[str]

    def geometry(self) -> dict:
        raise NotImplementedError

    def newton(self) -> it.NewtonOptions:
        return it.NewtonOptions()

    def voltage_history(self, data):
        """The voltage history of ``data`` (knots ``volt_t``, ``volt_v``)."""
        return Interp(data["volt_t"], data["volt_v"])

    def problem(self, params, data):
        volt = self.voltage_history(data)
        stretch = Interp(data["knots_t"], data["knots_lam"]) if "knots_t" in data else None
        return experiment_problem(self.scenario, self.geometry(), parameters.from_flat(params, self.n_units),
                                  voltage=volt, stretch=stretch, damping=params.get("c_d", 0.0))

    def simulate(self, params, data):
        """The Solution of ``data``'s trace with the material of ``params`` (``simulate_trace``)."""
        return simulate_trace(self.problem(params, data), data["times"], self.newton(),
                              rho_inf=getattr(self, "rho_inf", None))  # the uniaxial test has none: quasi-static

    def __call__(self, params, data):
        sol = self.simulate(params, data)
        pred = jnp.interp(data["t_obs"], data["times"], sol.outputs[self.output])
        return jnp.where(sol.status == 0, pred, jnp.nan)


class UniaxialForward(_AtObservations):
    """Stress (Pa) of a stretch-controlled uniaxial test at the observation times.

    n_units: viscous units; lz: thickness (m) when a voltage acts across it;
    voltage: whether ``data`` carries a voltage history; output: "stress".
    Quasi-static (the scenario's default scheme); full Newton (reuse=False), relative
    residual ``tol``, up to 40 iterations.
    """

    scenario: ClassVar[str] = "uniaxial"
    n_units: int = eqx.field(static=True, converter=int)
    voltage: bool = eqx.field(static=True, default=False, converter=bool)
    lz: float = eqx.field(static=True, default=1e-3, converter=float)
    output: str = eqx.field(static=True, default="stress")
    tol: float = eqx.field(static=True, default=1e-9, converter=float)
    max_iter: int = eqx.field(static=True, default=40, converter=int)
    reuse: bool = eqx.field(static=True, default=False, converter=bool)

    def geometry(self):
        return {"h": self.lz}

    def voltage_history(self, data):
        return Interp(data["volt_t"], data["volt_v"]) if self.voltage else None

    def newton(self):
        return it.NewtonOptions(tol=self.tol, max_iter=self.max_iter, reuse=self.reuse)


class BlockForward(_AtObservations):
    """An output of the DE block (default lateral_stretch) under a voltage history."""

    scenario: ClassVar[str] = "block"
    n_units: int = eqx.field(static=True, converter=int)
    L: float = eqx.field(static=True, default=1e-3, converter=float)
    output: str = eqx.field(static=True, default="lateral_stretch")
    rho_inf: float = eqx.field(static=True, default=0.8, converter=float)

    def geometry(self):
        return {"L": self.L}


class RolledForward(_AtObservations):
    """Axial displacement x_P (m) of the rolled tube under a voltage history (``probe``
    "P_outer": the top face's outer edge, else its inner edge P)."""

    scenario: ClassVar[str] = "rolled"
    n_units: int = eqx.field(static=True, converter=int)
    h: float = eqx.field(static=True, converter=float)
    r: float = eqx.field(static=True, converter=float)
    L: float = eqx.field(static=True, converter=float)
    shape: tuple = eqx.field(static=True, default=(1, 4, 1), converter=lambda s: tuple(int(n) for n in s))
    rho_inf: float = eqx.field(static=True, default=0.8, converter=float)
    output: str = eqx.field(static=True, default="x_P")
    probe: str = eqx.field(static=True, default="P")

    def geometry(self):
        return {"h": self.h, "r": self.r, "L": self.L, "mesh": self.shape, "probe": self.probe}


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


def uniaxial_steps(stretch) -> int:
    """Default steps of a uniaxial history: ``STRETCH_PER_STEP`` of stretch travelled per
    step, at least 50."""
    travel = float(np.sum(np.abs(np.diff(np.asarray(stretch, dtype=float)))))
    return max(int(np.ceil(travel / STRETCH_PER_STEP)), 50)


UNIAXIAL_LABELS = {"stress": "nominal stress (Pa)", "stretch": "stretch"}
"""Axis labels of a uniaxial fit's plots."""


def uniaxial_target(name, time, stretch, stress, n_steps: int, voltage=None, max_points=None, knots=None,
                    weight=1.0) -> Trace:
    """Trace for ``UniaxialForward``: the measured stress at the measured times (its
    response), against the stretch.

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
    return Trace(time[idx], {"stress": stress[idx], "stretch": stretch[idx]}, name=name, weight=weight,
                 response="stress", against="stretch", data=data, labels=UNIAXIAL_LABELS)


def triangle_knots(time, stretch):
    """(times, stretches) of the ideal loading-unloading triangle through the start, peak and end."""
    i = int(np.argmax(stretch))
    return np.array([time[0], time[i], time[-1]]), np.array([stretch[0], stretch[i], stretch[-1]])


def hossain_target(peak: float, rate: float, n_steps: int, max_points=None) -> Trace:
    """Trace of one Hossain et al. (2012) VHB 4910 curve, ideal triangle stretch history."""
    from .datasets import load_hossain2012

    c = load_hossain2012(peak, rate)
    return uniaxial_target(f"hossain_{peak:g}_{rate:g}", c.time, c.stretch, c.stress, n_steps,
                           max_points=max_points, knots=triangle_knots(c.time, c.stretch))


# ----------------------------------------------------------------------------- experiment files


def from_experiment(exp, n_steps: int | None = None, max_points: int | None = None):
    """(forward, params0, free, bounds, targets, holdout, options) for a fitting.data.Experiment."""
    params0 = {k: v for k, v in exp.parameters().items() if parameters.PATTERN.match(k)}
    params0["c_d"] = float(exp.solver.get("damping", 0.0))
    if float(exp.material.get("mullins_d", 0.0)) > 0:
        raise ValueError("dejax fit does not model Mullins softening (its forwards build the paper's material): "
                         "remove [material] mullins_d, or diagnose with it (dejax diagnose)")
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
    fwd, traces = FIT_TARGETS[exp.scenario](exp, n_steps, max_points)
    targets = [tg for tg in traces if tg.role == "fit"]
    holdout = [tg for tg in traces if tg.role != "fit"]
    if not targets:
        raise ValueError("the experiment has no trace with role = 'fit'")
    return fwd, params0, free, bounds, targets, holdout, opts


def _measured(tg: Trace, tr: Trace) -> Trace:
    """The fit trace ``tg`` with the role, conditions, source and loading of the experiment's
    trace ``tr`` it was built from."""
    return dataclasses.replace(tg, role=tr.role, conditions=tr.conditions, source=tr.source, loading=tr.loading)


def _uniaxial_targets(exp, n_steps, max_points):
    """UniaxialForward and the fit traces of a uniaxial experiment: the stress at the
    measured times, one number of steps for every trace (one compiled simulation)."""
    fwd = UniaxialForward(exp.n_units, voltage=any(tr.voltage() is not None for tr in exp.traces),
                          lz=float(exp.geometry.get("h", 1e-3)))
    traces = []
    for tr in exp.traces:
        lam = tr["stretch"]
        N = int(n_steps) if n_steps is not None else uniaxial_steps(lam)
        v = tr.voltage()
        if fwd.voltage and v is None:
            v = np.zeros_like(tr.time)
        traces.append(_measured(uniaxial_target(tr.name, tr.time, lam, tr["stress"], N,
                                                voltage=v if fwd.voltage else None, max_points=max_points,
                                                weight=tr.weight), tr))
    N = max(int(tg.data["times"].shape[0]) - 1 for tg in traces)

    def regrid(tg):
        nodes = turning_points(tg.data["knots_t"], tg.data["knots_lam"])
        return dataclasses.replace(tg, data={**tg.data, "times": jnp.asarray(step_grid(float(tg.data["times"][-1]), N,
                                                                                          nodes))})

    return fwd, [regrid(tg) for tg in traces]


def _driven_targets(fwd, channel):
    """Fit-trace builder of a voltage-driven scenario: ``channel`` of each trace at its
    samples, against the voltage, the simulation on one number of steps for every trace
    (from [solver] dt, else 200)."""

    def build(exp, n_steps, max_points):
        dt = exp.solver.get("dt")
        Ts = [float(tr.time[-1]) for tr in exp.traces]
        N = int(n_steps) if n_steps is not None else max(int(np.ceil(T / dt)) if dt else 200 for T in Ts)
        labels = {channel: f"{channel} ({SI_UNIT[CHANNELS[channel]]})", "voltage": "voltage (V)"}
        traces = []
        for tr in exp.traces:
            y = tr[channel]
            v = tr.voltage()
            if v is None:
                raise ValueError(f"trace {tr.name!r}: needs a voltage channel or a loading table")
            idx = _subsample(y.size, max_points)
            data = dict(times=jnp.linspace(0.0, float(tr.time[-1]), N + 1), volt_t=jnp.asarray(tr.time),
                        volt_v=jnp.asarray(v), t_obs=jnp.asarray(tr.time[idx]))
            tg = Trace(tr.time[idx], {channel: np.asarray(y[idx], dtype=float), "voltage": np.asarray(v)[idx]},
                       name=tr.name, weight=tr.weight, response=channel, against="voltage", data=data, labels=labels)
            traces.append(_measured(tg, tr))
        return fwd(exp), traces

    return build


def _block_forward(exp):
    return BlockForward(exp.n_units, L=block_length(exp.geometry), rho_inf=float(exp.solver.get("rho_inf", 0.8)))


def _rolled_forward(exp):
    g = exp.geometry
    return RolledForward(exp.n_units, g["h"], g["r"], g["L"], shape=tuple(g.get("mesh", DEFAULT_MESH["rolled"])),
                         rho_inf=float(exp.solver.get("rho_inf", 0.8)), probe=str(g.get("probe", "P")))


FIT_TARGETS = {
    "uniaxial": _uniaxial_targets,
    "block": _driven_targets(_block_forward, "stretch"),
    "rolled": _driven_targets(_rolled_forward, "displacement"),
}
"""Scenario name -> ``(exp, n_steps, max_points) -> (forward, [Trace])`` (the experiment's
traces as its forward compares them: response, ``data``, role): the scenarios ``dejax fit``
supports."""


def run_experiment(path, out=None, adam_steps=None, lbfgs_steps=None, n_steps=None, max_points=None,
                   verbose=True, plots=True, optimizer=None):
    """Load an experiment TOML (``path``; or an already loaded ``fitting.data.Experiment``),
    fit it, write ``out``/fit.json, the plots (``plots``) and ``out``/fitted.toml
    (``fitting.fitted``); return the FitResult.

    ``optimizer``: "lm" or "adam-lbfgs" (default: the file's ``[fit] optimizer``, else "lm";
    "adam-lbfgs" when ``adam_steps`` or ``lbfgs_steps`` is given). ``[fit] max_iter`` bounds
    the evaluations of lm and the iterations of adam-lbfgs (half Adam, half L-BFGS)."""
    from .data import Experiment, load_experiment
    from .fitted import write_fitted

    exp = path if isinstance(path, Experiment) else load_experiment(path)
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
        write_fitted(exp, res, out)
    return res


# ----------------------------------------------------------------------------- dejax run of an experiment


class RunSetup(NamedTuple):
    """What ``dejax run experiment.toml`` simulates: ``problem`` (a ``dejax`` Problem) from 0
    to ``t_end`` (s) under the loading of the trace ``trace`` (its name); ``settings``: dt,
    dt_min (s), rho_inf, newton_tol (1) for the run; ``output``: the output it reports."""

    problem: scenarios.Problem
    trace: str
    t_end: float
    settings: dict
    output: str


RUN_STEPS = 200
"""Default steps of a voltage-driven run without ``[solver] dt`` (as ``dejax fit``)."""


def _run_trace(exp, name):
    """The trace ``name`` of ``exp`` (default the first); ValueError naming the file otherwise."""
    try:
        tr = exp.traces[0] if name is None else exp.trace(name)
    except KeyError as e:
        raise ValueError(e.args[0]) from None
    if tr.time is None:
        raise ValueError(f"{exp.path}: trace '{tr.name}' has no time column; dejax run needs one")
    return tr


def _trace_geometry(exp, tr) -> dict:
    """``[geometry]`` with the trace's ``conditions`` that name geometry keys applied."""
    from .schema import GEOMETRY_KEYS

    return {**exp.geometry, **{k: v for k, v in tr.conditions.items() if k in GEOMETRY_KEYS[exp.scenario]}}


def _run_params(problem, exp, tr, volt) -> dict:
    """The results file's parameters: the scenario's, its own loading's replaced by the
    experiment, the trace, its peak voltage phi_max (V) and frequency freq (Hz) where known."""
    params = {k: v for k, v in problem.params.items() if k not in ("phi_max", "t_ramp", "freq", "phibar_max")}
    params.update(experiment=exp.name, experiment_file=str(exp.path), trace=tr.name)
    if volt is not None:
        params["phi_max"] = float(np.max(np.abs(np.asarray(loads.evaluate(volt, tr.time)))))
    if tr.frequency is not None:
        params["freq"] = tr.frequency
    return params


def experiment_run(exp, trace: str | None = None, dt=None, dt_min=None, rho_inf=None, damping=None,
                   gauss_order=None, newton_tol=None, volumetric: str = "mixed") -> RunSetup:
    """The run of ``exp`` (``fitting.data.Experiment``) under the loading of its trace
    ``trace`` (name; default the first) from 0 to ``[solver] t_end`` or the trace's last
    time. Settings given here win over ``[solver]`` (dt, dt_min s; rho_inf, newton_tol 1;
    damping 1/s; gauss_order), whose defaults are: dt the trace's span over 200 steps (uniaxial:
    ``uniaxial_steps``), dt_min 1e-6 s, the scenario's rho_inf, newton_tol 1e-6, no damping,
    3 Gauss points. ValueError (naming the file) for an unknown trace or scenario."""
    tr = _run_trace(exp, trace)
    s = exp.solver
    t_end = float(s.get("t_end", tr.time[-1]))
    steps = uniaxial_steps(tr["stretch"]) if exp.scenario == "uniaxial" else RUN_STEPS
    common = dict(gauss_order=int(gauss_order or s.get("gauss_order", 3)),
                  damping=float(damping if damping is not None else s.get("damping", 0.0)), volumetric=volumetric)
    volt = tr.voltage_history
    if exp.scenario not in SCENARIO_OUTPUT:
        raise ValueError(f"{exp.path}: dejax run does not support scenario {exp.scenario!r}")
    stretch = loads.PiecewiseLinear(tr.time, tr["stretch"]) if exp.scenario == "uniaxial" else None
    material = Material(**exp.material_kwargs())  # with the optional keys (Mullins softening)
    problem = experiment_problem(exp.scenario, _trace_geometry(exp, tr), material, volt, stretch, **common)
    problem = dataclasses.replace(problem, params=_run_params(problem, exp, tr, volt))
    settings = dict(dt=float(dt or s.get("dt", t_end / steps)), dt_min=float(dt_min or s.get("dt_min", 1e-6)),
                    rho_inf=float(rho_inf if rho_inf is not None else s.get("rho_inf", problem.rho_inf)),
                    newton_tol=float(newton_tol or s.get("newton_tol", 1e-6)))
    return RunSetup(problem, tr.name, t_end, settings, SCENARIO_OUTPUT[exp.scenario])
