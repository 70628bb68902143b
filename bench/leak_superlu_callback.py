"""Reproduction of the memory growth of the sparse path (issue 10: memory), now fixed.

    python bench/leak_superlu_callback.py

Factorizes the torsional strip 24x4x2's tangent 40 times with different values, first
by calling ``SparseSolver._host_solve`` directly from Python (RSS stays flat), then
through ``SparseSolver.solve_factored`` inside ``jax.jit`` (the host callback path the
simulations use): there RSS grows by about one factorization (~30 MB) per factorization
although the factor cache holds at most four. Measured 2026-12-01: 0.93 -> 1.94 GB over
35 factorizations; unchanged with MALLOC_ARENA_MAX=1, MALLOC_MMAP_THRESHOLD_, malloc_trim,
a cache of one entry, an owned copy of the values, or the factorization run on a
dedicated Python thread. On the paper's 48x8x2 strip this is 22 GB after two runs.

Cause: XLA runs host callbacks on varying threads, and a SuperLU factorization freed on
another thread than the one that made it was never released. Fixed by running every host
factorization, solve and eviction on one dedicated thread (``linsolve._HOST_THREAD``):
after the fix both loops stay flat (0.95 -> 1.00 GB over 40 factorizations); regression
test ``tests/test_linsolve.py::test_sparse_factorizations_through_the_callback_are_freed``.
"""
import jax
import jax.numpy as jnp
import numpy as np

from dejax import linsolve, scenarios
from dejax import model as mdl

jax.config.update("jax_enable_x64", True)


def rss_gb() -> float:
    for line in open("/proc/self/status"):
        if line.startswith("VmRSS"):
            return int(line.split()[1]) / 1e6
    return float("nan")


def main():
    m = scenarios.torsional(0.5, 1.0, viscous=False, shape=(24, 4, 2)).model
    E = mdl.nominal_field(m, jnp.zeros(m.field_dirs.shape[0]))
    Ke = mdl.element_tangents(m, m.q0, E, mdl.initial_viscous_state(m), 1.0, mdl.initial_pressure(m))[1]
    solver = linsolve.SparseSolver()
    vals = np.asarray(mdl.assemble_values(m, Ke))
    pat = mdl.assembly(m.structure)  # rows, cols, indptr, n, nnz
    b = np.random.default_rng(0).standard_normal(pat.n)
    print(f"nnz {pat.nnz}, RSS {rss_gb():.2f} GB")
    for k in range(40):
        solver._host_solve(pat, vals * (1 + 1e-3 * k), b)
        if k % 10 == 9:
            print(f"direct   {k + 1:3d} factorizations: RSS {rss_gb():.2f} GB", flush=True)
    solve = jax.jit(lambda v, r: solver.solve_factored(m, v, r))
    vj, bj = jnp.asarray(vals), jnp.asarray(b)
    for k in range(40):
        jax.block_until_ready(solve(vj * (1 + 1e-3 * (k + 40)), bj))
        if k % 10 == 9:
            print(f"callback {k + 1:3d} factorizations: RSS {rss_gb():.2f} GB", flush=True)


if __name__ == "__main__":
    main()
