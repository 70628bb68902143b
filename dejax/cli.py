"""Command line: ``dejax run``, ``dejax verify`` (and more verbs as they land).

Exit codes: 0 success, 1 simulation failure (reported with its time), 2 bad
arguments or an unwritable output path (nothing is written).
"""
from __future__ import annotations

import argparse
import importlib
import sys
import time

from . import compile_cache


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # exit code 2 with a clear message (argparse default is also 2)
        self.print_usage(sys.stderr)
        self.exit(2, f"{self.prog}: error: {message}\n")


def _positive(name):
    def conv(text):
        try:
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{name} must be a number, got {text!r}") from None
        if not v > 0:
            raise argparse.ArgumentTypeError(f"{name} must be > 0, got {text}")
        return v

    return conv


def _nonneg(name):
    def conv(text):
        try:
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{name} must be a number, got {text!r}") from None
        if v < 0:
            raise argparse.ArgumentTypeError(f"{name} must be >= 0, got {text}")
        return v

    return conv


def _mesh_shape(text):
    parts = text.lower().split("x")
    try:
        shape = tuple(int(p) for p in parts)
    except ValueError:
        shape = ()
    if len(shape) != 3 or min(shape) < 1:
        raise argparse.ArgumentTypeError(f"mesh must look like 12x20x4 (three positive integers), got {text!r}")
    return shape


def _rho_inf(text):
    v = _nonneg("--rho-inf")(text)
    if v > 1:
        raise argparse.ArgumentTypeError(f"--rho-inf must lie in [0, 1], got {text}")
    return v


def _common_solver_args(p):
    p.add_argument("--dt", type=_positive("--dt"), default=None, help="time step (s)")
    p.add_argument("--rho-inf", type=_rho_inf, default=0.8, help="generalized-alpha spectral radius (default 0.8)")
    p.add_argument("--damping", type=_nonneg("--damping"), default=0.0, help="structural damping c_d (1/s), C = c_d M")
    p.add_argument("--gauss", type=int, default=None, choices=(2, 3, 4, 5), help="Gauss points per direction")
    p.add_argument("--newton-tol", type=_positive("--newton-tol"), default=1e-6,
                   help="Newton tolerance: relative residual (default 1e-6), or the largest correction "
                        "(strain-like) with --newton-criterion correction")
    p.add_argument("--newton-criterion", default="residual", choices=("residual", "correction"),
                   help="Newton convergence test (default residual)")
    p.add_argument("--no-line-search", action="store_true", help="plain Newton steps (admissibility safeguard only)")
    p.add_argument("--dt-min", type=_positive("--dt-min"), default=1e-6,
                   help="smallest step of the cut-back (s, default 1e-6); a failure at dt-min is final")
    p.add_argument("--quasi-static", action="store_true", help="no inertia (equilibrium at every step)")
    p.add_argument("--volumetric", default="mixed", choices=("mixed", "displacement"),
                   help="volumetric treatment: element pressure (mixed, default) or the paper's pointwise penalty")
    p.add_argument("--out", required=True, help="results file (HDF5), written atomically")
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
    b.add_argument("--phi-max", type=_nonneg("--phi-max"), default=12e3, help="peak voltage phi_m (V)")
    b.add_argument("--t-end", type=_positive("--t-end"), default=3.0, help="end time (s)")
    b.add_argument("--t-ramp", type=_positive("--t-ramp"), default=1.0, help="ramp duration (s)")
    b.add_argument("--L", type=_positive("--L"), default=1e-3, help="cube side (m)")
    b.add_argument("--mesh", type=_mesh_shape, default=(1, 1, 1), help="elements, e.g. 2x2x2")
    b.add_argument("--hyperelastic", action="store_true", help="drop the viscous unit")
    b.add_argument("--mu-inf", type=_positive("--mu-inf"), default=None, help="override mu_inf (Pa)")
    b.add_argument("--eta", type=_positive("--eta"), default=None, help="override eta_1 (Pa s)")
    _common_solver_args(b)

    r = rsub.add_parser("rolled", help="rolled (tubular) DEA under the Eq. (42) sine voltage (paper Sec. 6)")
    r.add_argument("--model", default="IV", choices=("I", "II", "III", "IV", "hyperelastic"), help="Table 2 material")
    r.add_argument("--freq", type=_positive("--freq"), default=30.0, help="voltage frequency f (Hz)")
    r.add_argument("--phi-max", type=_nonneg("--phi-max"), default=50e3, help="peak voltage phi_m (V)")
    r.add_argument("--cycles", type=_positive("--cycles"), default=10.0, help="number of voltage cycles")
    r.add_argument("--mesh", type=_mesh_shape, default=(12, 20, 4), help="n_l x n_s x n_r elements")
    r.add_argument("--h", type=_positive("--h"), default=2e-3, help="wall thickness (m)")
    r.add_argument("--r", type=_positive("--r"), default=2e-3, help="inner radius (m)")
    r.add_argument("--L", type=_positive("--L"), default=8e-3, help="length (m)")
    r.add_argument("--point", default="P", choices=("P", "P_outer"), help="output point on the top face")
    r.add_argument("--mu-inf", type=_positive("--mu-inf"), default=None, help="override mu_inf (Pa)")
    r.add_argument("--mu", default=None, help="override the viscous mu_s, comma-separated (Pa)")
    r.add_argument("--eta", default=None, help="override the viscous eta_s, comma-separated (Pa s)")
    r.add_argument("--solver", default="auto", choices=("auto", "dense", "sparse", "pardiso"), help="linear solver")
    _common_solver_args(r)

    t = rsub.add_parser("torsional", help="twisted torsional strip, phibar ramp (paper Sec. 5)")
    t.add_argument("--phibar-max", type=_nonneg("--phibar-max"), default=0.5, help="final dimensionless voltage")
    t.add_argument("--t-ramp", type=_positive("--t-ramp"), default=1.0, help="ramp duration (s)")
    t.add_argument("--t-end", type=_positive("--t-end"), default=None, help="end time (s), default t_ramp")
    t.add_argument("--viscous", action="store_true", help="add the paper's viscous unit")
    t.add_argument("--mesh", type=_mesh_shape, default=(48, 8, 2), help="length x width x thickness elements")
    t.add_argument("--solver", default="auto", choices=("auto", "dense", "sparse", "pardiso"), help="linear solver")
    _common_solver_args(t)

    v = sub.add_parser("verify", help="run the verification cases against independent references")
    v.add_argument("--quick", action="store_true", help="fewer, shorter cases")
    v.add_argument("--json", default=None, help="also write the table as JSON to this path")

    from . import bench

    bench.register(sub)
    for module in ("fitting.experiment", "fitting.sensitivity", "fitting.diagnose", "dejax.plot", "dejax.sweep"):
        try:
            mod = importlib.import_module(module)
        except ImportError:  # an optional verb whose module is not installed
            continue
        if hasattr(mod, "register"):
            mod.register(sub)
    return parser


def _progress(quiet):
    if quiet:
        return None
    last = [0.0]

    def report(k, n, t, wall):
        now = time.perf_counter()
        if now - last[0] < 1.0 and k < n:
            return
        last[0] = now
        rate = k / wall if wall > 0 else float("nan")
        sys.stderr.write(f"\r  step {k}/{n}  t = {t:.4g} s  {rate:.0f} steps/s  ")
        if k >= n:
            sys.stderr.write("\n")
        sys.stderr.flush()

    return report


def _floats(text, name):
    try:
        return [float(x) for x in text.split(",")]
    except ValueError:
        raise ValueError(f"{name} must be comma-separated numbers, got {text!r}") from None


def _run_problem(problem, t_end, dt, args, summary_outputs, solver="auto"):
    import numpy as np

    from . import integrate as it
    from . import linsolve, stability
    from .results import write_h5

    times = it.time_grid(t_end, dt)
    sol, snaps, compile_s, run_s = it.run_chunked(
        problem.model,
        problem.loading,
        times,
        problem.output_fn,
        problem.scheme(args.rho_inf, True if args.quasi_static else None),
        it.NewtonOptions(tol=args.newton_tol, criterion=args.newton_criterion, line_search=not args.no_line_search),
        linsolve.choose_solver(problem.model.structure, solver),
        chunk=min(500, len(times) - 1),
        progress=_progress(args.quiet),
        snapshot_times=(float(times[-1]),),
        control=it.StepControl(dt_min=args.dt_min),
    )
    iters = np.asarray(sol.iterations)
    sol = stability.classify_failure(problem.model, problem.loading, sol, args.dt_min)
    if not sol.ok:
        detail = (f"the failing step was cut back {int(np.asarray(sol.cutbacks)[int(sol.fail_step)])} times, down to "
                  f"dt = {args.dt_min:g} s" if sol.n_cutbacks and int(sol.fail_step) >= 0 else "")
        detail = "; ".join(d for d in (detail, sol.detail) if d)
        err = it.SimulationError(it.Status(int(sol.status)), sol.fail_time, int(sol.fail_step) + 1, detail)
        print(f"dejax: error: {err} (no results file written)", file=sys.stderr)
        return 1
    n = len(times) - 1
    attrs = dict(
        status="ok",
        dt=dt,
        t_end=t_end,
        rho_inf=args.rho_inf,
        newton_tol=args.newton_tol,
        newton_criterion=args.newton_criterion,
        quasi_static=bool(args.quasi_static or problem.quasi_static),
        cutbacks=sol.n_cutbacks,
        dt_smallest=float(sol.dt_smallest),
        compile_s=compile_s,
        run_s=run_s,
        newton_mean=float(iters.mean()),
        newton_max=int(iters.max()),
    )
    snapshots = {k: {"t": float(st.t), "q": np.asarray(st.q), "q0": np.asarray(problem.model.q0)} for k, st in snaps.items()}
    write_h5(args.out, sol.time, {k: np.asarray(v) for k, v in sol.outputs.items()}, problem.params, iters,
             snapshots=snapshots, attrs=attrs)
    finals = ", ".join(f"{k} = {float(np.asarray(sol.outputs[k])[-1]):.6g}" for k in summary_outputs)
    print(
        f"{problem.name}: {n} steps to t = {t_end:g} s, compile {compile_s:.1f} s, run {run_s:.2f} s "
        f"({n / max(run_s, 1e-9):.0f} steps/s), Newton {iters.mean():.2f} mean / {iters.max()} max, "
        f"{sol.n_cutbacks} cut-backs (smallest dt {float(sol.dt_smallest):.3g} s); "
        f"final {finals} -> {args.out}"
    )
    return 0


def _cmd_run(args):
    from .results import OutputPathError, check_output_path

    try:
        check_output_path(args.out)
    except OutputPathError as e:
        print(f"dejax: error: {e}", file=sys.stderr)
        return 2
    if args.scenario == "block":
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
        return _run_problem(problem, args.t_end, args.dt or 1e-3, args, ["lateral_stretch"])
    if args.scenario == "rolled":
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
        problem = scenarios.rolled(material, args.freq, args.phi_max, h=args.h, r=args.r, L=args.L, shape=args.mesh,
                                   gauss_order=args.gauss or 3, damping=args.damping, point=args.point,
                                   volumetric=args.volumetric)
        problem.params["model"] = args.model
        return _run_problem(problem, args.cycles / args.freq, args.dt or 1e-4, args, ["x_P"], args.solver)
    if args.scenario == "torsional":
        from . import scenarios

        problem = scenarios.torsional(args.phibar_max, args.t_ramp, viscous=args.viscous, shape=args.mesh,
                                      gauss_order=args.gauss or 3, damping=args.damping, volumetric=args.volumetric)
        return _run_problem(problem, args.t_end or args.t_ramp, args.dt or 1e-2, args, ["twist_angle"], args.solver)
    raise AssertionError(args.scenario)


def _cmd_verify(args):
    from . import verify

    ok = verify.main(quick=args.quick, json_path=args.json)
    return 0 if ok else 1


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not (args.no_compile_cache or compile_cache.disabled_by_env()):
        compile_cache.enable()
    try:
        if args.command == "run":
            return _cmd_run(args)
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
