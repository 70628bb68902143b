"""What JAX's tracing of G1R's program (``jax.grad`` of G1's objective, tube 4x8x1) handles:
the traced program's equations by primitive (nested programs included) and the time of
``jax.jit(...).trace`` in a fresh process (the Python third of the bench's compile time;
alternate runs of two versions to compare them).

    python bench/trace_size.py [--mode grad|jacfwd|forward] [--top 15]

Measured 2026-12-08 (CPU reference 1.4-1.9 s): G1R 19,233 equations (mul 4,238,
broadcast_in_dim 3,690, slice 1,539, squeeze 1,499, sub 1,116, add_any 998), traced in
5.7-7.2 s. With the adjugate's nine entries taken by one ``lax.split`` and joined by one
concatenate instead of row and entry indexing and a stack (``git apply
bench/patches/adj3_split.patch``): 16,800 equations (slice 399, squeeze 0), traced in
5.6-7.1 s, alternated with the code as it is in separate processes: the equations saved are
the cheap ones; the time is in JAX's linearization and partial evaluation of the rest.
"""
from __future__ import annotations

import argparse
import collections
import time

import jax
from jax.extend import core as jcore

from dejax import bench


def count(jaxpr, counter):
    for eqn in jaxpr.eqns:
        counter[eqn.primitive.name] += 1
        for p in eqn.params.values():
            for sub in p if isinstance(p, (list, tuple)) else [p]:
                if isinstance(sub, jcore.ClosedJaxpr):
                    count(sub.jaxpr, counter)
                elif isinstance(sub, jcore.Jaxpr):
                    count(sub, counter)
    return counter


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--mode", default="grad", choices=("grad", "jacfwd", "forward"))
    ap.add_argument("--top", type=int, default=15)
    a = ap.parse_args()
    f, theta = bench.g1_objective(10, bench.TUBE_DT)
    g = {"grad": jax.grad, "jacfwd": jax.jacfwd, "forward": lambda h: h}[a.mode](f)
    tic = time.perf_counter()
    traced = jax.jit(g).trace(theta)
    print(f"{a.mode}: traced in {time.perf_counter() - tic:.2f} s")
    c = count(traced.jaxpr.jaxpr, collections.Counter())
    print(f"{sum(c.values())} equations")
    for name, k in c.most_common(a.top):
        print(f"{k:8d}  {name}")


if __name__ == "__main__":
    main()
