"""G1 (``jax.jacfwd`` of G1's objective, tube 4x8x1, 100 steps) with the derivative's MKL
Pardiso calls made on XLA's calling thread or handed to dejax's host thread, toggled
between calls of one compiled program (six rounds, alternated), beside the forward run.
Needs ``git apply bench/patches/pardiso_on_caller.patch`` (the switch
``linsolve._PARDISO_ON_CALLER``).

    python bench/pardiso_caller_thread.py [--steps 100]

Measured 2026-12-08 (CPU reference 1.4-1.6 s): on the caller's thread best 3.034 s, median
3.170 s; on the host thread 3.092 s, 3.200 s (forward run 0.534 s best: 5.68x against
5.79x); the derivatives identical. Within the noise: not kept.
"""
from __future__ import annotations

import argparse
import time

import jax
import numpy as np

from dejax import bench, linsolve


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=100)
    a = ap.parse_args()
    if not hasattr(linsolve, "_PARDISO_ON_CALLER"):
        raise SystemExit("apply bench/patches/pardiso_on_caller.patch first")
    f, theta = bench.g1_objective(a.steps, bench.TUBE_DT)
    g = jax.jit(jax.jacfwd(f)).lower(theta).compile()
    fw = jax.jit(f).lower(theta).compile()
    jax.block_until_ready(g(theta))
    jax.block_until_ready(fw(theta))
    times, outs = {True: [], False: [], "forward": []}, {}
    for _ in range(6):
        for flag in (True, False):
            linsolve._PARDISO_ON_CALLER = flag
            tic = time.perf_counter()
            outs[flag] = np.asarray(g(theta))
            times[flag].append(time.perf_counter() - tic)
        tic = time.perf_counter()
        jax.block_until_ready(fw(theta))
        times["forward"].append(time.perf_counter() - tic)
    for key, name in ((True, "caller's thread"), (False, "host thread"), ("forward", "forward run")):
        v = times[key]
        print(f"{name:16s} best {min(v):.3f} s, median {np.median(v):.3f} s")
    print(f"G1 / forward (best): caller's thread {min(times[True]) / min(times['forward']):.2f}, "
          f"host thread {min(times[False]) / min(times['forward']):.2f}; largest difference "
          f"{np.max(np.abs(outs[True] - outs[False])):.1e}")


if __name__ == "__main__":
    main()
