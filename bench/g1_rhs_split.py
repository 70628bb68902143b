"""G1's right-hand side without its F chain: the 12-lane jvp of the mixed point law (Model
IV, BDF2 flow step) at 864 random points (the tube 4x8x1's count), with every input
carrying a tangent (F, E, the flow step, the material: what each step's implicit
derivative differentiates now) against F closed over (its part would then come from the
exact tangent's dP/dF, already computed for the iteration matrix), F's lanes alone, the
primal law and the consistent tangent (9 F lanes and one along p); min ms of 30 calls,
three rounds.

    python bench/g1_rhs_split.py

Measured 2026-12-07 (2 cores, CPU reference ~2.1 s): all inputs 6.29-6.47 ms, F closed
4.84-6.33, F alone 4.73-4.92, primal 0.94-1.06, tangent 3.60-5.07 ms. Closing F over saves
at most ~1.5 ms of the law's lanes per step (G1's step is ~22 ms on a fast machine, ~69 ms
here): not built.
"""
import time

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402

from dejax import material as mat  # noqa: E402
from dejax import scenarios  # noqa: E402

M = scenarios.rolled_material("IV")
N, LANES = 864, 12
rng = np.random.default_rng(0)
F = jnp.asarray(np.eye(3) + 0.05 * rng.standard_normal((N, 3, 3)))
E = jnp.asarray(1e6 * rng.standard_normal((N, 3)))
Cv = np.eye(3) + 0.02 * rng.standard_normal((N, M.n_units, 3, 3))
Cv = jnp.asarray(0.5 * (Cv + np.swapaxes(Cv, -1, -2)))
flow = jax.vmap(lambda a, b: mat.bdf2_flow_step(a, b, 6.7e-4, 6.7e-4))(Cv, Cv + 1e-3)
p = jnp.asarray(1e3 * rng.standard_normal(N))


def lanes_of(x):
    return jnp.asarray(1e-3 * rng.standard_normal((LANES,) + jnp.shape(x)))


tF, tE, tflow = lanes_of(F), lanes_of(E), jax.tree.map(lanes_of, flow)
tmat = jax.tree.map(lambda x: lanes_of(x) if jnp.issubdtype(jnp.asarray(x).dtype, jnp.floating) else None, M)


def law(F, E, flow, m):
    return jax.vmap(lambda F, E, fl, p: mat.mixed_stress_and_update(F, E, fl, 0.0, p, m))(F, E, flow, p)


def all_inputs(F, E, flow, m):
    return jax.vmap(lambda a, b, c, d: jax.jvp(law, (F, E, flow, m), (a, b, c, d))[1])(tF, tE, tflow, tmat)


def F_closed(F, E, flow, m):
    return jax.vmap(lambda b, c, d: jax.jvp(lambda E_, fl_, m_: law(F, E_, fl_, m_), (E, flow, m), (b, c, d))[1])(
        tE, tflow, tmat)


def F_alone(F, E, flow, m):
    return jax.vmap(lambda a: jax.jvp(lambda F_: law(F_, E, flow, m), (F,), (a,))[1])(tF)


def tangent(F, E, flow, m):
    return jax.vmap(lambda F, E, fl, p: mat.mixed_tangent_and_update(F, E, fl, 0.0, p, m))(F, E, flow, p)


def timed(f):
    jax.block_until_ready(f(F, E, flow, M))
    ts = []
    for _ in range(30):
        t = time.perf_counter()
        jax.block_until_ready(f(F, E, flow, M))
        ts.append(time.perf_counter() - t)
    return 1e3 * min(ts)


cases = {name: jax.jit(f) for name, f in
         (("all inputs", all_inputs), ("F closed", F_closed), ("F alone", F_alone), ("primal", law),
          ("tangent", tangent))}
for _ in range(3):
    print("  ".join(f"{k} {timed(f):.2f} ms" for k, f in cases.items()), flush=True)
