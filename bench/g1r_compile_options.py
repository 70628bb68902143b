"""G1R's program (jax.grad of G1's objective, 60 steps) compiled with XLA:CPU options that
might compile it faster, one process, then each run twice (min s) and compared with the
first variant's derivatives.

    python bench/g1r_compile_options.py [base,region,no-expensive-llvm,split2]

Measured 2026-12-07 (fresh DEJAX_CACHE_DIR): compile 17.4 s (base), 18.3 s (copy insertion
by region analysis), 22.0 s (LLVM's expensive passes off), 22.7 s (codegen split in two);
runs 2.44 / 2.50 / 2.82 / 2.70 s, derivatives identical. None kept. Where the base's time
goes (a run with TF_CPP_VMODULE=cpu_compiler=1,hlo_pass_pipeline=1: 25-28 s on that slow
hour): HLO passes 8.5 s (copy insertion 4.2 s of them, simplification 1.2, call inlining
0.6, fusion 0.5), then the code generation, 15.3 s, most of it in LLVM.
"""
import sys
import time

import jax
import numpy as np

from dejax import bench

VARIANTS = {
    "base": None,
    "region": {"xla_cpu_copy_insertion_use_region_analysis": True},
    "no-expensive-llvm": {"xla_llvm_disable_expensive_passes": True},
    "split2": {"xla_cpu_parallel_codegen_split_count": 2},
}

names = (sys.argv[1] if len(sys.argv) > 1 else ",".join(VARIANTS)).split(",")
f, theta = bench.g1_objective(60, bench.TUBE_DT)
lowered = jax.jit(jax.grad(f)).lower(theta)
programs = {}
for name in names:
    tic = time.perf_counter()
    programs[name] = lowered.compile(compiler_options=VARIANTS[name])
    print(f"{name}: compiled in {time.perf_counter() - tic:.1f} s", flush=True)
ref, best = None, {name: np.inf for name in programs}
for rep in range(2):
    for name, program in programs.items():
        tic = time.perf_counter()
        out = np.asarray(jax.block_until_ready(program(theta)))
        best[name] = min(best[name], time.perf_counter() - tic)
        ref = out if ref is None else ref
        if rep == 0:
            print(f"{name}: largest difference {np.max(np.abs(out - ref)) / np.max(np.abs(ref)):.1e} (relative)")
print("run s (min of 2): " + ", ".join(f"{name} {s:.2f}" for name, s in best.items()))
