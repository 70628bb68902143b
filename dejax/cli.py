"""Command line: ``dejax run``, ``dejax verify``, ``dejax plot``, ``dejax sweep`` here, and the
verbs registered by ``dejax.bench`` (bench) and ``fitting.cli`` (fit, sensitivity, diagnose):
``verb_registrars``; ``run experiment`` is registered by ``fitting.cli`` (``run_registrars``).

Exit codes: 0 success, 1 simulation failure (reported with its time; ``run`` still writes
the trajectory up to the last converged step, status = "failed"), 2 bad arguments or an
unwritable output path (every output path of a verb, ``OUTPUT_PATHS``, is checked before
any computation; nothing is written).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from . import compile_cache
from .argtypes import float_list, mesh_shape, nonneg, positive, positive_int, rho_inf



class HelpFormatter(argparse.HelpFormatter):
    """Help that shows each option's default, unless the text already names it or there is none."""

    def _get_help_string(self, action):
        text = action.help or ""
        default = action.default
        if (default is None or default is False or default is argparse.SUPPRESS or default == ""
                or "default" in text.lower()
                or not action.option_strings or isinstance(action, argparse._HelpAction)):
            return text
        shown = "x".join(str(v) for v in default) if isinstance(default, tuple) else default
        return f"{text} (default: {shown})" if text else f"(default: {shown})"


class _Parser(argparse.ArgumentParser):
    def __init__(self, *args, **kwargs):
        kwargs.setdefault("formatter_class", HelpFormatter)
        super().__init__(*args, **kwargs)

    def error(self, message):  # exit code 2 with a clear message (argparse default is also 2)
        self.print_usage(sys.stderr)
        self.exit(2, f"{self.prog}: error: {message}\n")


def common_solver_args(p, dt: float):
    p.add_argument("--dt", type=positive("--dt"), default=dt,
                   help="time step (s); the run takes ceil(t_end / dt) equal steps, so the step used "
                        "(stored as dt) may be slightly smaller")
    p.add_argument("--rho-inf", type=rho_inf, default=0.8, help="generalized-alpha spectral radius (default 0.8)")
    p.add_argument("--damping", type=nonneg("--damping"), default=0.0, help="structural damping c_d (1/s), C = c_d M")
    p.add_argument("--gauss", type=int, default=None, choices=(2, 3, 4, 5),
                   help="Gauss points per direction (default: 3)")
    p.add_argument("--newton-tol", type=positive("--newton-tol"), default=1e-6,
                   help="Newton tolerance: relative residual (default 1e-6), or the largest correction "
                        "(strain-like) with --newton-criterion correction")
    p.add_argument("--newton-criterion", default="residual", choices=("residual", "correction"),
                   help="Newton convergence test (default residual)")
    p.add_argument("--no-line-search", action="store_true", help="plain Newton steps (admissibility safeguard only)")
    p.add_argument("--dt-min", type=positive("--dt-min"), default=1e-6,
                   help="smallest step of the cut-back (s, default 1e-6); a failure at dt-min is final")
    p.add_argument("--step-tol", type=positive("--step-tol"), default=None,
                   help="error control: the largest local error estimate of a step (displacement error over "
                        "element size, strain-like; e.g. 1e-4); --dt is then the output grid and the longest "
                        "step, sub-steps (dt over a power of two) follow the estimate (generalized-alpha only)")
    p.add_argument("--quasi-static", action="store_true", help="no inertia (equilibrium at every step)")
    p.add_argument("--flow-update", default="bdf2", choices=("bdf2", "backward-euler"),
                   help="time discretization of the viscous flow rule: bdf2 (second order, default) or "
                        "backward-euler (the paper's Eq. 39, first order)")
    p.add_argument("--volumetric", default="mixed", choices=("mixed", "displacement"),
                   help="volumetric treatment: element pressure (mixed, default) or the paper's pointwise penalty")
    p.add_argument("--out", required=True, help="results file (HDF5), written atomically; a failed run writes "
                                                "the trajectory up to its last converged step (status = failed)")
    p.add_argument("--vtu", default=None, metavar="DIR",
                   help="also write a ParaView time series into DIR: <out stem>.pvd + one VTU per frame "
                        "(displacement m, potential V, nominal_field V/m, strain_norm)")
    p.add_argument("--vtu-frames", type=positive_int("--vtu-frames"), default=50,
                   help="number of VTU frames (evenly spaced in time)")
    p.add_argument("--quiet", action="store_true", help="no progress output")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="dejax", description="Differentiable hyper-viscoelastic DEA simulator")
    parser.add_argument("--no-compile-cache", action="store_true",
                        help="do not use JAX's persistent compilation cache (default: on, in ~/.cache/dejax/jax "
                             "or $DEJAX_CACHE_DIR; also off with DEJAX_COMPILE_CACHE=0)")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    run = sub.add_parser("run", help="run a scenario and write an HDF5 results file")
    rsub = run.add_subparsers(dest="scenario", required=True, parser_class=_Parser)
    b = rsub.add_parser("block", help="DE block under the Eq. (41) ramp-and-hold voltage (paper Sec. 4)")
    b.add_argument("--phi-max", type=nonneg("--phi-max"), default=12e3, help="peak voltage phi_m (V)")
    b.add_argument("--t-end", type=positive("--t-end"), default=3.0, help="end time (s)")
    b.add_argument("--t-ramp", type=positive("--t-ramp"), default=1.0, help="ramp duration (s)")
    b.add_argument("--L", type=positive("--L"), default=1e-3, help="cube side (m)")
    b.add_argument("--mesh", type=mesh_shape, default=(1, 1, 1), help="elements, e.g. 2x2x2")
    b.add_argument("--hyperelastic", action="store_true", help="drop the viscous unit")
    b.add_argument("--mu-inf", type=positive("--mu-inf"), default=None,
                   help="override mu_inf (Pa; default: the paper's 67e3)")
    b.add_argument("--eta", type=positive("--eta"), default=None,
                   help="override eta_1 (Pa s; default: the paper's 3000)")
    common_solver_args(b, dt=1e-3)
    b.set_defaults(run_scenario=_run_block)

    r = rsub.add_parser("rolled", help="rolled (tubular) DEA under the Eq. (42) sine voltage (paper Sec. 6)")
    r.add_argument("--model", default="IV", choices=("I", "II", "III", "IV", "hyperelastic"), help="Table 2 material")
    r.add_argument("--freq", type=positive("--freq"), default=30.0, help="voltage frequency f (Hz)")
    r.add_argument("--phi-max", type=nonneg("--phi-max"), default=50e3, help="peak voltage phi_m (V)")
    r.add_argument("--cycles", type=positive("--cycles"), default=None,
                   help="number of voltage cycles (default 10; with --voltage: the file's last time)")
    r.add_argument("--voltage", default=None, metavar="CSV",
                   help="voltage history replacing the sine: CSV with a header and rows 'time (s), voltage (V)', "
                        "linear between rows; --freq then only sets the cycle length of the cycle features")
    r.add_argument("--mesh", type=mesh_shape, default=(12, 20, 4), help="n_l x n_s x n_r elements")
    r.add_argument("--h", type=positive("--h"), default=2e-3, help="wall thickness (m)")
    r.add_argument("--r", type=positive("--r"), default=2e-3, help="inner radius (m)")
    r.add_argument("--L", type=positive("--L"), default=8e-3, help="length (m)")
    r.add_argument("--point", default="P", choices=("P", "P_outer"), help="output point on the top face")
    r.add_argument("--mu-inf", type=positive("--mu-inf"), default=None,
                   help="override mu_inf (Pa; default: the --model's)")
    r.add_argument("--mu", default=None, help="override the viscous mu_s, comma-separated (Pa; default: the --model's)")
    r.add_argument("--eta", default=None,
                   help="override the viscous eta_s, comma-separated (Pa s; default: the --model's)")
    r.add_argument("--solver", default="auto", choices=("auto", "dense", "sparse", "pardiso"), help="linear solver")
    common_solver_args(r, dt=1e-4)
    r.set_defaults(run_scenario=_run_rolled)

    t = rsub.add_parser("torsional", help="twisted torsional strip, phibar ramp (paper Sec. 5)")
    t.add_argument("--phibar-max", type=nonneg("--phibar-max"), default=0.5, help="final dimensionless voltage")
    t.add_argument("--t-ramp", type=positive("--t-ramp"), default=1.0, help="ramp duration (s)")
    t.add_argument("--t-end", type=positive("--t-end"), default=None, help="end time (s), default t_ramp")
    t.add_argument("--viscous", action="store_true", help="add the paper's viscous unit")
    t.add_argument("--mesh", type=mesh_shape, default=(48, 8, 2), help="length x width x thickness elements")
    t.add_argument("--solver", default="auto", choices=("auto", "dense", "sparse", "pardiso"), help="linear solver")
    common_solver_args(t, dt=1e-2)
    t.set_defaults(run_scenario=_run_torsional)

    for register in run_registrars():
        register(rsub)

    v = sub.add_parser("verify", help="run the verification cases against independent references")
    v.add_argument("--quick", action="store_true", help="fewer, shorter cases")
    v.add_argument("--json", default=None, help="also write the table as JSON to this path")
    v.add_argument("--quiet", action="store_true", help="no progress output")

    for register in verb_registrars():
        register(sub)
    return parser


def run_registrars() -> tuple:
    """The ``register(run_subparsers)`` of the scenarios of ``dejax run`` defined above this
    package: ``run experiment FILE.toml`` (``fitting.cli``)."""
    from fitting import cli as fitting_cli

    return (fitting_cli.register_run_experiment,)


def verb_registrars() -> tuple:
    """The ``register(subparsers)`` of every verb beyond run and verify, in the order of the
    help: bench (``dejax.bench``), fit, sensitivity, diagnose (``fitting.cli``), plot, sweep."""
    from fitting import cli as fitting_cli

    from . import bench

    return (bench.register, fitting_cli.register, register_plot, register_sweep)


def _floats(text, name):
    try:
        return [float(x) for x in text.split(",")]
    except ValueError:
        raise ValueError(f"{name} must be comma-separated numbers, got {text!r}") from None


def _frame_times(times, frames: int) -> tuple:
    """Grid times (s) of about ``frames`` evenly spaced VTU frames, the start and end included."""
    import numpy as np

    n = len(times) - 1
    idx = np.unique(np.round(np.linspace(0, n, min(int(frames), n) + 1)).astype(int))
    return tuple(float(times[i]) for i in idx)


def _announce_long_run(problem, n_steps: int) -> None:
    """Say the projected wall time before a run expected to exceed progress.LONG_RUN_SECONDS."""
    from . import progress as pg

    n_el = int(problem.model.dV.shape[0])
    est = pg.projected_seconds(n_el, n_steps)
    if est > pg.LONG_RUN_SECONDS:
        print(f"dejax: this run is projected to take about {pg.format_long_duration(est)} "
              f"({n_el} elements x {n_steps} steps at roughly {1e3 * pg.SECONDS_PER_ELEMENT_STEP:g} ms per "
              f"element-step); shorten it with --t-end / --cycles, a larger --dt or a coarser --mesh",
              file=sys.stderr)


def _write_vtu_series(problem, states: dict, folder, stem: str) -> list:
    """One VTU per State (displacement, potential, nominal field, strain norm) and ``stem.pvd``."""
    from pathlib import Path

    import numpy as np

    from . import outputs

    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    mesh = problem.extras["mesh"]
    entries, seen = [], set()
    for k, st in sorted(states.items()):
        t = float(st.t)
        if t in seen:  # two frames taken at the same chunk end
            continue
        seen.add(t)
        phi = np.asarray(problem.loading.phi(t)) if problem.loading.voltages else None
        name = f"{stem}_{int(k):06d}.vtu"
        outputs.write_vtu(out / name, mesh, st.q, phi, problem.model)
        entries.append((t, name))
    outputs.write_pvd(out / f"{stem}.pvd", entries)
    return [out / f for _, f in entries]


def _h5_snapshot(problem, state, q0) -> dict:
    """A results-file snapshot: t (s), q, q0 and the electrode voltages phi (V) at t, so that
    ``outputs.vtu_from_h5`` can add the potential and the nominal field."""
    import numpy as np

    snap = {"t": float(state.t), "q": np.asarray(state.q), "q0": q0}
    if problem.loading.voltages:
        snap["phi"] = np.atleast_1d(np.asarray(problem.loading.phi(state.t), dtype=float))
    return snap


def run_problem(problem, t_end, dt, args, summary_outputs, solver="auto"):
    import numpy as np

    from . import integrate as it
    from . import linsolve, stability
    from . import progress as pg
    from .results import write_h5

    times = it.time_grid(t_end, dt)
    n = len(times) - 1
    dt_used = float(times[1] - times[0])
    _announce_long_run(problem, n)
    n_el = int(problem.model.dV.shape[0])
    vtu = getattr(args, "vtu", None)
    chunk = pg.chunk_steps(n, pg.SECONDS_PER_ELEMENT_STEP * n_el, frames=args.vtu_frames if vtu else None)
    bar = pg.ProgressBar(n, float(times[-1]), quiet=args.quiet)
    import jax

    bar.compiling(f"the {problem.name} stepper ({n_el} element{'s' if n_el != 1 else ''}, {chunk}-step chunks)",
                  cached=bool(jax.config.jax_compilation_cache_dir))
    snapshot_times = _frame_times(times, args.vtu_frames) if vtu else (float(times[-1]),)
    scheme = problem.scheme(args.rho_inf, True if args.quasi_static else None, args.flow_update)
    step_tol = getattr(args, "step_tol", None)
    if step_tol is not None and not scheme.inertial:
        raise ValueError("--step-tol (error control) needs inertia: its error estimate comes from the "
                         "generalized-alpha accelerations, and this run is quasi-static")
    sol, snaps, compile_s, run_s = it.run_chunked(
        problem.model,
        problem.loading,
        times,
        problem.output_fn,
        scheme,
        it.NewtonOptions(tol=args.newton_tol, criterion=args.newton_criterion, line_search=not args.no_line_search),
        linsolve.choose_solver(problem.model.structure, solver),
        chunk=chunk,
        progress=bar,
        snapshot_times=snapshot_times,
        control=it.StepControl(dt_min=args.dt_min, tol=step_tol),
    )
    sol = stability.classify_failure(problem.model, problem.loading, sol, args.dt_min)
    rows = len(sol.time) if sol.ok else int(sol.fail_step) + 1  # the last converged grid step
    bar.close(failed=not sol.ok, k=rows - 1, t=float(sol.time[rows - 1]))
    iters = np.asarray(sol.iterations)[: rows - 1]
    attrs = dict(
        status="ok" if sol.ok else "failed",
        dt=dt_used,
        dt_requested=dt,
        t_end=t_end,
        steps=rows - 1,
        steps_planned=n,
        rho_inf=args.rho_inf,
        newton_tol=args.newton_tol,
        newton_criterion=args.newton_criterion,
        quasi_static=bool(args.quasi_static or problem.quasi_static),
        flow_update=args.flow_update,
        dt_min=args.dt_min,
        **({} if step_tol is None else {"step_tol": float(step_tol)}),
        cutbacks=sol.n_cutbacks,
        dt_smallest=float(sol.dt_smallest),
        compile_s=compile_s,
        run_s=run_s,
        newton_mean=float(iters.mean()) if iters.size else float("nan"),
        newton_max=int(iters.max()) if iters.size else 0,
        command_line=getattr(args, "command_line", ""),
    )
    states = {k: st for k, st in snaps.items() if k <= rows - 1}  # none past the failure
    err = None
    if not sol.ok:
        note = (f"the failing step was cut back {int(np.asarray(sol.cutbacks)[int(sol.fail_step)])} times, down to "
                f"dt = {args.dt_min:g} s" if sol.n_cutbacks and int(sol.fail_step) >= 0 else "")
        err = sol.error(note)
        attrs.update(fail_status=err.status.name.lower(), fail_time=err.time, fail_step=err.step,
                     fail_reason=str(err), t_last_converged=float(sol.time[rows - 1]))
        if sol.last_converged is not None:  # the converged sub-step nearest the failure
            states[rows - 1] = sol.last_converged
    q0 = np.asarray(problem.model.q0)
    h5_states = states if not vtu else {k: states[k] for k in sorted(states)[-1:]}
    snapshots = {k: _h5_snapshot(problem, st, q0) for k, st in h5_states.items()}
    write_h5(args.out, np.asarray(sol.time)[:rows], {k: np.asarray(v)[:rows] for k, v in sol.outputs.items()},
             problem.params, iters, snapshots=snapshots, attrs=attrs)
    if vtu:
        frames = _write_vtu_series(problem, states, vtu, Path(args.out).stem)
        vtu_note = f", {len(frames)} VTU frames + {Path(args.out).stem}.pvd in {vtu}"
    else:
        vtu_note = ""
    if err is not None:
        print(f"dejax: error: {err}; the trajectory up to the last converged step (t = "
              f"{float(sol.time[rows - 1]):.6g} s, step {rows - 1} of {n}) is written to {args.out} "
              f"(status = failed){vtu_note}", file=sys.stderr)
        return 1
    finals = ", ".join(f"{k} = {float(np.asarray(sol.outputs[k])[-1]):.6g}" for k in summary_outputs)
    dt_note = f", dt = {dt_used:.6g} s (requested {dt:g} s: {n} equal steps)" if abs(dt_used - dt) > 1e-12 * dt else ""
    print(
        f"{problem.name}: {n} steps to t = {t_end:g} s{dt_note}, compile {compile_s:.1f} s, run {run_s:.2f} s "
        f"({n / max(run_s, 1e-9):.0f} steps/s), Newton {iters.mean():.2f} mean / {iters.max()} max, "
        f"{sol.n_cutbacks} cut-backs (smallest dt {float(sol.dt_smallest):.3g} s); "
        f"final {finals} -> {args.out}{vtu_note}"
    )
    return 0


def _run_block(args):
    from . import scenarios

    over = {}
    if args.mu_inf is not None:
        over["mu_inf"] = args.mu_inf
    if args.eta is not None:
        over["eta"] = [args.eta]
    if args.hyperelastic:
        over.update(mu=[], K=[], Jm=[], eta=[])
    material = scenarios.block_material(**over)
    problem = scenarios.block(
        phi_max=args.phi_max,
        L=args.L,
        shape=args.mesh,
        material=material,
        t_ramp=args.t_ramp,
        gauss_order=args.gauss or 3,
        damping=args.damping,
        volumetric=args.volumetric,
    )
    return run_problem(problem, args.t_end, args.dt, args, ["lateral_stretch"])


def _run_rolled(args):
    from . import scenarios

    over = {}
    if args.mu_inf is not None:
        over["mu_inf"] = args.mu_inf
    if args.mu is not None:
        over["mu"] = _floats(args.mu, "--mu")
    if args.eta is not None:
        over["eta"] = _floats(args.eta, "--eta")
    n = len(over.get("mu", scenarios.TABLE2[args.model][1]))
    if "mu" in over or "eta" in over:
        over.setdefault("K", [7.5e9] * n)
        over.setdefault("Jm", [5.0] * n)
    material = scenarios.rolled_material(args.model, **over)
    voltage = None
    if args.voltage is not None:
        from . import loads

        voltage = loads.read_csv(args.voltage)  # ValueError naming file, row, column: exit 2
    problem = scenarios.rolled(material, args.freq, args.phi_max, h=args.h, r=args.r, L=args.L, shape=args.mesh,
                               gauss_order=args.gauss or 3, damping=args.damping, point=args.point,
                               voltage=voltage, volumetric=args.volumetric)
    problem.params["model"] = args.model
    if voltage is not None:
        problem.params["voltage_file"] = str(args.voltage)
        t_end = args.cycles / args.freq if args.cycles is not None else float(voltage.times[-1])
    else:
        t_end = (args.cycles if args.cycles is not None else 10.0) / args.freq
    return run_problem(problem, t_end, args.dt, args, ["x_P"], args.solver)


def _run_torsional(args):
    from . import scenarios

    problem = scenarios.torsional(args.phibar_max, args.t_ramp, viscous=args.viscous, shape=args.mesh,
                                  gauss_order=args.gauss or 3, damping=args.damping, volumetric=args.volumetric)
    return run_problem(problem, args.t_end or args.t_ramp, args.dt, args, ["twist_angle"], args.solver)


def expand_run_shorthand(argv: list) -> list:
    """``dejax [options] run FILE.toml ...`` -> ``dejax [options] run experiment FILE.toml ...``;
    any other command line unchanged."""
    i = next((k for k, a in enumerate(argv) if not a.startswith("-")), None)
    if i is not None and argv[i] == "run" and i + 1 < len(argv) and argv[i + 1].lower().endswith(".toml"):
        return argv[: i + 1] + ["experiment"] + argv[i + 1:]
    return argv


def _cmd_verify(args):
    from .verification import cases

    ok = cases.main(quick=args.quick, json_path=args.json, quiet=args.quiet)
    return 0 if ok else 1


# ----------------------------------------------------------------------------- plot, sweep


def plot_handler(args) -> int:
    """``dejax plot``: PNG figures of a results file; prints their paths."""
    from .plot import plot_file

    try:
        paths = plot_file(args.file, args.out)
    except FileNotFoundError as e:
        print(f"dejax: error: {e}", file=sys.stderr)
        return 2
    except (OSError, KeyError) as e:
        print(f"dejax: error: cannot plot {args.file!r}: {e}", file=sys.stderr)
        return 2
    for p in paths:
        print(p)
    return 0


def register_plot(subparsers):
    """Add the ``plot`` verb: ``dejax plot results.h5 [--out DIR]``."""
    p = subparsers.add_parser("plot", help="PNG figures of a results file (x(t), loop, k_c, deformed mesh)")
    p.add_argument("file", help="results file (HDF5) written by dejax run")
    p.add_argument("--out", default=None, help="folder for the PNGs (default: next to the file)")
    p.set_defaults(func=plot_handler)
    return p


def _sweep_values(value, name):
    """A list of floats from the parsed option (a list) or a comma-separated string."""
    if isinstance(value, str):
        try:
            return float_list(name)(value)
        except Exception as e:  # argparse.ArgumentTypeError outside argparse
            raise ValueError(str(e)) from None
    return [float(v) for v in value]


def sweep_case_progress(stream):
    """A ``run_sweep`` progress callback writing ``case k/n (x s, ETA h:mm:ss)`` lines to ``stream``."""
    from .progress import format_duration

    def report(k, n, wall, ok):
        eta = wall / k * (n - k) if k else float("nan")
        stream.write(f"  case {k}/{n}{'' if ok else ' FAILED'}  {wall:.1f} s  ETA {format_duration(eta)}\n")
        stream.flush()

    return report


def sweep_handler(args) -> int:
    """``dejax sweep``: the rolled tube's cycle features per case, as a table (and JSON)."""
    from . import sweep
    from .integrate import Status

    grid = {k: _sweep_values(getattr(args, k), "--" + k.replace("_", "-")) for k in sweep.SWEEPABLE
            if getattr(args, k) is not None}
    if not grid:
        print("dejax: error: nothing to sweep: give at least one of --h --r --L --freq --phi-max", file=sys.stderr)
        return 2
    shape = mesh_shape(args.mesh) if isinstance(args.mesh, str) else tuple(args.mesh)
    try:
        cases = sweep.cases_from_grid(grid, dict(model=args.model), field_const=args.field_const)
        report = None if getattr(args, "quiet", False) else sweep_case_progress(sys.stderr)
        if report is not None:
            sys.stderr.write(f"compiling the tube stepper ({'x'.join(map(str, shape))} elements; the first "
                             f"{'case' if args.method == 'sequential' else 'batch'} includes it) ...\n")
        rows, info = sweep.run_sweep(cases, shape, args.cycles, args.steps_per_cycle, args.method, progress=report)
    except ValueError as e:
        print(f"dejax: error: {e}", file=sys.stderr)
        return 2
    cols = list(grid) + ["x_max", "x_min", "mean", "k_c", "loop_area"]
    print(" ".join(f"{c:>12}" for c in cols))
    for r in rows:
        print(" ".join(f"{r.get(c, float('nan')):12.5g}" for c in cols)
              + ("" if r["ok"] else f"  FAILED: {Status(r['status']).message}"))
    print(f"# {info['n_cases']} cases, {info['method']}, {info['n_devices']} device(s), {info['wall_s']:.1f} s",
          file=sys.stderr)
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"info": info, "rows": rows}, f, indent=1, default=float)
    return 0 if all(r["ok"] for r in rows) else 1


def register_sweep(subparsers):
    """Add the ``sweep`` verb: e.g. ``dejax sweep --freq 10,30,50 --phi-max 25e3 --mesh 1x4x1``."""
    from . import scenarios, sweep

    p = subparsers.add_parser("sweep", help="rolled-DEA parameter sweep -> per-case cycle features")
    base = sweep.cases_from_grid({})[0]
    for k, hlp in (("h", "wall thickness (m)"), ("r", "inner radius (m)"), ("L", "length (m)"),
                   ("freq", "frequency (Hz)"), ("phi_max", "peak voltage (V)")):
        flag = "--" + k.replace("_", "-")
        p.add_argument(flag, dest=k, type=float_list(flag), default=None,
                       help=f"comma-separated {hlp} (default when not swept: {base[k]:g})")
    p.add_argument("--model", default="IV", choices=sorted(scenarios.TABLE2), help="Table 2 material model")
    p.add_argument("--mesh", type=mesh_shape, default=(1, 4, 1), help="elements n_l x n_s x n_r")
    p.add_argument("--cycles", type=positive_int("--cycles"), default=2, help="voltage cycles per case")
    p.add_argument("--steps-per-cycle", type=positive_int("--steps-per-cycle"), default=40,
                   help="time steps per cycle (dt = 1 / (freq x steps))")
    p.add_argument("--method", choices=("sequential", "vmap"), default="sequential",
                   help="one compiled run case after case (one device), or all cases in one vmapped run, "
                        "sharded over every device JAX sees (cases padded to a multiple of their number)")
    p.add_argument("--field-const", action="store_true", help="scale phi_max with h (constant phi_max/h)")
    p.add_argument("--json", default=None, help="also write rows + timing info as JSON")
    p.add_argument("--quiet", action="store_true", help="no progress output")
    p.set_defaults(func=sweep_handler)
    return p


# ----------------------------------------------------------------------------- output paths, main


OUTPUT_PATHS = {
    "run": (("out", "file"), ("vtu", "folder")),
    "verify": (("json", "file"),),
    "sweep": (("json", "file"),),
    "bench": (("json", "file"),),
    "fit": (("out", "folder"),),
    "diagnose": (("out", "folder"),),
    "plot": (("out", "folder"),),
    "sensitivity": (("out", "folder"),),
}
"""Per verb: the arguments naming output files or folders, checked before any computation."""


def check_outputs(args) -> None:
    """Raise results.OutputPathError if an output path of ``args`` cannot be written."""
    from .results import check_output_dir, check_output_path

    for attr, kind in OUTPUT_PATHS.get(args.command, ()):
        path = getattr(args, attr, None)
        if path:
            (check_output_path if kind == "file" else check_output_dir)(path)


def main(argv=None) -> int:
    import shlex

    parser = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    args = parser.parse_args(expand_run_shorthand(argv))
    args.command_line = shlex.join(["dejax", *argv])
    from .results import OutputPathError

    try:
        check_outputs(args)
    except OutputPathError as e:
        print(f"dejax {args.command}: error: {e}", file=sys.stderr)
        return 2
    if not (args.no_compile_cache or compile_cache.disabled_by_env()):
        compile_cache.enable()
    try:
        if args.command == "run":
            return args.run_scenario(args)
        if args.command == "verify":
            return _cmd_verify(args)
        if hasattr(args, "func"):
            return int(args.func(args) or 0)
    except ValueError as e:  # bad parameter values found while building the problem
        print(f"dejax: error: {e}", file=sys.stderr)
        return 2
    parser.error(f"unknown command {args.command!r}")
    return 2


if __name__ == "__main__":
    sys.exit(main())
