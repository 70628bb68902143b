"""Size of the lowered programs of the forward run, G1 (jax.jacfwd) and G1R (jax.grad) of
G1's objective at 3 steps (tube 4x8x1): StableHLO text (MB), the part of it in large
constants (the mesh's index arrays, written out as literals), its lines, functions, while
loops, custom calls (the host's linear solves, LAPACK) and log1p operations (the Gent
logarithms), with the lowering time: what XLA compiles (most of G1R's compilation time).

    python bench/hlo_size.py

Measured 2026-12-07 (two runs; the first lowering pays the shared tracing, so the
lowering times depend on the order): forward 6.15 MB of which 5.05 MB large constants,
12,372 lines, 122 functions, 9 while loops, 19 custom calls, 8 log1p; G1 12.32 MB (10.14
MB), 24,267 lines, 174, 15, 35, 11; G1R 17.48 MB (15.12 MB: the largest constant, 3.9 MB
of text, three times), 25,285 lines, 266, 16, 35, 12. The constants are not what takes
the time (the dense assembly's scatter compiles in 0.05-0.07 s with its index a constant,
0.03 s with it an argument), and G1 and G1R have about as many lines, twice the forward
run's, while G1R took 28.2 s to compile against G1's 17.6 s: G1R's extra time is in what
XLA does with its operations (the transposes, the rematerialized body), not in their count.
"""
import time

import jax

from dejax import bench

f, theta = bench.g1_objective(3, bench.TUBE_DT)
for name, g in (("forward", f), ("G1", jax.jacfwd(f)), ("G1R", jax.grad(f))):
    tic = time.perf_counter()
    txt = jax.jit(g).lower(theta).as_text()
    lower_s = time.perf_counter() - tic
    lines = txt.splitlines()
    const = sum(len(s) for s in lines if "stablehlo.constant dense<" in s and len(s) > 500)
    print(f"{name}: lowered in {lower_s:.1f} s, {len(txt) / 1e6:.2f} MB ({const / 1e6:.2f} MB large constants), "
          f"{len(lines)} lines, functions {txt.count('func.func')}, while {txt.count('stablehlo.while')}, "
          f"custom calls {txt.count('custom_call')}, log1p {txt.count('log_plus_one')}", flush=True)
