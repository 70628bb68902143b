"""Where the consistent tangent of Model IV goes at one Gauss point, batched over 25,920 random
points (the size of the paper's tube 12x20x4), each piece jitted on its own: the primal stress
and flow update, the flow update alone, its nine F lanes (dCv/dF), P at fixed Cv, its nine lanes
(dP/dF at fixed Cv), the equilibrium branch's lanes and the full tangent (median ms, two rounds).

    python bench/tangent_pieces.py
"""
import time, jax, jax.numpy as jnp, numpy as np
jax.config.update("jax_enable_x64", True)
from dejax import material as mat, scenarios
M = scenarios.rolled("IV", 30.0, 50e3, shape=(4, 8, 1)).model.material
N = 25920
rng = np.random.default_rng(0)
F = jnp.asarray(np.eye(3) + 0.1 * rng.standard_normal((N, 3, 3)))
E = jnp.asarray(1e6 * rng.standard_normal((N, 3)))
Cv = np.eye(3) + 0.02 * rng.standard_normal((N, M.n_units, 3, 3)); Cv = jnp.asarray(0.5 * (Cv + np.swapaxes(Cv, -1, -2)))
dt = 1e-4
dirs = jnp.asarray(np.eye(9).reshape(9, 3, 3))
def lanes(f, F):
    return jax.vmap(lambda t: jax.jvp(f, (F,), (t,)), out_axes=(None, 0))(dirs)
V = lambda g: jax.jit(jax.vmap(g))
cases = {
 "primal stress+update": V(lambda F, E, Cv: mat.stress_and_update(F, E, Cv, dt, M)),
 "viscous update only": V(lambda F, E, Cv: mat.update_all_units(F, Cv, dt, M)),
 "dCv/dF (9 lanes of update)": V(lambda F, E, Cv: lanes(lambda F_: mat.update_all_units(F_, Cv, dt, M), F)),
 "P at fixed Cv": V(lambda F, E, Cv: jax.grad(mat.free_energy)(F, E, Cv, M)),
 "dP/dF at fixed Cv (9 lanes)": V(lambda F, E, Cv: lanes(lambda F_: jax.grad(mat.free_energy)(F_, E, Cv, M), F)),
 "equilibrium only dP/dF": V(lambda F, E, Cv: lanes(lambda F_: jax.grad(mat.equilibrium_energy)(F_, E, M), F)),
 "full tangent": V(lambda F, E, Cv: mat.stress_tangent_update_and_flow_tangent(F, E, Cv, dt, M)),
}
def timed(f, *a):
    jax.block_until_ready(f(*a)); ts = []
    for _ in range(10):
        t = time.perf_counter(); jax.block_until_ready(f(*a)); ts.append(time.perf_counter() - t)
    return 1e3 * np.median(ts)
for r in range(2):
    for k, f in cases.items():
        print(f"{k:32s} {timed(f, F, E, Cv):8.2f} ms")
