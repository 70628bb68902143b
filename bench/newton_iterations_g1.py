"""Newton iterations and factorizations of R1's first 100 steps (tube 4x8x1, dt = 1/1500 s)
at three Newton tolerances, with and without step cut-back: what a better Newton matrix
(the implicit derivative's exact tangent handed to the next step) could take off G1.

    python bench/newton_iterations_g1.py

Measured 2026-12-07: at 1e-2 (R1's and G1's tolerance) 204 iterations and 1 factorization
in 100 steps (2.04 per step), x_P(end) 1.897e-5 m; at 0.3, 105 iterations, 6
factorizations, x_P(end) 3.44e-5 m (a different trajectory); at 0.9 the run fails without
cut-back (status 1) and needs 16 cut-backs with it. The forward run (no cut-back, jitted,
min of 5 alternated calls: the script's last line) takes 0.709 / 0.572 s at 1e-2 and
0.624 / 0.552 s at 0.3 (1.05 iterations per step; two runs): one iteration less per step
saves 0.02-0.085 s per 100 steps, at most ~1 % of G1's 6.89 s there. A perfect Newton
matrix can take no more than that off G1. An earlier bound that ran G1 at tolerance 0.9
(5.11 s) timed a failed run, whose steps after the failure are skipped.
"""
import time

import jax
import numpy as np

from dejax import bench, scenarios
from dejax import integrate as it

times = it.time_grid(10 / 30.0, bench.TUBE_DT)[:101]
for tol in (1e-2, 0.3, 0.9):
    for control in (None, it.StepControl()):
        p = scenarios.rolled(scenarios.rolled_material("IV"), 30.0, 50e3, shape=(4, 8, 1))
        sol = it.simulate(p.model, p.loading, times, p.output_fn, newton=it.NewtonOptions(tol=tol), control=control)
        cut = None if sol.cutbacks is None else int(np.sum(sol.cutbacks))
        print(f"tol {tol:g} cut-back {control is not None}: status {int(sol.status)}, iterations "
              f"{int(np.sum(sol.iterations))}, factorizations {int(np.sum(sol.factorizations))}, cut-backs {cut}, "
              f"x_P(end) {float(sol.outputs['x_P'][-1]):.4g} m", flush=True)

# the forward run at 1e-2 and at 0.3 (about one iteration per step), compiled, alternated
progs = {}
for tol in (1e-2, 0.3):
    f, theta = bench.g1_objective(100, bench.TUBE_DT, newton_tol=tol)
    progs[tol] = jax.jit(lambda th, f=f: f(th, None)).lower(theta).compile()
best = {tol: np.inf for tol in progs}
for _ in range(5):
    for tol, c in progs.items():
        t = time.perf_counter()
        jax.block_until_ready(c(theta))
        best[tol] = min(best[tol], time.perf_counter() - t)
print("forward run, 100 steps, min of 5: " + ", ".join(f"tol {k:g} {v:.3f} s" for k, v in best.items()))
