"""G1R's program (jax.grad of G1's objective, 60 steps) compiled with XLA:CPU options that
might compile it faster, one process, then each run twice (min s) and compared with the
first variant's derivatives.

    python bench/g1r_compile_options.py base,region,no-expensive-llvm,split2

Measured 2026-12-07 (fresh DEJAX_CACHE_DIR): compile 17.4 s (base), 18.3 s (copy insertion
by region analysis), 22.0 s (LLVM's expensive passes off), 22.7 s (codegen split in two);
runs 2.44 / 2.50 / 2.82 / 2.70 s, derivatives identical. None kept. Where the base's time
goes (a run with TF_CPP_VMODULE=cpu_compiler=1,hlo_pass_pipeline=1: 25-28 s on that slow
hour): HLO passes 8.5 s (copy insertion 4.2 s of them, simplification 1.2, call inlining
0.6, fusion 0.5), then the code generation, 15.3 s, most of it in LLVM.
"""
import sys, time, jax, numpy as np
from dejax import bench
f, th = bench.g1_objective(60, bench.TUBE_DT)
g = jax.jit(jax.grad(f))
low = g.lower(th)
variants = {"base": None,
            "region": {"xla_cpu_copy_insertion_use_region_analysis": True},
            "no-expensive-llvm": {"xla_llvm_disable_expensive_passes": True},
            "split2": {"xla_cpu_parallel_codegen_split_count": 2},
            "size": {"xla_cpu_optimize_for_size": True}}
names = sys.argv[1].split(",")
progs = {}
for n in names:
    t = time.perf_counter()
    try:
        progs[n] = low.compile(compiler_options=variants[n]) if variants[n] else low.compile()
    except Exception as e:
        print(n, "failed:", str(e)[:200]); continue
    print(n, "compile s", round(time.perf_counter() - t, 1), flush=True)
ref = None
best = {n: np.inf for n in progs}
for r in range(2):
    for n, c in progs.items():
        t = time.perf_counter(); out = np.asarray(jax.block_until_ready(c(th))); best[n] = min(best[n], time.perf_counter() - t)
        if ref is None: ref = out
        if r == 0: print(n, "max rel diff", float(np.max(np.abs(out - ref)) / np.max(np.abs(ref))), flush=True)
print({n: round(v, 2) for n, v in best.items()})
