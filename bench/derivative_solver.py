"""The implicit derivative's solver (``integrate._derivative_solver``): dense against MKL
Pardiso, in one process.

    python bench/derivative_solver.py [--shapes 2x4x1,4x4x1,4x8x1] [--g1-steps 100] [--rounds 2]

1. For each tube mesh (Model IV, a state 20 steps into R1's loading): the condensed exact
   tangent's factorization and one solve (ms, median; the sparse cache cleared before each),
   and 12 solves with the factorization (one vmapped call, G1's lanes), dense and Pardiso.
2. G1 (``bench.case_G1``, first ``--g1-steps`` steps, run time projected to the full run as
   ``dejax bench`` does), the derivative's solver alternating between dense
   (``DERIVATIVE_SPARSE_FROM`` above the mesh's unknowns) and Pardiso, and the largest
   relative difference of the twelve derivatives.
"""
from __future__ import annotations

import argparse

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)

from dejax import bench, linsolve  # noqa: E402
from dejax import integrate as it  # noqa: E402
from dejax import model as mdl  # noqa: E402
from profile_step import loaded_step, timed  # noqa: E402

DT = 6.666666666666667e-4


def condensed_tangent(shape):
    p, _, state, ctx, z = loaded_step(shape, 20, DT)
    m, scheme = p.model, p.scheme()
    s = jax.jit(lambda z, p: it._system(m, scheme, ctx, z, p))(z, state.p)
    return m, jax.jit(lambda s: mdl.condense(s.Ke, s.kup, mdl.newton_kpp(m, s.kpp)))(s)


def factor_and_solve(shape):
    m, Kc = condensed_tangent(shape)
    n = m.structure.n_free
    rhs, lanes = jnp.ones(n), jnp.ones((12, n))
    for name, solver in (("dense", linsolve.DenseSolver()), ("pardiso", linsolve.SparseSolver("pardiso"))):
        once = jax.jit(lambda K, r: solver.solve_factored(m, solver.factor(m, K), r))
        fac = jax.jit(lambda K: solver.factor(m, K))(Kc)
        twelve = jax.jit(lambda F, r: jax.vmap(lambda b: solver.solve_factored(m, F, b))(r))
        t_once = timed(once, Kc, rhs, repeat=30, before=linsolve.clear_factorizations)[0]
        print(f"tube {'x'.join(map(str, shape))} ({n} unknowns) {name:<8} factorization + solve "
              f"{t_once:6.2f} ms, 12 solves {timed(twelve, fac, lanes, repeat=30)[0]:6.2f} ms")


def g1(steps, rounds):
    grads = {}
    for r in range(rounds):
        for name, start in (("dense", 10**9), ("pardiso", 0)):
            it.DERIVATIVE_SPARSE_FROM = start
            jax.clear_caches()
            row = bench.case_G1(max_steps=steps, dt=DT)
            grads[name] = np.asarray(row["gradient"])
            print(f"round {r}: G1 derivative solver {name:<8} run {row['run_s']:6.2f} s (projected), "
                  f"compile {row['compile_s']:5.1f} s", flush=True)
    d, s = grads["dense"], grads["pardiso"]
    print(f"max |G(pardiso) - G(dense)| / max |G(dense)| = {np.max(np.abs(s - d)) / np.max(np.abs(d)):.1e}")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--shapes", default="2x4x1,4x4x1,4x8x1")
    ap.add_argument("--g1-steps", type=int, default=100, help="0: skip G1")
    ap.add_argument("--rounds", type=int, default=2)
    a = ap.parse_args()
    if not linsolve.pardiso_available():
        raise SystemExit("pip install pypardiso (or the fast extra) to compare with MKL Pardiso")
    for sh in a.shapes.split(","):
        factor_and_solve(tuple(int(x) for x in sh.split("x")))
    if a.g1_steps:
        g1(a.g1_steps, a.rounds)


if __name__ == "__main__":
    main()
