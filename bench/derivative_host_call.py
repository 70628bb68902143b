"""What one host call of the derivative's Pardiso solve costs on the tube 4x8x1 (720
unknowns, the condensed tangent 20 steps into R1's loading, factorization cached): the
12-lane solve through ``jax.pure_callback`` from a jitted program, the host function alone,
and MKL's phase 33 alone (ms, best and median of 200), with a cProfile of the host side.

    cd bench && python derivative_host_call.py
"""
import time, jax, jax.numpy as jnp, numpy as np, cProfile, pstats
jax.config.update("jax_enable_x64", True)
from dejax import linsolve, model as mdl, integrate as it
from derivative_solver import condensed_tangent
m, Kc = condensed_tangent((4, 8, 1))
solver = linsolve.SparseSolver("pardiso")
vals = jax.jit(lambda K: solver.factor(m, K))(Kc)
n = m.structure.n_free
B = jnp.asarray(np.random.default_rng(0).standard_normal((12, n)))
solve12 = jax.jit(jax.vmap(lambda b: solver.solve_factored(m, vals, b)))
jax.block_until_ready(solve12(B))
def t(f, *a, n=200):
    ts = []
    for _ in range(n):
        tic = time.perf_counter(); jax.block_until_ready(f(*a)); ts.append(time.perf_counter() - tic)
    return 1e3 * min(ts), 1e3 * np.median(ts)
print("jitted 12-lane solve via callback (ms best/median):", t(solve12, B))
pat = mdl.assembly(m.structure)
vn, Bn = np.asarray(vals), np.asarray(B)
print("host _host_solve (ms):", t(lambda: solver._host_solve(pat, vn, Bn)))
print("host _host_solve_here (ms):", t(lambda: solver._host_solve_here(pat, vn, Bn)))
f = linsolve._CACHE.get(pat, vn, "pardiso")
Bt = np.ascontiguousarray(Bn.T)
print("pardiso phase 33 alone (ms):", t(lambda: f(Bt)))
pr = cProfile.Profile(); pr.enable()
for _ in range(200): solver._host_solve_here(pat, vn, Bn)
pr.disable(); pstats.Stats(pr).sort_stats("tottime").print_stats(8)
