"""R2's first step by full Newton limited to 1, 2 and 3 iterations (every one run: a correction
criterion of 1e-300), compiled once each and alternated in one process, fresh factorizations:
the step's own work (predictor, start pass, checks) beside the iterations' cost.

    python bench/n1_iterations.py
"""
import time, jax, numpy as np
jax.config.update("jax_enable_x64", True)
from dejax import bench, linsolve, scenarios, integrate as it
p = scenarios.rolled("IV", 30.0, 50e3, shape=(12, 20, 4))
m = p.model
solv = linsolve.choose_solver(m.structure, "auto")
s0 = it.initial_state(m, p.loading, 0.0)
fac0 = it.initial_carry(m, s0, solv).fac
def prog(k):
    step = it.make_step(p.scheme(), it.NewtonOptions(reuse=False, max_iter=k, tol=1e-300, criterion="correction", line_search=False), solv)
    return jax.jit(lambda s, fac: step(m, p.loading, s, s.t + bench.TUBE_DT, fac, False))
progs = {k: prog(k) for k in (1, 2, 3)}
for k, f in progs.items():
    out = jax.block_until_ready(f(s0, fac0)); print(k, "iterations", int(out[1]), "fac", int(out[2]))
res = {k: [] for k in progs}
for r in range(5):
    for k, f in progs.items():
        linsolve.clear_factorizations()
        tic = time.perf_counter(); jax.block_until_ready(f(s0, fac0)); res[k].append(time.perf_counter() - tic)
for k in res: print(k, "best %.3f median %.3f" % (min(res[k]), np.median(res[k])))
print("marginal 1->2 %.3f, 2->3 %.3f" % (min(res[2]) - min(res[1]), min(res[3]) - min(res[2])))
