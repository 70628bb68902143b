"""Robustness matrix of the nonlinear solve: ``dejax bench --cases robust``.

Each case runs a scenario with the default solver (mixed form unless the row says
"penalty", line search, cut-back; full Newton for the one-element uniaxial cases, as
FElupe's figures, modified Newton elsewhere) and reports Newton iterations per step
(median / max over the steps taken), factorizations, cut-backs, the smallest step used
and pass/fail:

* uniaxial (one element, quasi-static, Gent mu = 15 kPa, Jm = 60): stretch to 3 and 6,
  K/mu = 1e3 .. 1e6 and K = inf (mixed form), stretch increments 0.05, 0.1, 0.2 at a
  stretch rate of 0.05 1/s, hyperelastic and with two viscous units (VHB-like:
  mu_1 = 25 kPa, eta_1 = 2.5e5 Pa s; mu_2 = 15 kPa, eta_2 = 1.5e4 Pa s), in the mixed
  form and in the paper's pointwise penalty form;
* the block (paper Sec. 4) at 8, 12, 16 kV, dt = 1e-3 and 1e-2 s, to 3 s;
* the rolled tube, Model IV, 50 kV, 30 Hz, two cycles, meshes 2x4x1, 4x8x1, 8x12x2,
  dt = 1e-4 and 1e-3 s;
* the torsional strip, quasi-static, phibar 0 -> 0.5 in 10 and 40 increments,
  hyperelastic and viscous, on the paper's 48x8x2 mesh (768 elements).

``select`` keeps the cases whose name contains any of the given substrings.
"""
from __future__ import annotations

import time

import numpy as np

from . import integrate as it
from . import linsolve, loads, scenarios
from .material import Material

UNIAXIAL_RATE = 0.05  # 1/s
VHB_UNITS = dict(mu=[25e3, 15e3], K=[0.0, 0.0], Jm=[60.0, 60.0], eta=[2.5e5, 1.5e4])


def _row(name, sol, wall, n_steps):
    its = np.asarray(sol.iterations)
    done = its[its > 0] if np.any(its > 0) else its
    return dict(case=name, steps=n_steps, newton_median=float(np.median(done)), newton_max=int(its.max()),
                factorizations=int(np.sum(np.asarray(sol.factorizations))),
                cutbacks=sol.n_cutbacks, dt_smallest=float(sol.dt_smallest), passed=bool(sol.ok),
                status=it.Status(int(sol.status)).name, fail_time=sol.fail_time, wall_s=wall)


def uniaxial_cases():
    for lam in (3.0, 6.0):
        for visc in (False, True):
            for vol in ("mixed", "displacement"):
                for kr in (1e3, 1e4, 1e5, 1e6, np.inf):
                    if vol == "displacement" and not np.isfinite(kr):
                        continue
                    for inc in (0.05, 0.1, 0.2):
                        form = "mixed" if vol == "mixed" else "penalty"
                        name = (f"uniaxial lam {lam:g} K/mu {kr:g} inc {inc:g} {'visc' if visc else 'hyper'} "
                                f"{form}")
                        yield name, dict(lam=lam, visc=visc, vol=vol, kr=kr, inc=inc)


def run_uniaxial(lam, visc, vol, kr, inc):
    mu = 15e3
    mat = Material(mu_inf=mu, K_inf=kr * mu, Jm_inf=60.0, eps=4e-11, rho=1000.0, **(VHB_UNITS if visc else {}))
    t_end = (lam - 1.0) / UNIAXIAL_RATE
    p = scenarios.uniaxial(loads.PiecewiseLinear([0.0, t_end], [1.0, lam]), mat, volumetric=vol)
    times = it.time_grid(t_end, inc / UNIAXIAL_RATE)
    pad = int(round((6.0 - 1.0) / 0.05))  # one compilation per material type
    # full Newton, as FElupe's figures in the issue (on one element a factorization costs nothing)
    return p, times, dict(pad_to=pad, newton=it.NewtonOptions(reuse=False))


def block_cases():
    for vol in ("mixed", "displacement"):
        for phi in (8e3, 12e3, 16e3):
            for dt in (1e-3, 1e-2):
                form = "mixed" if vol == "mixed" else "penalty"
                yield f"block {phi / 1e3:g} kV dt {dt:g} {form}", dict(phi=phi, dt=dt, vol=vol)


def run_block(phi, dt, vol):
    p = scenarios.block(phi_max=phi, volumetric=vol)
    return p, it.time_grid(3.0, dt), dict(pad_to=3000)


def tube_cases():
    for shape in ((2, 4, 1), (4, 8, 1), (8, 12, 2)):
        for dt in (1e-4, 1e-3):
            yield f"tube {'x'.join(map(str, shape))} IV 50 kV 30 Hz dt {dt:g}", dict(shape=shape, dt=dt)


def run_tube(shape, dt):
    p = scenarios.rolled("IV", 30.0, 50e3, shape=shape)
    return p, it.time_grid(2.0 / 30.0, dt), dict(solver=linsolve.choose_solver(p.model.structure))


def torsional_cases(shape=(48, 8, 2)):
    for visc in (False, True):
        for n in (10, 40):
            yield (f"torsional {'x'.join(map(str, shape))} {'visc' if visc else 'hyper'} {n} increments",
                   dict(visc=visc, n=n, shape=shape))


def run_torsional(visc, n, shape):
    p = scenarios.torsional(0.5, 1.0, viscous=visc, shape=shape)
    return p, it.time_grid(1.0, 1.0 / n), dict(solver=linsolve.choose_solver(p.model.structure), quasi_static=True)


FAMILIES = (
    (uniaxial_cases, run_uniaxial, True),
    (block_cases, run_block, False),
    (tube_cases, run_tube, False),
    (torsional_cases, run_torsional, True),
)


def run(select=(), progress=None, torsional_shape=(48, 8, 2)):
    """Run the matrix; returns the rows (dicts)."""
    rows = []
    for cases, runner, quasi in FAMILIES:
        gen = cases(torsional_shape) if cases is torsional_cases else cases()
        for name, kw in gen:
            if select and not any(s in name for s in select):
                continue
            if progress:
                progress(name)
            problem, times, opts = runner(**kw)
            scheme = it.QuasiStatic() if (quasi or opts.pop("quasi_static", False)) else it.GeneralizedAlpha(
                problem.rho_inf)
            tic = time.perf_counter()
            sol = it.simulate(problem.model, problem.loading, times, problem.output_fn, scheme,
                              opts.get("newton", it.NewtonOptions()), solver=opts.get("solver"),
                              pad_to=opts.get("pad_to"))
            n = times.size - 1
            rows.append(_row(name, sol, time.perf_counter() - tic, n))
    return rows


def format_table(rows) -> str:
    head = (f"{'case':<58} {'steps':>5} {'Newton med/max':>14} {'fact.':>6} {'cut-backs':>9} {'dt min':>9} "
            f"{'result':>8}")
    lines = [head, "-" * len(head)]
    for r in rows:
        res = "pass" if r["passed"] else f"FAIL {r['status']} t={r['fail_time']:.4g}"
        lines.append(f"{r['case']:<58} {r['steps']:>5} {r['newton_median']:>8.1f}/{r['newton_max']:<5} "
                     f"{r['factorizations']:>6} {r['cutbacks']:>9} {r['dt_smallest']:>9.3g} {res:>8}")
    n_pass = sum(r["passed"] for r in rows)
    lines.append(f"{n_pass} of {len(rows)} cases pass (Newton: iterations per step over all sub-steps; wall "
                 f"times in the JSON include compilation)")
    return "\n".join(lines)
