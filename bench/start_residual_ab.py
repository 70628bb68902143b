"""The start pass that factorizes (``integrate._make_newton``: where the first iteration
factorizes anyway, the starting residual comes from the system's forces) against the
start pass that evaluates the residual on its own, in one process: the same step of
N1 (one full-Newton iteration, a fresh factorization each call) compiled both ways,
alternated; the old way is the current source with ``early`` switched off.

    python bench/start_residual_ab.py [12x20x4] [rounds]
"""
import sys, time, importlib.util, jax, jax.numpy as jnp, numpy as np
jax.config.update("jax_enable_x64", True)
from dejax import bench, linsolve, scenarios, integrate as it
src = open(it.__file__).read()
old = """            early = start & first & jax.lax.cond(start & first, lambda: _admissible(model, ctx, z),
                                                 lambda: jnp.asarray(False))"""
assert old in src
spec = importlib.util.spec_from_loader("dejax.integrate_old", loader=None)
old_mod = importlib.util.module_from_spec(spec); old_mod.__package__ = "dejax"; sys.modules["dejax.integrate_old"] = old_mod
exec(compile(src.replace(old, "            early = start & jnp.asarray(False)"), "integrate_old", "exec"), old_mod.__dict__)
shape = tuple(int(x) for x in (sys.argv[1] if len(sys.argv) > 1 else "12x20x4").split("x"))
p = scenarios.rolled("IV", 30.0, 50e3, shape=shape)
m = p.model
solv = linsolve.choose_solver(m.structure, "auto")
s0 = it.initial_state(m, p.loading, 0.0)
fac0 = it.initial_carry(m, s0, solv).fac
progs = {}
for name, mod in (("old", old_mod), ("new", it)):
    step = mod.make_step(p.scheme(), mod.NewtonOptions(reuse=False, max_iter=1, line_search=False), solv)
    progs[name] = jax.jit(lambda s, fac, step=step: step(m, p.loading, s, s.t + bench.TUBE_DT, fac, False))
    o = jax.block_until_ready(progs[name](s0, fac0)); print(name, "iterations", int(o[1]), "factorizations", int(o[2]), "status", int(o[3]))
    progs[name + "_q"] = o[0].q
print("max |q_new - q_old| / max |q|:", float(jnp.max(jnp.abs(progs["new_q"] - progs["old_q"])) / jnp.max(jnp.abs(progs["old_q"]))))
res = {"old": [], "new": []}
for r in range(int(sys.argv[2]) if len(sys.argv) > 2 else 8):
    for name in ("old", "new"):
        linsolve.clear_factorizations()
        tic = time.perf_counter(); jax.block_until_ready(progs[name](s0, fac0)); res[name].append(time.perf_counter() - tic)
for name, v in res.items(): print(f"{name}: best {min(v):.3f} s, median {np.median(v):.3f} s  ({' '.join(f'{x:.3f}' for x in v)})")
