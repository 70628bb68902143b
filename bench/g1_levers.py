"""G1's levers measured against each other in one process (issue 10: G1 <= 4x R1).

    python bench/g1_levers.py [--steps 100] [--reps 3] [--variants exact,no-ynn,sharded]

G1 (``dejax bench``: ``jax.jacfwd`` of R1's last-cycle mean x_P with respect to Model IV's
nine parameters and h, L, r; tube 4x8x1, dt = 1/1500 s, Newton to 1e-2) over its first
``--steps`` steps, each variant compiled once and run in turn with R1's forward run of
the same steps (``--reps`` rounds, min), so that the machine's drift hits every variant
alike. Printed per variant: seconds, the ratio to the forward run, and the largest
difference of its twelve derivatives from the exact variant's, relative to the largest.

Variants:
  exact    what dejax does: each step's tangent solved with the exact iteration matrix
           at the converged state (built and factorized again for the tangent).
  no-ynn   the same program compiled without XLA:CPU's YNNPACK matrix-product fusions
           (the profile lists the 12-lane 3 x 3 products under them).
  sharded  the twelve lanes split over two emulated CPU devices (``shard_map``, six lanes
           and one forward run each; the script sets the device count before JAX starts).
  refine[:TOL]  only with ``git apply bench/patches/g1_tangent_refine.patch``: the tangent
           without the exact matrix, by corrections with the factorization Newton ended
           with (stale), each checked against the exact linearized residual (a jvp along
           the lanes), to a correction below TOL (default 1e-6) of the tangent; prints the
           sweeps per step and lane. Revert the patch afterwards (``git checkout
           dejax/integrate.py``).
  stale[-cv]  only with ``git apply bench/patches/g1_stale_tangent.patch``: the cheapest
           tangent there is: the predictor's tangent corrected once by the stale
           factorization against the exact linearized residual (one jvp along the lanes per
           step, no exact matrix, no check); ``stale-cv`` also moves Cv's tangent along the
           correction (a jvp of the flow update). A lower bound of the lanes' cost, not a
           derivative (it diverges: see docs/performance.md).
  lanes:K  ``jax.jacfwd`` with respect to the first K of the twelve parameters only (the
           others held): what the lanes cost one by one (``lanes:1`` = one lane with every
           lane-independent cost of the exact derivative); its derivatives are compared with
           the exact variant's first K.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

if "sharded" in " ".join(sys.argv):  # before JAX starts
    os.environ["XLA_FLAGS"] = os.environ.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=2"
    os.environ.setdefault("PJRT_NPROC", "4")  # the pool larger than the device count (dejax.sweep)

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from dejax import bench  # noqa: E402
from dejax import integrate as it  # noqa: E402


def compiled_variant(name, f, theta):
    """(compiled program, its argument) of a variant."""
    if name in ("exact", "no-ynn"):
        opts = {"xla_cpu_experimental_ynn_fusion_type": ""} if name == "no-ynn" else None
        return jax.jit(jax.jacfwd(f)).lower(theta).compile(compiler_options=opts), theta
    if name == "sharded":
        from jax import shard_map
        from jax.sharding import Mesh, PartitionSpec as P

        basis = jnp.eye(theta.size)
        lanes = lambda B: jax.vmap(lambda v: jax.jvp(f, (theta,), (v,))[1])(B)  # noqa: E731
        mesh = Mesh(np.array(jax.devices()[:2]), ("lane",))
        return jax.jit(shard_map(lanes, mesh=mesh, in_specs=P("lane"), out_specs=P("lane"))).lower(basis).compile(), basis
    if name.startswith("lanes:"):
        k = int(name.partition(":")[2])
        return jax.jit(jax.jacfwd(lambda x: f(theta.at[:k].set(x)))).lower(theta[:k]).compile(), theta[:k]
    if name.startswith("refine") or name.startswith("stale"):
        if name.startswith("refine") and not hasattr(it, "_refined_tangent"):
            raise SystemExit("variant refine needs `git apply bench/patches/g1_tangent_refine.patch`")
        if name.startswith("stale") and "SymbolicZero" not in vars(it):
            raise SystemExit("variant stale needs `git apply bench/patches/g1_stale_tangent.patch`")
        os.environ["DEJAX_TANGENT"] = name  # read while tracing
        jax.clear_caches()  # the inner jits' traces of the other variants
        try:
            return jax.jit(jax.jacfwd(f)).lower(theta).compile(), theta
        finally:
            del os.environ["DEJAX_TANGENT"]
            jax.clear_caches()
    raise SystemExit(f"unknown variant {name!r}")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--steps", type=int, default=100)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--variants", default="exact,no-ynn")
    a = ap.parse_args()
    names = ["exact"] + [v for v in a.variants.split(",") if v != "exact"]
    f, theta = bench.g1_objective(a.steps, bench.TUBE_DT)
    programs = {"forward": (jax.jit(lambda t: f(t, it.StepControl())).lower(theta).compile(), theta)}
    programs.update({v: compiled_variant(v, f, theta) for v in names})
    grads = {}
    for k, (c, x) in programs.items():
        grads[k] = np.asarray(jax.block_until_ready(c(x)))
        jax.effects_barrier()  # the sweep counts' callbacks
        if k.startswith("refine") and hasattr(it, "REFINE_SWEEPS"):
            s = np.concatenate([np.ravel(v) for v in it.REFINE_SWEEPS])
            print(f"{k}: sweeps per step and lane: mean {s.mean():.2f}, max {s.max()}", flush=True)
            it.REFINE_SWEEPS.clear()
    times = {k: [] for k in programs}
    for _ in range(a.reps):
        for k, (c, x) in programs.items():
            tic = time.perf_counter()
            jax.block_until_ready(c(x))
            times[k].append(time.perf_counter() - tic)
    fwd = min(times["forward"])
    print(f"forward ({a.steps} steps of R1): {fwd:.3f} s")
    ref = grads["exact"]
    for k in names:
        t = min(times[k])
        diff = np.max(np.abs(grads[k] - ref[: grads[k].size])) / np.max(np.abs(ref[: grads[k].size]))
        print(f"{k:<14} {t:7.3f} s  {t / fwd:5.2f}x forward  derivatives vs exact {diff:.1e}", flush=True)


if __name__ == "__main__":
    main()
