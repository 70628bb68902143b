"""The consistent tangent's lane layout, timed in one process (issue 10: cost per step).

    python bench/tangent_layout.py [--mesh 4x8x1] [--repeat 7]

Times the element tangent (the mixed law's forward lanes at every Gauss point and the
stiffness product) of the rolled tube (Model IV) two ways, alternated in one process: A,
``jax.jacfwd`` (its Jacobian's lanes moved last, D[i, j, k, l], a strided copy of every
per-point Jacobian), as dejax did before 2026-12-05; B, ``material.mixed_tangent_and_update``
(the lanes kept first, D[k, l, i, j]). Prints the largest difference of the element
matrices (relative) and the best and median time of each.

Measured (2026-12-05, 2 cores): 4x8x1 7.33 -> 5.28 ms, 8x12x2 (unchunked) 87.6 -> 74.8 ms.
"""
from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp

from dejax import element as el
from dejax import integrate as it
from dejax import material as M
from dejax import model as mdl
from dejax import scenarios


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--mesh", default="4x8x1")
    ap.add_argument("--repeat", type=int, default=7)
    a = ap.parse_args()
    p = scenarios.rolled("IV", 30.0, 50e3, shape=tuple(int(x) for x in a.mesh.split("x")))
    m, load, dt = p.model, p.loading, 1.0 / 1500.0
    state = it.initial_state(m, load, 0.0)
    F = mdl.deformation_gradients(m, state.q) + 0.01  # off the reference state
    E = mdl.nominal_field(m, load.phi(dt))
    flow, pg, w = mdl.flow_step(m, state, dt), mdl.pressure_at_points(m, state.p), mdl.initial_history(m)
    G = el.gradients_from_factors(m.dNdxi, m.Jinv, m.dXdxi)
    axes = (0, 0, 0, None, 0, None, 0)

    def lanes_last(F):
        def law(F, E, Cv_old, dt, p, mat, wmax):
            def f(F_, p_):
                r = M.mixed_stress_and_update(F_, E, Cv_old, dt, p_, mat, wmax)
                return r, r

            ((D, _), _, (Cv_F, _)), _ = jax.jacfwd(f, argnums=(0, 1), has_aux=True)(F, p)
            return D, Cv_F

        D, Cv_F = mdl.over_points(law, axes)(F, E, flow, dt, pg, m.material, w)
        return jnp.einsum("eg,egaj,egijkl,egbl->eaibk", m.dV, G, D, G), Cv_F

    def lanes_first(F):
        def law(*args):
            out = M.mixed_tangent_and_update(*args)
            return out[2], out[6]

        D, Cv_F = mdl.over_points(law, axes)(F, E, flow, dt, pg, m.material, w)
        return jnp.einsum("eg,egaj,egklij,egbl->eaibk", m.dV, G, D, G), Cv_F

    fs = {"A jacfwd, lanes last": jax.jit(lanes_last), "B lanes first": jax.jit(lanes_first)}
    ka, kb = (f(F)[0] for f in fs.values())
    print(f"mesh {a.mesh}: element matrices differ by {float(jnp.abs(ka - kb).max() / jnp.abs(ka).max()):.1e} "
          "(relative)")
    times = {k: [] for k in fs}
    for _ in range(a.repeat):
        for k, f in fs.items():
            tic = time.perf_counter()
            for _ in range(10):
                jax.block_until_ready(f(F))
            times[k].append((time.perf_counter() - tic) / 10 * 1e3)
    for k, v in times.items():
        v = sorted(v)
        print(f"{k:<22} best {v[0]:.2f} ms, median {v[len(v) // 2]:.2f} ms")


if __name__ == "__main__":
    main()
