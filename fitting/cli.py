"""The command-line verbs of the fitting package, registered by ``dejax.cli``:

* ``dejax fit experiment.toml --out DIR``: identify the ``[fit] free`` parameters
  (``fitting.experiment``, ``fitting.fit``); DIR/fit.json and DIR/fitted.toml (``fitting.fitted``);
* ``dejax sensitivity --params h,L,mu_inf``: forward-mode design sensitivities of the
  rolled tube (``fitting.sensitivity``);
* ``dejax diagnose experiment.toml --out DIR``: where the sim-to-real gap lies and which
  candidate effect closes it (``fitting.diagnose``).

Exit codes as ``dejax.cli``: 0 success, 1 a failed simulation, 2 bad arguments or input.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import jax
import numpy as np

from dejax import scenarios
from dejax.argtypes import int_at_least, nonneg, positive

from . import diagnose as dg
from . import effects as fx
from . import experiment
from . import placement
from . import report
from . import sensitivity as S
from .data import load_experiment
from .fitted import FITTED_NAME
from .schema import DataError


def register(subparsers) -> None:
    """Add the verbs fit, sensitivity and diagnose (in this order) to argparse subparsers."""
    register_fit(subparsers)
    register_sensitivity(subparsers)
    register_diagnose(subparsers)


# ----------------------------------------------------------------------------- run experiment


def run_experiment_handler(args) -> int:
    """``dejax run experiment FILE.toml``: the experiment under one trace's loading
    (``experiment.experiment_run``); a missing or invalid file or an unknown trace raises
    ValueError (exit 2) before any computation."""
    from dejax.cli import run_problem

    exp = load_experiment(args.experiment)  # DataError (a ValueError): exit 2, nothing computed
    setup = experiment.experiment_run(exp, args.trace, dt=args.dt, dt_min=args.dt_min, rho_inf=args.rho_inf,
                                      damping=args.damping, gauss_order=args.gauss, newton_tol=args.newton_tol,
                                      volumetric=args.volumetric)
    run_args = argparse.Namespace(**{**vars(args), **setup.settings})
    return run_problem(setup.problem, setup.t_end, setup.settings["dt"], run_args, [setup.output])


def register_run_experiment(run_subparsers) -> argparse.ArgumentParser:
    """Add ``experiment`` to the scenarios of ``dejax run``."""
    from dejax.cli import common_solver_args

    e = run_subparsers.add_parser(
        "experiment", help="an experiment file (TOML + CSV, e.g. dejax fit's fitted.toml) under one trace's loading; "
                           "short form: dejax run FILE.toml",
        description="Simulate an experiment file's scenario with its material and geometry under the loading of one "
                    "of its traces (its voltage column, else its loading table; uniaxial: its stretch), from 0 to the "
                    "trace's last time ([solver] t_end if given). --dt, --dt-min, --rho-inf, --damping, --gauss and "
                    "--newton-tol default to the file's [solver] (else dt = the trace's span / 200, the defaults "
                    "below). 'dejax run FILE.toml ...' is short for 'dejax run experiment FILE.toml ...'.")
    e.add_argument("experiment", help="experiment TOML file (docs/experiment-format.md)")
    e.add_argument("--trace", default=None, help="name of the trace whose loading drives the run (default: the "
                                                 "first [[traces]])")
    common_solver_args(e, dt=None)
    e.set_defaults(run_scenario=run_experiment_handler, rho_inf=None, damping=None, newton_tol=None, dt_min=None)
    return e


# ----------------------------------------------------------------------------- fit


def fit_handler(args) -> int:
    """``dejax fit``: fit the experiment, print the table, write --out."""
    try:
        exp = load_experiment(args.experiment)
        with placement.placed(_device(args, exp, "fit")):
            res = experiment.run_experiment(exp, out=args.out, adam_steps=args.adam_steps,
                                            lbfgs_steps=args.lbfgs_steps, n_steps=args.steps,
                                            max_points=args.max_points, verbose=not args.quiet,
                                            plots=not args.no_plots, optimizer=args.optimizer)
    except (DataError, ValueError, KeyError, FileNotFoundError) as e:
        print(f"dejax fit: error: {e}", file=sys.stderr)
        return 2
    except FloatingPointError as e:
        print(f"dejax fit: {e}", file=sys.stderr)
        return 1
    if args.quiet:
        print(res.table())
    if args.out:
        print(f"wrote {Path(args.out) / 'fit.json'} and {Path(args.out) / FITTED_NAME} (the experiment at the fitted "
              f"values: dejax run / diagnose / fit accept it)")
    return 0


def register_fit(subparsers) -> argparse.ArgumentParser:
    """Add the ``fit`` verb: ``dejax fit experiment.toml --out DIR``."""
    p = subparsers.add_parser("fit", help="fit material parameters to an experiment file (TOML + CSV)",
                              description="Fit the [fit] free parameters of an experiment TOML to its 'fit' "
                                          "traces; report held-out errors; write fit.json, fitted.toml (the "
                                          "experiment file at the fitted values, standard errors in comments and "
                                          "[fit.result]) and PNGs to --out.")
    p.add_argument("experiment", help="experiment TOML file")
    p.add_argument("--out", default=None, help="output folder (fit.json, fitted.toml, PNG plots)")
    p.add_argument("--optimizer", choices=("lm", "adam-lbfgs"), default=None,
                   help="Levenberg-Marquardt on the forward-mode Jacobian (at most max_iter evaluations), or "
                        "optax Adam then L-BFGS (default: [fit] optimizer, else lm; adam-lbfgs when --adam-steps "
                        "or --lbfgs-steps is given)")
    p.add_argument("--adam-steps", type=int_at_least("--adam-steps", 0), default=None,
                   help="Adam iterations of adam-lbfgs (default: max_iter / 2)")
    p.add_argument("--lbfgs-steps", type=int_at_least("--lbfgs-steps", 0), default=None,
                   help="L-BFGS iterations of adam-lbfgs (default: the rest of max_iter)")
    p.add_argument("--steps", type=int_at_least("--steps", 1), default=None,
                   help="time steps per trace (default: from the data / [solver] dt)")
    p.add_argument("--max-points", type=int_at_least("--max-points", 2), default=None,
                   help="subsample each trace to at most this many points (default: all)")
    p.add_argument("--no-plots", action="store_true", help="write fit.json and fitted.toml only")
    p.add_argument("--quiet", action="store_true", help="print only the final table")
    _add_device_option(p)
    p.set_defaults(func=fit_handler)
    return p


def _add_device_option(p) -> None:
    p.add_argument("--device", choices=placement.DEVICE_CHOICES, default="auto",
                   help="where the simulations run: auto (the host CPU for one-element problems when JAX's default "
                        "backend is a GPU, which is slower for them; else JAX's default), cpu, or default")


def _device(args, exp, verb: str):
    """``placement.device_for`` the experiment and ``--device``; says so when it moves the run
    to the host CPU on its own."""
    choice, elements = getattr(args, "device", "auto"), placement.n_elements(exp)
    device = placement.device_for(elements, choice)
    if device is not None and choice == "auto" and not getattr(args, "quiet", False):
        print(f"dejax {verb}: a {elements}-element problem: running on the host CPU, faster than "
              f"the {jax.default_backend().upper()} for it (--device default to keep it there)")
    return device


# ----------------------------------------------------------------------------- sensitivity


def sensitivity_handler(args) -> int:
    """``dejax sensitivity``: derivatives of the tube's outputs, printed and written to --out."""
    try:
        shape = tuple(int(s) for s in args.mesh.lower().split("x"))
        if len(shape) != 3:
            raise ValueError
    except ValueError:
        print(f"dejax sensitivity: error: --mesh must look like 1x4x1, got {args.mesh!r}", file=sys.stderr)
        return 2
    setup = S.Setup(shape=shape, model=args.model, freq=args.freq, phi_max=args.phi_max, t_end=args.t_end, dt=args.dt,
                    field=args.field)
    params = S.default_params(setup)
    names = [s.strip() for s in args.params.split(",") if s.strip()]
    try:
        S.check_names(names, params)
        if not (args.dt > 0 and args.t_end > args.dt):
            raise ValueError("need 0 < --dt < --t-end")
    except (KeyError, ValueError) as e:
        print(f"dejax sensitivity: error: {e}", file=sys.stderr)
        return 2
    res = S.sensitivity(params, names, setup)
    if not np.all(np.isfinite(res["values"]["x_P"])):
        print("dejax sensitivity: the simulation failed (non-finite x_P)", file=sys.stderr)
        return 1
    print(f"{'output':>10} " + " ".join(f"{'d/d' + k:>12}" for k in names) + "   (relative: p/y dy/dp)")
    for k, J in res["jacobian"].items():
        y = res["values"][k]
        yi = y[-1] if np.ndim(y) else y
        Ji = J[-1] if J.ndim > 1 else J
        rel = Ji * res["p"] / (yi if yi != 0 else 1.0)
        print(f"{k:>10} " + " ".join(f"{r:12.4g}" for r in rel) + ("  (last)" if np.ndim(y) else ""))
    print(f"one simulation {res['seconds_simulation']:.3f} s, jacfwd ({len(names)} parameters) "
          f"{res['seconds_jacobian']:.3f} s, ratio {res['ratio']:.2f}")
    checks = None
    if args.check:
        tic = time.perf_counter()
        fd = S.finite_differences(params, names, setup, rel_step=args.fd_step)
        fd_s = time.perf_counter() - tic
        rev = S.reverse_check(params, names, setup, jacobian=res["jacobian"])
        print(f"{'output':>10} {'jacfwd vs central FD':>21} {'reverse vs forward':>19}   (max relative error; "
              "not judged: entries with |p dy/dp| < 1e-3 max|y|)")
        checks = {}
        for r in S.check_rows(res, fd, rev):
            checks[r["output"]] = dict(fd_rel_error=r["fd_error"], reverse_rel_error=r["rev_error"], not_judged=r["tiny"])
            e_fd = "-" if r["fd_error"] is None else f"{r['fd_error']:.2e}"
            print(f"{r['output']:>10} {e_fd:>21} {r['rev_error']:19.2e}" + (f"   not judged: {', '.join(r['tiny'])}"
                                                                            if r["tiny"] else ""))
        print(f"central differences ({2 * len(names)} simulations, step {args.fd_step:g} p) {fd_s:.1f} s; one reverse "
              f"pass {rev['seconds_reverse']:.3f} s ({rev['seconds_reverse'] / res['seconds_simulation']:.2f} x a simulation)")
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        d = dict(names=names, p=res["p"].tolist(), setup=dataclasses.asdict(setup),
                 values={k: np.asarray(v).tolist() for k, v in res["values"].items()},
                 jacobian={k: np.asarray(v).tolist() for k, v in res["jacobian"].items()},
                 seconds_simulation=res["seconds_simulation"], seconds_jacobian=res["seconds_jacobian"],
                 ratio=res["ratio"], time=setup.times.tolist(), checks=checks,
                 units=dict(time="s", x_P="m", x_max="m", x_min="m", mean="m", k_c="1", loop_area="V m",
                            jacobian="output unit / parameter unit (parameters in SI: m, Pa, Pa s, F/m, kg/m^3)"))
        (out / "sensitivity.json").write_text(json.dumps(d))
        print(f"wrote {out / 'sensitivity.json'}")
    return 0


def register_sensitivity(subparsers) -> argparse.ArgumentParser:
    """Add the ``sensitivity`` verb: ``dejax sensitivity --params h,L,mu_inf --out DIR``."""
    p = subparsers.add_parser("sensitivity", help="forward-mode derivatives of the tube's x_P and cycle features",
                              description="Derivatives of x_P(t) and per-cycle features of the rolled tube with "
                                          "respect to geometry (h, L, r) and material parameters, by jax.jacfwd.")
    p.add_argument("--params", default="h,L,r,mu_inf,mu_1,eta_1", help="comma-separated parameter names")
    p.add_argument("--model", default="I", choices=sorted(scenarios.TABLE2), help="Table 2 material model")
    p.add_argument("--mesh", default="1x4x1", help="axial x circumferential x radial elements")
    p.add_argument("--freq", type=positive("--freq"), default=100.0, help="sine frequency (Hz)")
    p.add_argument("--phi-max", type=nonneg("--phi-max"), default=25e3, help="peak voltage (V)")
    p.add_argument("--t-end", type=positive("--t-end"), default=0.03, help="end time (s)")
    p.add_argument("--dt", type=positive("--dt"), default=5e-4, help="time step (s)")
    p.add_argument("--field", type=positive("--field"), default=None,
                   help="hold the nominal field phi_max / h fixed (V/m; phi_max then follows h, as in the paper's Fig. 20)")
    p.add_argument("--check", action="store_true",
                   help="also check the Jacobian against central finite differences and reverse mode (jax.vjp)")
    p.add_argument("--fd-step", type=positive("--fd-step"), default=1e-4, help="relative step of --check's differences")
    p.add_argument("--out", default=None, help="folder for sensitivity.json")
    p.set_defaults(func=sensitivity_handler)
    return p


# ----------------------------------------------------------------------------- diagnose


def register_diagnose(subparsers) -> argparse.ArgumentParser:
    """Add the ``diagnose`` verb: ``dejax diagnose experiment.toml --out DIR``."""
    p = subparsers.add_parser("diagnose", help="diagnose the sim-to-real gap of an experiment (report in --out)")
    p.add_argument("experiment", help="experiment TOML file (fitting.data schema)")
    p.add_argument("--out", default="report", help="output directory (report.md, report.json, PNGs)")
    p.add_argument("--effects", default=None, help="comma-separated candidate effects (default: the experiment's "
                   "[effects] tables, else the whole library)")
    p.add_argument("--noise", type=positive("--noise"), default=None,
                   help="noise sigma in output units (default: estimated from the traces)")
    p.add_argument("--max-iter", type=int_at_least("--max-iter", 1), default=8,
                   help="Levenberg-Marquardt evaluations per candidate (with --refit, 3 more per refitted "
                        "parameter)")
    p.add_argument("--fit-top", type=int_at_least("--fit-top", 0), default=3,
                   help="fit the best N candidates of the screening at the baseline (0: fit every candidate)")
    p.add_argument("--fit-pairs", type=int_at_least("--fit-pairs", 0), default=3,
                   help="when no single effect leaves residuals at the noise level, fit the best N screened pairs "
                        "(more, up to 8, while none does; 0: no pairs)")
    p.add_argument("--refit", nargs="?", const="", default=None, metavar="PARAMS",
                   help="refit the baseline's material parameters with every candidate (a factor in [1/10, 10] "
                        "on each): the comma-separated PARAMS, or without a value the experiment's [fit] free "
                        "(c_d excepted)")
    p.add_argument("--quiet", action="store_true", help="no progress output (the table and verdict only)")
    _add_device_option(p)
    p.set_defaults(func=diagnose_handler)
    return p


def refit_params(option: str | None, exp) -> list[str]:
    """The material parameters ``dejax diagnose --refit`` refits: none without the flag, the
    comma-separated list given, else the experiment's ``[fit] free`` without ``c_d``
    (ValueError when it has none)."""
    if option is None:
        return []
    if option.strip():
        return [s.strip() for s in option.split(",") if s.strip()]
    free = [k for k in exp.fit.free if k != "c_d"]
    if not free:
        raise ValueError(f"--refit without a list: {exp.path} has no [fit] free material parameters; "
                         "name them, e.g. --refit mu_inf,mu_1")
    return free


def diagnose_handler(args) -> int:
    """``dejax diagnose``: rank the candidate effects, print the table and verdict, write the report."""
    try:
        exp = load_experiment(args.experiment)
        with placement.placed(_device(args, exp, "diagnose")):  # the models built there too
            fwd, traces = dg.forward_from_experiment(exp)
            if args.effects:
                cands = [s.strip() for s in args.effects.split(",") if s.strip()]
            else:
                cands = list(exp.effects) or None
            for c in cands or []:
                fx.get(c)
            start = fx.from_experiment(exp) if exp.effects else None
            refit = refit_params(getattr(args, "refit", None), exp)
            diag = dg.diagnose(fwd, traces, cands, noise=args.noise, max_iter=args.max_iter, start=start,
                               verbose=not getattr(args, "quiet", False), fit_top=args.fit_top,
                               pairs=args.fit_pairs > 0, fit_pairs=args.fit_pairs, refit=refit)
    except (DataError, KeyError, ValueError, NotImplementedError, OSError) as e:
        print(f"dejax diagnose: error: {e}", file=sys.stderr)
        return 2
    files = report.write_report(diag, traces, args.out, title=f"Gap diagnosis: {exp.name}")
    print(diag.table())
    print(f"verdict: {diag.verdict}")
    if diag.alternatives:
        print("not separated from it by the withheld data (equivalent explanations): " + ", ".join(diag.alternatives))
    print(f"report: {files['markdown']}")
    return 0
