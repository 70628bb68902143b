"""The viscous units' share of the consistent tangent in closed form against forward lanes
through the whole point law, alternated in one process (issue 10, point 3: "a cheaper
consistent tangent ... closed forms"). Tried on 2026-12-06 and not kept: the closed form
lives in a patch.

    git apply bench/patches/closed_form_unit_tangent.patch
    python bench/unit_tangent.py [--points 864,25920] [--g1-steps 100] [--n1] [--reps 3]
    git apply -R bench/patches/closed_form_unit_tangent.patch

The patch writes each unit's stress, flow update and their derivatives along F as a
handful of 3 x 3 tensors and scalars (the chain rule through the rate equation's implicit
function theorem written out; the scalar derivatives still by jax.grad) and sums D as outer
products; the equilibrium branch keeps its forward lanes. Its test checks it against
jax.jacfwd of the primal laws to 1e-13 (backward Euler and BDF2, both forms, a material with
every extension), and a 0.1 % error in one term fails it.

1. The mixed law's tangent at random states of Model IV (``mixed_tangent_and_update``
   without dCv/dF, which a forward run does not use), batched over points: median ms.
2. G1 (``jax.jacfwd`` of R1's last-cycle mean x_P, 12 parameters, the first ``--g1-steps``
   steps), each variant compiled once, then run alternately with the forward run: best of
   ``--reps`` and the derivatives' largest relative difference.
3. With ``--n1``: N1 (``bench.case_N1``: one Newton iteration of R2) with each variant, two
   rounds alternated.

Measured (2026-12-06, 2 cores, CPU reference 1.15 s): the tangent at 864 points 3.5 -> 2.3
ms, at 25,920 points 186-190 -> 124-126 ms (D equal to 6e-16); G1 at 100 steps 3.84 s
(6.26x the forward run) against 3.90 s (6.35x), derivatives equal to 2.5e-15; N1 0.688/0.683 s
against 0.683/0.648 s (FElupe 0.34-0.37 s). The per-point law is ~10 % of a G1 step and the
chunked tangent ~0.1 s of N1, so a third off it moves neither target, while it departs from
the design's "autodiff derives the tangents" and must follow every change of the free
energy by hand.
"""
from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)

from dejax import bench, scenarios  # noqa: E402
from dejax import integrate as it  # noqa: E402
from dejax import material as mat  # noqa: E402
from dejax import model as mdl  # noqa: E402
from profile_step import timed  # noqa: E402


@jax.jit
def lanes_tangent(F, E, Cv_old, dt, m, wmax=0.0):
    """``stress_tangent_update_and_flow_tangent`` by forward lanes through the whole law."""
    (P, Cv_new), (dP, dCv) = mat._tangent_lanes(lambda F_: mat.stress_and_update(F_, E, Cv_old, dt, m, wmax), F)
    return P, dP.reshape(3, 3, 3, 3), Cv_new, dCv.reshape((3, 3) + dCv.shape[1:])


@jax.jit
def lanes_mixed_tangent(F, E, Cv_old, dt, p, m, wmax=0.0):
    """``mixed_tangent_and_update`` by forward lanes through the whole law."""
    f = lambda F_, p_: mat.mixed_stress_and_update(F_, E, Cv_old, dt, p_, m, wmax)  # noqa: E731
    (P, r_p, Cv_new), (dP, dr, dCv) = mat._tangent_lanes(f, F, (p, jnp.ones((1,) + jnp.shape(p))))
    return P, r_p, dP[:9].reshape(3, 3, 3, 3), dP[9], dr[9], Cv_new, dCv[:9].reshape((3, 3) + dCv.shape[1:])


VARIANTS = {"lanes": (lanes_tangent, lanes_mixed_tangent),
            "closed": (mat.stress_tangent_update_and_flow_tangent, mat.mixed_tangent_and_update)}


def use(variant):
    """Point the model's element system at a variant (the next trace uses it)."""
    mdl.stress_tangent_update_and_flow_tangent, mdl.mixed_tangent_and_update = VARIANTS[variant]
    jax.clear_caches()


def points(n, reps):
    m = scenarios.rolled("IV", 30.0, 50e3, shape=(4, 8, 1)).model.material
    rng = np.random.default_rng(0)
    F = jnp.asarray(np.eye(3) + 0.1 * rng.standard_normal((n, 3, 3)))
    E = jnp.asarray(1e6 * rng.standard_normal((n, 3)))
    Cv = np.eye(3) + 0.02 * rng.standard_normal((n, m.n_units, 3, 3))
    Cv = jnp.asarray(0.5 * (Cv + np.swapaxes(Cv, -1, -2)))
    p = jnp.asarray(1e3 * rng.standard_normal(n))
    fs = {k: jax.jit(jax.vmap(lambda F, E, Cv, p, g=g[1]: g(F, E, Cv, 1e-4, p, m)[:5])) for k, g in VARIANTS.items()}
    D = {k: np.asarray(f(F, E, Cv, p)[2]) for k, f in fs.items()}
    diff = np.max(np.abs(D["closed"] - D["lanes"])) / np.max(np.abs(D["lanes"]))
    for r in range(reps):
        print(f"{n} points, round {r}: " + ", ".join(f"{k} {timed(f, F, E, Cv, p, repeat=15)[0]:.2f} ms" for k, f in fs.items())
              + f"; D differs by {diff:.1e}", flush=True)


def g1(steps, reps):
    f, theta = bench.g1_objective(steps, bench.TUBE_DT)
    programs = {"forward": jax.jit(lambda t: f(t, it.StepControl())).lower(theta).compile()}
    for k in VARIANTS:
        use(k)
        programs[k] = jax.jit(jax.jacfwd(f)).lower(theta).compile()
    use("closed")
    grads = {k: np.asarray(c(theta)) for k, c in programs.items()}
    times = {k: [] for k in programs}
    for _ in range(reps):
        for k, c in programs.items():
            tic = time.perf_counter()
            jax.block_until_ready(c(theta))
            times[k].append(time.perf_counter() - tic)
    fwd = min(times["forward"])
    print(f"G1, {steps} steps: forward {fwd:.3f} s; " + ", ".join(
        f"{k} {min(times[k]):.3f} s ({min(times[k]) / fwd:.2f}x)" for k in VARIANTS)
        + f"; derivatives differ by {np.max(np.abs(grads['closed'] - grads['lanes'])) / np.max(np.abs(grads['lanes'])):.1e}")


def n1(rounds=2):
    for r in range(rounds):
        for k in VARIANTS:
            use(k)
            row = bench.case_N1()
            felupe = row["felupe"]["seconds_per_iteration"] if row["felupe"] else float("nan")
            print(f"N1 round {r} {k:<7} {row['run_s']:.3f} s (without the factorization "
                  f"{row['without_factorization_s']:.3f} s; FElupe {felupe:.3f} s)", flush=True)
    use("closed")


def main():
    if not hasattr(mat, "_UnitTangent"):  # without it both variants would be the lanes
        raise SystemExit("apply the closed form first: git apply bench/patches/closed_form_unit_tangent.patch")
    ap = argparse.ArgumentParser()
    ap.add_argument("--points", default="864,25920")
    ap.add_argument("--g1-steps", type=int, default=100, help="0: skip G1")
    ap.add_argument("--n1", action="store_true")
    ap.add_argument("--reps", type=int, default=3)
    a = ap.parse_args()
    for n in filter(None, a.points.split(",")):
        points(int(n), 2)
    if a.g1_steps:
        g1(a.g1_steps, a.reps)
    if a.n1:
        n1()


if __name__ == "__main__":
    main()
