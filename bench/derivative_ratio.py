"""G1's objective (tube 4x8x1, R1's loading) at N steps: its forward run, ``jax.jacfwd`` (G1)
and ``jax.grad`` (G1R), each compiled once and timed as the best of three calls, with the
ratios to the forward run: a quick check of a G1 lever (run the old and new code in
separate processes, alternated; ``dejax bench --cases R1,G1`` gives the bench's own figure).

    python bench/derivative_ratio.py [--steps 60] [--modes fwd,jacfwd,grad]
"""
from __future__ import annotations

import argparse
import time

import jax
import numpy as np

from dejax import bench


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=60)
    ap.add_argument("--modes", default="fwd,jacfwd")
    a = ap.parse_args()
    f, theta = bench.g1_objective(a.steps, bench.TUBE_DT)
    best = {}
    for mode in a.modes.split(","):
        g = jax.jit({"grad": jax.grad, "jacfwd": jax.jacfwd, "fwd": lambda h: h}[mode](f))
        tic = time.perf_counter()
        c = g.lower(theta).compile()
        compile_s = time.perf_counter() - tic
        ts = []
        for _ in range(3):
            tic = time.perf_counter()
            out = jax.block_until_ready(c(theta))
            ts.append(time.perf_counter() - tic)
        best[mode] = min(ts)
        print(f"{mode}: compile {compile_s:.1f} s, best {min(ts):.3f} s ({', '.join(f'{t:.3f}' for t in ts)}), "
              f"first component {np.ravel(out)[0]:.12e}", flush=True)
    if "fwd" in best:
        for mode, t in best.items():
            if mode != "fwd":
                print(f"{mode} / fwd: {t / best['fwd']:.2f}")


if __name__ == "__main__":
    main()
