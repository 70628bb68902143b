"""``dejax bench``: a fixed set of timing cases, printed as a table and written as JSON.

Cases (issue 6):
  B1  block, one element, Eq. (41) to 3 s
  R1  rolled tube 4 x 8 x 1, Model IV, ten cycles at 30 Hz, 50 kV
  R2  rolled tube 12 x 20 x 4, same loading (the paper's run)
  G1  forward-mode derivative of R1's mean x_P over the last cycle with respect to
      Model IV's nine parameters and h, L, r
  G1R the same derivative by one reverse pass (jax.grad); beside G1, their largest
      difference relative to the largest component
  S1  R1's loading at five mesh sizes from 4 x 8 x 1 to 12 x 20 x 4: the exponent of
      run time per step against coordinates
  F1  ``dejax fit data/examples/vhb4910_uniaxial.toml``, as a user runs it: wall time
      including compilation and peak memory of the command, cold (a fresh compilation
      cache) and warm (the same command again)
  D1  ``dejax diagnose data/examples/block_d1.toml``, every candidate effect: wall time
      and peak memory of the command (fresh compilation cache)
  N1  one Newton iteration (element system, assembly, factorization, solve) of R2,
      beside FElupe's 16^3 hex8 cube (K/mu = 1e4) in the same run when FElupe is installed

F1 and D1 run the ``dejax`` command in a child process (the fitting layer sits above
this one); they need the repository's ``data/examples`` folder.

``--max-steps N`` runs at most N steps of a case and reports the projected full-run
time (rate x steps), marked "projected" in the table; without it every case runs in
full. Times are wall-clock seconds on this machine after compilation; "compile" is the
XLA compile time of the case's program.

The machine's speed (``cpu_reference``: seconds of ``sum(range(10**8))`` in pure Python, one
core) is measured before and after the cases and printed beside the table: figures from
runs at different references are not comparable, and a reference that changed by more than
20 % during the run says the machine's load changed under it (its ratios, G1 against its
forward run or N1 against FElupe, then mix two speeds).

Accuracy (issue 10: speed may not cost accuracy): with ``--reference`` the tube cases
also run a reference on the same mesh and time span (dt = 1e-4 s, Newton converged to a
relative residual of 1e-10, tighter than full Newton at the default 1e-6: the converged
solution does not depend on the Newton variant) and report ``deviation``, the largest
|x_P - x_P,ref| over the run (reference grid, linear interpolation) divided by the peak
|x_P,ref|; the issue's bound is 0.5 %. References are cached in ``~/.cache/dejax/bench``
(or ``$DEJAX_CACHE_DIR/bench``).
"""
from __future__ import annotations

import json
import resource
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from . import integrate as it
from . import linsolve, scenarios


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _peak_device_mb() -> float:
    """The accelerator's peak memory in use by this process so far (MB); NaN on the CPU or
    where the backend keeps no statistics."""
    if jax.default_backend() == "cpu":
        return float("nan")
    stats = jax.devices()[0].memory_stats() or {}
    return stats.get("peak_bytes_in_use", float("nan")) / 2**20


REFERENCE_DT = 1e-4
REFERENCE_TOL = 1e-10
# Defaults of the tube cases: with the BDF2 flow update the deviation from the reference
# on R1 grows as dt^2: 0.199 % of the peak at dt = 5e-4 s, 0.367 % at dt = 1/1500 s (50
# steps per 30 Hz cycle, the default: 500 steps for R1), against the bound of 0.5 %
# (backward Euler needed dt = 1e-4 s for 0.25 %). Newton to a relative residual of 1e-2
# (R1, G1 and its forward run alike): at dt = 5e-4 s 2.03 iterations per step against
# 3.44 at 1e-4 and 4.53 at 1e-6; x_P within 2.2e-4 of the peak of Newton to 1e-6 (1e-4:
# 2.2e-6), deviation from the reference 0.199 % (1e-4: 0.205 %); G1's twelve derivatives
# over 100 steps within 5.5e-4 (relative, per parameter) of Newton to 1e-6.
TUBE_DT = 1.0 / 1500.0
TUBE_NEWTON_TOL = 1e-2


CPU_REFERENCE_CHANGE = 0.2
"""Relative change of the CPU reference during a run above which ``dejax bench`` warns."""


def cpu_reference(n: int = 10 ** 8) -> float:
    """Seconds of ``sum(range(n))`` in pure Python (one core): the machine-speed yardstick
    printed beside every bench run (1.1-2.7 s on the project's shared 2-core machines)."""
    tic = time.perf_counter()
    sum(range(n))
    return time.perf_counter() - tic


def speed_note(before: float, after: float) -> str | None:
    """A warning when the CPU reference changed by more than ``CPU_REFERENCE_CHANGE`` from
    ``before`` to ``after`` (s), else None."""
    change = abs(after - before) / min(before, after)
    if change <= CPU_REFERENCE_CHANGE:
        return None
    return (f"warning: the CPU reference changed by {100 * change:.0f} % during the run ({before:.2f} -> {after:.2f} s): "
            "the machine's load changed, so these timings and their ratios mix two speeds; run again")


def _wall(fn, *args, fresh: bool = False):
    """(seconds, output) of one call of ``fn(*args)`` until its result is ready; ``fresh``:
    the sparse solver's cached factorizations dropped first, so the call factorizes."""
    if fresh:
        linsolve.clear_factorizations()
    tic = time.perf_counter()
    out = jax.block_until_ready(fn(*args))
    return time.perf_counter() - tic, out


def reference_path(key: str) -> Path:
    """Where the accuracy reference ``key`` is cached: <cache root>/bench/<key>.npz."""
    from .compile_cache import cache_root

    return cache_root() / "bench" / f"{key}.npz"


def reference_trace(key, problem, t_end, output="x_P"):
    """(time, output) of the accuracy reference of a case (dt = REFERENCE_DT, Newton to
    REFERENCE_TOL), computed once and cached under ``key``."""
    path = reference_path(key)
    if path.exists():
        d = np.load(path)
        if abs(float(d["time"][-1]) - t_end) <= 1e-12 * max(1.0, t_end):
            return d["time"], d[output]
    times = it.time_grid(t_end, REFERENCE_DT)
    sol, *_ = it.run_chunked(problem.model, problem.loading, times, problem.output_fn, problem.scheme(),
                             it.NewtonOptions(tol=REFERENCE_TOL), linsolve.choose_solver(problem.model.structure),
                             chunk=min(250, times.size - 1))
    sol.check()
    t, x = np.asarray(sol.time), np.asarray(sol.outputs[output])
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, time=t, **{output: x})
    return t, x


def deviation(t, x, t_ref, x_ref) -> float:
    """max |x - x_ref| on the reference grid (x interpolated linearly) / max |x_ref|."""
    xi = np.interp(t_ref, t, x)
    return float(np.max(np.abs(xi - x_ref)) / np.max(np.abs(x_ref)))


def _run_case(name, problem, t_end, dt, max_steps, solver="auto", newton=it.NewtonOptions(), reference=None):
    times = it.time_grid(t_end, dt)
    n_full = times.size - 1
    n = n_full if max_steps is None else min(n_full, int(max_steps))
    solv = linsolve.choose_solver(problem.model.structure, solver)
    sol, _, compile_s, run_s = it.run_chunked(
        problem.model, problem.loading, times[: n + 1], problem.output_fn, problem.scheme(),
        newton, solv, chunk=min(250, n),
    )
    dev = float("nan")
    if reference is not None and sol.ok:
        key = f"{reference}-{problem.scheme().flow_update}-{float(times[n]):.6g}s"
        t_ref, x_ref = reference_trace(key, problem, float(times[n]))
        dev = deviation(np.asarray(sol.time), np.asarray(sol.outputs["x_P"]), t_ref, x_ref)
    iters = np.asarray(sol.iterations)
    facs = np.asarray(sol.factorizations)
    rate = n / run_s if run_s > 0 else float("nan")
    return dict(
        case=name,
        coordinates=int(problem.model.structure.n_dofs),
        unknowns=int(problem.model.structure.n_free),
        solver=type(solv).__name__,
        steps=n_full,
        steps_run=n,
        compile_s=compile_s,
        run_s=run_s if n == n_full else n_full / rate,
        projected=n < n_full,
        steps_per_s=rate,
        newton_mean=float(iters.mean()),
        newton_max=int(iters.max()),
        factorizations=int(facs.sum()) if n == n_full else int(round(facs.sum() * n_full / n)),
        peak_mb=_peak_rss_mb(),
        device_peak_mb=_peak_device_mb(),
        status=int(sol.status),
        dt=float(dt),
        newton_tol=float(newton.tol),
        deviation=dev,
    )


def case_B1(max_steps=None, dt=1e-3):
    return _run_case("B1 block 1 el, 3 s", scenarios.block(phi_max=12e3), 3.0, dt, max_steps)


def case_R(name, shape, max_steps=None, dt=1e-4, cycles=10, solver="auto", newton=it.NewtonOptions(),
           reference=False):
    p = scenarios.rolled("IV", 30.0, 50e3, shape=shape)
    mesh = "x".join(map(str, shape))
    return _run_case(f"{name} tube {mesh}, IV, {cycles} cycles", p, cycles / 30.0, dt, max_steps, solver, newton,
                     f"tube-{mesh}-IV-50kV-30Hz" if reference else None)


def g1_objective(n_steps, dt=1e-4, cycles=10, shape=(4, 8, 1), newton_tol=TUBE_NEWTON_TOL):
    """G1's function and point: ``(mean_last_cycle(theta, control=None), theta0)``, the mean
    x_P (m) over the last cycle (or the run, if shorter) of the first ``n_steps`` steps of
    R1's loading (Newton to ``newton_tol``, as R1), as a function of theta (12,) = (mu_inf,
    mu_1..4, eta_1..4 of Model IV, h, L, r); NaN if the run fails. theta0: Model IV and the
    paper's geometry."""
    times = it.time_grid(cycles / 30.0, dt)[: n_steps + 1]
    per = int(round(1.0 / 30.0 / dt))

    def mean_last_cycle(theta, control=None):
        mat = scenarios.rolled_material("IV", mu_inf=theta[0], mu=theta[1:5], eta=theta[5:9])
        p = scenarios.rolled(mat, 30.0, 50e3, h=theta[9], L=theta[10], r=theta[11], shape=shape)
        sol = it.simulate(p.model, p.loading, times, p.output_fn, newton=it.NewtonOptions(tol=newton_tol),
                          control=control)
        x = sol.outputs["x_P"][-min(per, n_steps):]
        return jnp.where(sol.status == 0, jnp.mean(x), jnp.nan)

    base = scenarios.rolled_material("IV")
    return mean_last_cycle, jnp.concatenate([base.mu_inf[None], base.mu, base.eta, jnp.array([2e-3, 8e-3, 2e-3])])


def case_G1(max_steps=None, dt=1e-4, cycles=10, shape=(4, 8, 1), reverse=False, newton_tol=TUBE_NEWTON_TOL):
    """jacfwd (``reverse``: jax.grad, one reverse pass) of the last-cycle mean x_P w.r.t. 12
    parameters (9 material + h, L, r), against the forward run as R1 makes it (with step
    cut-back allowed), timed before and after the derivative (``forward_s``; the ratio
    ``ratio_to_forward`` takes the faster). The derivative is taken on the user's grid
    (``control=None``): R1 takes no cut-back, so it is the derivative of the same run (equal
    to the replayed one to round-off, measured), in one pass instead of a forward run plus a
    replay of its accepted sub-steps (12 % less on 100 steps of R1). The row carries the
    derivative (``gradient``) so that G1 and G1R can be compared."""
    n_full = it.time_grid(cycles / 30.0, dt).size - 1
    n = n_full if max_steps is None else min(n_full, int(max_steps))
    mean_last_cycle, theta0 = g1_objective(n, dt, cycles, shape, newton_tol)
    f = jax.jit(lambda th: mean_last_cycle(th, it.StepControl()))
    g = jax.jit(jax.grad(mean_last_cycle) if reverse else jax.jacfwd(mean_last_cycle))
    tic = time.perf_counter()
    lowered = g.lower(theta0).compile()
    compile_s = time.perf_counter() - tic
    fc = f.lower(theta0).compile()
    # the forward run before and after the derivative, the faster one the ratio's base: a
    # machine whose load changes during the case shows as two different forward times
    fwd_before, _ = _wall(fc, theta0)
    grad_s, grad = _wall(lowered, theta0)
    grad = np.asarray(grad)
    fwd_after, _ = _wall(fc, theta0)
    fwd_s = min(fwd_before, fwd_after)
    scale = n_full / n
    name = "G1R grad (reverse)" if reverse else "G1 jacfwd"
    return dict(case=f"{name} 12 params, tube {'x'.join(map(str, shape))}", coordinates=None, unknowns=None,
                solver="DenseSolver", steps=n_full, steps_run=n, compile_s=compile_s, run_s=grad_s * scale,
                projected=n < n_full, steps_per_s=n / grad_s, newton_mean=float("nan"), newton_max=0,
                factorizations=0, peak_mb=_peak_rss_mb(), device_peak_mb=_peak_device_mb(), status=0,
                ratio_to_forward=grad_s / fwd_s, forward_s=[fwd_before * scale, fwd_after * scale],
                gradient=grad.tolist())


S1_SHAPES = ((4, 8, 1), (6, 10, 2), (8, 12, 2), (10, 16, 3), (12, 20, 4))


EXAMPLES = Path(__file__).resolve().parents[1] / "data" / "examples"
_CHILD = """
import resource, sys
from dejax.cli import main
try:
    rc = main(sys.argv[1:])
except SystemExit as e:
    rc = e.code
try:  # this process's own high-water mark (ru_maxrss would include the parent's memory at fork on Linux)
    peak = next(int(line.split()[1]) for line in open("/proc/self/status") if line.startswith("VmHWM:"))
except (OSError, StopIteration):
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(f"__peak_rss_kb {peak}", file=sys.stderr)
sys.exit(rc)
"""


def run_command(argv, cache_dir) -> dict:
    """Run ``dejax argv`` in a child process with its compilation cache in ``cache_dir``:
    wall seconds (including start-up and compilation), peak resident memory (MB), exit code."""
    import os
    import subprocess

    env = dict(os.environ, DEJAX_CACHE_DIR=str(cache_dir))
    tic = time.perf_counter()
    p = subprocess.run([sys.executable, "-c", _CHILD, *argv], env=env, capture_output=True, text=True)
    wall = time.perf_counter() - tic
    peak = [line.split()[1] for line in p.stderr.splitlines() if line.startswith("__peak_rss_kb ")]
    if p.returncode != 0:
        raise RuntimeError(f"dejax {' '.join(argv)} failed (exit {p.returncode}):\n{p.stderr[-2000:]}")
    return dict(wall_s=wall, peak_mb=float(peak[-1]) / 1024.0 if peak else float("nan"), stdout=p.stdout)


def _example(name) -> Path:
    path = EXAMPLES / name
    if not path.exists():
        raise FileNotFoundError(f"bench case needs {path} (the repository's data/examples folder)")
    return path


def _command_row(name, runs, **extra) -> dict:
    """A table row for a case that times whole commands (``runs``: label -> run_command result)."""
    first = next(iter(runs.values()))
    row = dict(case=name, coordinates=None, unknowns=None, solver="-", steps=0, steps_run=0, compile_s=float("nan"),
               run_s=first["wall_s"], projected=False, steps_per_s=float("nan"), newton_mean=float("nan"),
               newton_max=0, factorizations=0, peak_mb=first["peak_mb"], status=0, dt=None, deviation=float("nan"))
    row.update({f"{label}_wall_s": r["wall_s"] for label, r in runs.items()})
    row.update({f"{label}_peak_mb": r["peak_mb"] for label, r in runs.items()})
    row.update(extra)
    return row


def case_F1() -> list[dict]:
    """The example fit, cold and warm: wall time and peak memory of each command."""
    import tempfile

    toml = _example("vhb4910_uniaxial.toml")
    with tempfile.TemporaryDirectory() as tmp:
        runs, fits = {}, {}
        for label in ("cold", "warm"):
            out = Path(tmp) / f"fit_{label}"
            runs[label] = run_command(["fit", str(toml), "--out", str(out), "--no-plots", "--quiet"],
                                      Path(tmp) / "cache")
            fits[label] = json.loads((out / "fit.json").read_text())
        rows = []
        for label, r in runs.items():
            fit = fits[label]
            rows.append(_command_row(f"F1 fit example ({label} cache)", {label: r}, evaluations=fit["n_evals"],
                                     rms=fit["rms"], params={k: fit["params"][k] for k in fit["free"]}))
    return rows


def case_D1() -> dict:
    """The D1 diagnosis, every candidate effect: wall time, peak memory, verdict."""
    import tempfile

    toml = _example("block_d1.toml")
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "diag"
        r = run_command(["diagnose", str(toml), "--out", str(out), "--quiet"], Path(tmp) / "cache")
        rep = json.loads((out / "report.json").read_text())
    return _command_row("D1 diagnose block, all effects", {"cold": r}, verdict=rep.get("verdict"),
                        best=rep.get("best"))


FELUPE_CUBE = """
import sys, time
import felupe as fem
try:
    from pypardiso import spsolve
    kw, solver = {"solver": spsolve}, "pypardiso"
except ImportError:
    kw, solver = {}, "scipy"
n = 16
mesh = fem.Cube(n=n + 1)
region = fem.RegionHexahedron(mesh)
field = fem.FieldContainer([fem.Field(region, dim=3)])
solid = fem.SolidBody(fem.NeoHooke(mu=1.0, bulk=1e4), field)
boundaries, _ = fem.dof.uniaxial(field, clamped=False, move=0.5, return_loadcase=True)
its = []
step = fem.Step(items=[solid], ramp={boundaries["move"]: fem.math.linsteps([0, 1], num=3)}, boundaries=boundaries)
job = fem.Job(steps=[step], callback=lambda stepnumber, substepnumber, substep, **k: its.append(substep.iterations))
tic = time.perf_counter()
job.evaluate(verbose=0, tol=1e-8, **kw)
wall = time.perf_counter() - tic
print(sum(f.values.size for f in field.fields), sum(its), wall, solver)
"""


def _felupe_iteration() -> dict | None:
    """FElupe's hex8 Neo-Hooke cube 16^3 (14,739 unknowns), K/mu = 1e4, uniaxial stretch
    1.5 in 3 steps (issue 10's peer figure): seconds per full Newton iteration (assembly
    and solve), in a child process; None when FElupe is not installed."""
    import subprocess

    p = subprocess.run([sys.executable, "-c", FELUPE_CUBE], capture_output=True, text=True)
    if p.returncode != 0:
        if "No module named 'felupe'" in p.stderr:
            return None
        raise RuntimeError(f"the FElupe peer run failed:\n{p.stderr[-2000:]}")
    dofs, its, wall, solver = p.stdout.split()[-4:]
    return dict(unknowns=int(dofs), iterations=int(its), seconds_per_iteration=float(wall) / int(its),
                solver=solver)


def n1_step(solver="auto", dt=TUBE_DT):
    """N1's program: R2's first step (tube 12 x 20 x 4, Model IV) limited to one full-Newton
    iteration. Returns (problem, solver, step(state, fac) jitted, initial state, empty
    factorization)."""
    p = scenarios.rolled("IV", 30.0, 50e3, shape=(12, 20, 4))
    m = p.model
    solv = linsolve.choose_solver(m.structure, solver)
    step = it.make_step(p.scheme(), it.NewtonOptions(reuse=False, max_iter=1, line_search=False), solv)
    s0 = it.initial_state(m, p.loading, 0.0)
    fac0 = it.initial_carry(m, s0, solv).fac
    return p, solv, jax.jit(lambda s, fac: step(m, p.loading, s, s.t + dt, fac, False)), s0, fac0


N1_ROUNDS = 3
"""Rounds of N1: dejax's iteration and FElupe's job are timed in turn, each round, so that a
change of the machine's speed during the case reaches both (``case_N1``)."""


def case_N1(dt=TUBE_DT, solver="auto", repeat=5, rounds=N1_ROUNDS) -> dict:
    """One Newton iteration of R2 (tube 12 x 20 x 4, Model IV): element system (forces and
    consistent tangent), condensation, sparse assembly, factorization, solve and the line
    search's residual, timed as a step limited to one iteration (after compilation, best of
    ``repeat``); beside it FElupe's cube when FElupe is installed, timed in the same run.

    The two are timed in turn, ``rounds`` times (dejax's best of ``repeat`` calls and its
    amortized figure, then FElupe's job), and each figure is its best round: on a machine
    whose speed drifts, timing one after the other gave ratios of 1.24 and 1.91 an hour
    apart (FElupe 0.78 and 0.53 s). ``round_ratios`` are the rounds' own ratios.

    The sparse solver keeps factorizations by the matrix's values, so repeating the same
    iteration would reuse the first one's: the cache is cleared before every timed call.
    ``without_factorization_s`` times the same call with the factorization cached (what
    an iteration on a reused factorization costs); ``amortized`` times a full-Newton step of
    several iterations per iteration, as FElupe's figure is made (``_amortized_iteration``)."""
    p, solv, one, s0, fac0 = n1_step(solver, dt)
    m = p.model
    first, _ = _wall(one, s0, fac0, fresh=True)
    amortized_step = _amortized_iteration(p, solv, s0, fac0, dt)
    ours, amortized, peers = [], [], []
    for _ in range(rounds):
        ours.append(min(_wall(one, s0, fac0, fresh=True)[0] for _ in range(repeat)))
        amortized.append(amortized_step(max(1, repeat // 2)))
        peers.append(_felupe_iteration())
        if peers[-1] is None:
            break
    per_it = min(ours)
    amortized = min(amortized, key=lambda r: r["seconds_per_iteration"])
    cached = min(_wall(one, s0, fac0)[0] for _ in range(repeat))
    peer = min(peers, key=lambda r: r["seconds_per_iteration"]) if peers[-1] else None
    return dict(case="N1 one Newton iteration, R2", coordinates=int(m.structure.n_dofs),
                unknowns=int(m.structure.n_free), solver=type(solv).__name__ + f"({getattr(solv, 'backend', '')})",
                steps=0, steps_run=0, compile_s=first - per_it, run_s=per_it, projected=False,
                steps_per_s=float("nan"), newton_mean=float("nan"), newton_max=0, factorizations=1,
                peak_mb=_peak_rss_mb(), status=0, dt=dt, deviation=float("nan"), felupe=peer,
                without_factorization_s=cached, amortized=amortized, rounds_s=ours,
                round_ratios=[a / b["seconds_per_iteration"] for a, b in zip(ours, peers)] if peer else None,
                ratio_to_felupe=per_it / peer["seconds_per_iteration"] if peer else None,
                amortized_ratio_to_felupe=(amortized["seconds_per_iteration"] / peer["seconds_per_iteration"]
                                           if peer else None))


N1_ITERATIONS = 5
"""Iterations of N1's amortized figure (FElupe's cube takes 5 per load step: 15 over 3)."""


def _amortized_iteration(p, solv, s0, fac0, dt):
    """N1 as FElupe's figure is made, its job's wall time over its iterations: R2's first step
    by full Newton (a factorization every iteration), ``N1_ITERATIONS`` iterations (a
    correction criterion of 1e-300 lets every one run: past convergence an iteration costs the
    same), divided by the iterations, so that the step's own work (the predictor, the
    state's checks) is shared by them as FElupe's load steps share theirs. Returns
    ``timed(repeat) -> dict`` (compiled and checked here; best of ``repeat`` calls with
    fresh factorizations)."""
    step = it.make_step(p.scheme(), it.NewtonOptions(reuse=False, max_iter=N1_ITERATIONS, tol=1e-300,
                                                     criterion="correction", line_search=False), solv)
    run = jax.jit(lambda s, fac: step(p.model, p.loading, s, s.t + dt, fac, False))  # the whole step, as N1's
    n0 = linsolve.host_factorizations()
    _, out = _wall(run, s0, fac0, fresh=True)  # compiles
    # the iteration matrix factorized at every iteration (on the host for the sparse solvers:
    # a factorization cached by its values would make later iterations cheaper)
    iterations, factorizations = int(out[1]), int(out[2])
    host = linsolve.host_factorizations() - n0

    def timed(repeat):
        best = min(_wall(run, s0, fac0, fresh=True)[0] for _ in range(repeat))
        return dict(iterations=iterations, factorizations=factorizations, host_factorizations=host, step_s=best,
                    seconds_per_iteration=best / max(iterations, 1))

    return timed


def case_S1(max_steps=50, dt=1e-4):
    rows = [case_R("S1", shape, max_steps=max_steps, dt=dt) for shape in S1_SHAPES]
    n = np.array([r["coordinates"] for r in rows], float)
    per_step = np.array([1.0 / r["steps_per_s"] for r in rows])
    slope = float(np.polyfit(np.log(n), np.log(per_step), 1)[0])
    return rows, slope


def format_table(rows) -> str:
    head = (f"{'case':<34} {'coords':>7} {'dt s':>8} {'steps':>6} {'compile s':>9} {'run s':>10} {'steps/s':>8} "
            f"{'Newton':>11} {'fact.':>6} {'peak MB':>8} {'deviation':>9}")
    lines = [head, "-" * len(head)]
    for r in rows:
        run = f"{r['run_s']:.2f}" + ("*" if r["projected"] else "")
        newton = f"{r['newton_mean']:.2f}/{r['newton_max']}" if np.isfinite(r["newton_mean"]) else "-"
        coords = str(r["coordinates"]) if r["coordinates"] else "-"
        dev = r.get("deviation", float("nan"))
        dev = f"{100 * dev:.3f} %" if np.isfinite(dev) else "-"
        dt = f"{r['dt']:.3g}" if r.get("dt") else "-"
        comp = f"{r['compile_s']:.1f}" if np.isfinite(r["compile_s"]) else "-"
        rate = f"{r['steps_per_s']:.1f}" if np.isfinite(r["steps_per_s"]) else "-"
        lines.append(f"{r['case']:<34} {coords:>7} {dt:>8} {r['steps']:>6} {comp:>9} {run:>10} "
                     f"{rate:>8} {newton:>11} {r['factorizations']:>6} {r['peak_mb']:>8.0f} {dev:>9}")
    lines.append("* projected from the steps run (rate x steps); Newton = iterations per step mean/max; deviation "
                 "(--reference) = max |x_P - x_P,ref| / peak |x_P,ref| against dt = 1e-4 s, Newton to 1e-10, over the "
                 "steps run; F1, D1: run s = wall time of the whole command (start-up and compilation included)")
    on_device = [r for r in rows if np.isfinite(r.get("device_peak_mb", float("nan")))]
    if on_device:
        lines.append(f"on {jax.devices()[0].device_kind}: peak MB = host memory; the accelerator's peak memory so far: "
                     + ", ".join(f"{r['case'].split()[0]} {r['device_peak_mb']:.0f} MB" for r in on_device))
    return "\n".join(lines)


def main(cases=("B1", "R1", "R2", "G1", "S1"), max_steps=None, json_path="bench.json", dt=TUBE_DT, select=(),
         torsional_mesh=(48, 8, 2), newton_tol=TUBE_NEWTON_TOL, reference=False, solver="auto") -> int:
    newton = it.NewtonOptions(tol=newton_tol)
    rows, extra = [], {}
    cpu_before = cpu_reference()
    for c in cases:
        sys.stderr.write(f"running {c} ...\n")
        if c == "robust":
            from . import robust

            extra["robust"] = robust.run(select, lambda name: sys.stderr.write(f"  {name}\n"), torsional_mesh)
            print(robust.format_table(extra["robust"]))
        elif c == "B1":
            rows.append(case_B1(max_steps))
        elif c == "R1":
            rows.append(case_R("R1", (4, 8, 1), max_steps, dt, solver=solver, newton=newton, reference=reference))
        elif c == "R2":
            rows.append(case_R("R2", (12, 20, 4), max_steps, dt, solver=solver, newton=newton, reference=reference))
        elif c in ("G1", "G1R"):
            rows.append(case_G1(max_steps, dt, reverse=c == "G1R", newton_tol=newton_tol))
            extra[f"{c}_over_forward"] = rows[-1]["ratio_to_forward"]
            grads = {r["case"].split()[0]: np.asarray(r["gradient"]) for r in rows if "gradient" in r}
            if len(grads) == 2:  # reverse against forward mode, relative to the largest component
                extra["G1R_vs_G1_max_rel"] = float(np.max(np.abs(grads["G1R"] - grads["G1"]))
                                                   / np.max(np.abs(grads["G1"])))
        elif c == "S1":
            srows, slope = case_S1(max_steps or 50, dt)
            rows += srows
            extra["S1_exponent"] = slope
        elif c == "N1":
            rows.append(case_N1(solver=solver))
            peer = rows[-1]["felupe"]
            extra["N1_seconds_per_iteration"] = rows[-1]["run_s"]
            extra["N1_seconds_without_factorization"] = rows[-1]["without_factorization_s"]
            extra["N1_amortized_seconds_per_iteration"] = rows[-1]["amortized"]["seconds_per_iteration"]
            if peer:
                extra["N1_felupe_seconds_per_iteration"] = peer["seconds_per_iteration"]
                extra["N1_over_felupe"] = rows[-1]["ratio_to_felupe"]
                extra["N1_over_felupe_by_round"] = rows[-1]["round_ratios"]
                extra["N1_amortized_over_felupe"] = rows[-1]["amortized_ratio_to_felupe"]
            else:
                sys.stderr.write("  N1: FElupe is not installed (pip install felupe pypardiso): no peer figure\n")
        elif c == "F1":
            rows += case_F1()
        elif c == "D1":
            rows.append(case_D1())
            sys.stderr.write(f"  D1 verdict: {rows[-1]['verdict']}\n")
        else:
            raise ValueError(f"unknown bench case {c!r}; choose from B1 R1 R2 G1 G1R S1 N1 F1 D1 robust")
    cpu_after = cpu_reference()
    if rows:
        print(format_table(rows))
    for k, v in extra.items():
        if k != "robust":
            print(f"{k}: {' '.join(f'{x:.3g}' for x in v) if isinstance(v, list) else f'{v:.3g}'}")
    print(f"CPU reference (s of sum(range(10**8))): {cpu_before:.2f} before, {cpu_after:.2f} after")
    note = speed_note(cpu_before, cpu_after)
    if note:
        print(note)
    if json_path:
        with open(json_path, "w") as f:
            json.dump({"rows": rows, **extra, "cpu_reference_s": [cpu_before, cpu_after],
                       "device": str(jax.devices()[0])}, f, indent=2, default=float)
    return 0


def register(sub):
    p = sub.add_parser("bench", help="timing benchmark (cases B1 R1 R2 G1 S1 F1 D1) and the robustness matrix, "
                                     "table + JSON")
    p.add_argument("--cases", default="B1,R1,R2,G1,S1",
                   help="comma-separated subset of B1,R1,R2,G1,G1R,S1,N1,F1,D1, or robust (the solver robustness "
                        "matrix); G1R is G1 by one reverse pass (jax.grad), compared with G1 when both run; "
                        "F1 and D1 time whole dejax fit / diagnose commands, N1 one Newton iteration of R2 beside "
                        "FElupe's cube (when FElupe is installed)")
    p.add_argument("--select", default="", help="robust: keep the cases whose name contains one of these "
                                                "comma-separated substrings (e.g. 'uniaxial,block')")
    p.add_argument("--torsional-mesh", type=_mesh, default=(48, 8, 2), help="robust: torsional strip mesh")
    p.add_argument("--max-steps", type=int, default=None, help="run at most N steps per case and project")
    p.add_argument("--dt", type=float, default=TUBE_DT, help="time step of the tube cases (s)")
    p.add_argument("--newton-tol", type=float, default=TUBE_NEWTON_TOL,
                   help="Newton tolerance (relative residual) of the tube cases R1, R2 and G1")
    p.add_argument("--reference", action="store_true",
                   help="R1, R2: also report the deviation of x_P from a reference run (dt = 1e-4 s, Newton to 1e-10; "
                        "computed once, cached in ~/.cache/dejax/bench)")
    p.add_argument("--solver", default="auto", choices=("auto", "dense", "sparse", "pardiso"),
                   help="linear solver of the tube cases R1, R2 (pardiso: pip install -e \".[fast]\")")
    p.add_argument("--json", default="bench.json", help="where to write the JSON table")
    p.set_defaults(func=lambda a: main(tuple(c.strip() for c in a.cases.split(",") if c.strip()), a.max_steps,
                                       a.json, a.dt, tuple(s for s in a.select.split(",") if s), a.torsional_mesh,
                                       a.newton_tol, a.reference, a.solver))


def _mesh(text):
    from .argtypes import mesh_shape

    return mesh_shape(text)
