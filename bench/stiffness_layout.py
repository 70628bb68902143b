"""The stiffness, mass and condensation of R2's 60 chunks of 16 elements (random data of
the real shapes) written in the (96, 96) layout the code uses, [e, a, i, b, k], against the
layout the stiffness product emits, [e, i, k, a, b] (no transposing copy); one process,
alternated. With ``bench/patches/stiffness_by_component.patch`` applied (the Newton
matrices stored by component, the assembly's gathers remapped), ``python
bench/stiffness_by_component_ab.py [rounds]`` times N1's step both ways. Tried 2026-12-08
and not kept (docs/performance.md).

    python bench/stiffness_layout.py
"""
import time, jax, jax.numpy as jnp, numpy as np
jax.config.update("jax_enable_x64", True)
import dejax  # XLA flags
C, E, NP = 60, 16, 4
r = np.random.default_rng(0)
dV = jnp.asarray(r.random((C, E, 27)))
G = jnp.asarray(r.standard_normal((C, E, 27, 32, 3)))
D = jnp.asarray(r.standard_normal((C, E, 27, 3, 3, 3, 3)))
M = jnp.asarray(r.standard_normal((C, E, 32, 32)))
kup = jnp.asarray(r.standard_normal((C, E, NP, 96)))
kpp = jnp.asarray(np.eye(NP) * 2.0 + 0.1 * r.standard_normal((C, E, NP, NP)))
c = 3.0
def cur(a):
    dV, G, D, M, kup, kpp = a
    K = jnp.einsum("eg,egaj,egklij,egbl->eaibk", dV, G, D, G).reshape(E, 96, 96)
    K = K + c * jnp.einsum("eab,ij->eaibj", M, jnp.eye(3)).reshape(E, 96, 96)
    return K - jnp.einsum("eka,ekb->eab", kup, jnp.linalg.solve(kpp, kup))
def nat(a):
    dV, G, D, M, kup, kpp = a
    K = jnp.einsum("eg,egaj,egklij,egbl->eikab", dV, G, D, G)
    K = K + c * jnp.einsum("eab,ik->eikab", M, jnp.eye(3))
    ku = kup.reshape(E, NP, 32, 3)
    X = jnp.linalg.solve(kpp, kup).reshape(E, NP, 32, 3)
    return K - jnp.einsum("epai,epbk->eikab", ku, X)
f_cur = jax.jit(lambda *a: jax.lax.map(cur, a))
f_nat = jax.jit(lambda *a: jax.lax.map(nat, a))
args = (dV, G, D, M, kup, kpp)
a1 = f_cur(*args); a2 = f_nat(*args)
np.testing.assert_allclose(np.asarray(a1).reshape(C, E, 32, 3, 32, 3).transpose(0, 1, 3, 5, 2, 4), np.asarray(a2), rtol=1e-10, atol=1e-9)
res = {"cur": [], "nat": []}
for _ in range(15):
    for k, f in (("cur", f_cur), ("nat", f_nat)):
        tic = time.perf_counter(); jax.block_until_ready(f(*args)); res[k].append(time.perf_counter() - tic)
for k, v in res.items(): print(k, f"best {1e3*min(v):.1f} ms median {1e3*np.median(v):.1f} ms")
