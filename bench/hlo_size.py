"""Size of the lowered programs of the forward run, G1 (jax.jacfwd) and G1R (jax.grad) of
G1's objective at 3 steps (tube 4x8x1): StableHLO text (MB), its functions, while loops,
custom calls (the host's linear solves, LAPACK) and log1p operations (the Gent logarithms:
one per branch of each instance of the point law), with the lowering time: what XLA
compiles, whose time is most of G1R's compilation.

    python bench/hlo_size.py

Measured 2026-12-07: forward 6.2 MB, 122 functions, 9 while loops, 19 custom calls, 8
log1p (0.6 s to lower); G1 12.3 MB, 174, 15, 35, 11 (3.7 s); G1R 17.5 MB, 266, 16, 35, 12
(10.2 s).
"""
import time, re, jax
from dejax import bench
f, th = bench.g1_objective(3, bench.TUBE_DT)
for name, g in (("G1R", jax.grad(f)), ("G1", jax.jacfwd(f)), ("fwd", f)):
    t = time.perf_counter(); low = jax.jit(g).lower(th); txt = low.as_text(); tl = time.perf_counter() - t
    print(name, "lower s", round(tl, 1), "MB", round(len(txt) / 1e6, 1), "log1p", txt.count("log_plus_one"),
          "while", txt.count("stablehlo.while"), "custom_call", txt.count("custom_call"), "func", txt.count("func.func"), flush=True)
