"""The element pressure blocks' small solves (kpp^-1 in the condensation, the pressure force
and the pressure correction) by LAPACK (``jnp.linalg.solve``) against Gaussian elimination
written out over n_p, two programs compiled in one process and alternated (six rounds,
best of two calls each): G1 (``jax.jacfwd``, 60 steps) or N1's iteration (factorization
cached). Needs ``git apply bench/patches/unrolled_pressure_solve.patch`` (the switch
``model.SMALL_SOLVE``).

    python bench/small_solve_ab.py G1      (or N1)

Measured 2026-12-08 (CPU reference 1.3-1.6 s): G1 best 1.838 / 1.806 s (LAPACK /
unrolled), then 1.774 / 1.801 s in a second run; N1 0.315 / 0.310 s, medians 0.337 / 0.339
s; derivatives equal to 3.6e-15. No effect beyond the noise: not kept.
"""
import sys
import time

import jax
import numpy as np

from dejax import bench, linsolve, scenarios
from dejax import integrate as it
from dejax import model as mdl


def main():
    case = sys.argv[1] if len(sys.argv) > 1 else "G1"
    if not hasattr(mdl, "SMALL_SOLVE"):
        raise SystemExit("apply bench/patches/unrolled_pressure_solve.patch first")
    progs = {}
    for variant in ("lapack", "unrolled"):
        mdl.SMALL_SOLVE = variant
        jax.clear_caches()  # the variant is read when the program is traced
        if case == "G1":
            f, theta = bench.g1_objective(60, bench.TUBE_DT)
            progs[variant] = (jax.jit(jax.jacfwd(f)).lower(theta).compile(), (theta,))
        else:
            p = scenarios.rolled("IV", 30.0, 50e3, shape=(12, 20, 4))
            m = p.model
            solver = linsolve.choose_solver(m.structure, "auto")
            s0 = it.initial_state(m, p.loading, 0.0)
            fac0 = it.initial_carry(m, s0, solver).fac
            step = it.make_step(p.scheme(), it.NewtonOptions(reuse=False, max_iter=1, line_search=False), solver)
            one = jax.jit(lambda s, fac, step=step, m=m, p=p: step(m, p.loading, s, s.t + bench.TUBE_DT, fac, False))
            progs[variant] = (one.lower(s0, fac0).compile(), (s0, fac0))
    outs = {}

    def wall(variant):
        g, args = progs[variant]
        tic = time.perf_counter()
        outs[variant] = jax.block_until_ready(g(*args))
        return time.perf_counter() - tic

    for variant in progs:
        wall(variant)
    times = {variant: [] for variant in progs}
    for _ in range(6):
        for variant in progs:
            times[variant].append(min(wall(variant) for _ in range(2)))
    for variant, t in times.items():
        print(f"{case} {variant}: best {min(t):.3f} s, median {np.median(t):.3f} s")
    a, b = (np.asarray(jax.tree_util.tree_leaves(outs[v])[0]) for v in progs)
    print(f"largest relative difference {np.max(np.abs(a - b)) / max(np.max(np.abs(a)), 1e-300):.1e}")


if __name__ == "__main__":
    main()
