"""What the tube cases' Newton tolerance costs in accuracy (issue 10: R1 and G1's default).

    python bench/newton_tolerance.py [--tols 1e-2,1e-3,1e-4,1e-6] [--g1-steps 100]

R1's run (tube 4x8x1, Model IV, ten cycles at 30 Hz, 50 kV, dt = 5e-4 s) at each Newton
tolerance (relative residual): Newton iterations per step and the largest deviation of x_P
from the run at the tightest tolerance, relative to its peak; then G1's twelve derivatives
(jacfwd of the last-cycle mean x_P, ``dejax.bench.g1_objective``) over ``--g1-steps`` steps,
compared per parameter with those at the tightest tolerance. Measured (2 cores, 2026-12-04):
2.03 / 2.83 / 3.44 / 4.53 iterations per step; x_P within 2.2e-4 / 2.7e-5 / 2.2e-6 of the
peak; G1's derivatives over 100 steps within 5.5e-4 (1e-2) and 1.5e-5 (1e-4), relative.
"""
from __future__ import annotations

import argparse

import jax
import numpy as np

from dejax import bench
from dejax import integrate as it
from dejax import scenarios


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tols", default="1e-2,1e-3,1e-4,1e-6")
    ap.add_argument("--g1-steps", type=int, default=100)
    a = ap.parse_args()
    tols = sorted((float(t) for t in a.tols.split(",")), reverse=True)
    tight = tols[-1]

    p = scenarios.rolled("IV", 30.0, 50e3, shape=(4, 8, 1))
    times = it.time_grid(10 / 30.0, bench.TUBE_DT)
    x = {}
    for tol in tols:
        sol = it.simulate(p.model, p.loading, times, p.output_fn, p.scheme(), it.NewtonOptions(tol=tol)).check()
        x[tol] = np.asarray(sol.outputs["x_P"])
        print(f"R1 Newton to {tol:g}: {float(np.mean(np.asarray(sol.iterations)[1:])):.2f} iterations per step",
              flush=True)
    peak = np.max(np.abs(x[tight]))
    for tol in tols[:-1]:
        print(f"  max |x_P - x_P({tight:g})| / peak at {tol:g}: {np.max(np.abs(x[tol] - x[tight])) / peak:.2e}")

    jac = {}
    for tol in tols:
        f, theta0 = bench.g1_objective(a.g1_steps, bench.TUBE_DT, newton_tol=tol)
        jac[tol] = np.asarray(jax.jit(jax.jacfwd(f))(theta0))
    for tol in tols[:-1]:
        rel = np.max(np.abs(jac[tol] - jac[tight]) / np.abs(jac[tight]))
        print(f"G1 over {a.g1_steps} steps, Newton to {tol:g}: largest relative deviation of a derivative "
              f"from Newton to {tight:g}: {rel:.2e}")


if __name__ == "__main__":
    main()
