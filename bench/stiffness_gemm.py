"""The element stiffness K = sum_p dV G^T D G two ways, on random symmetric tangents D:
the per-point einsum of ``model._element_system_of`` (G from its factors), and one matrix
product with a matrix every element shares, K^ = H @ D~ (H[(a, b), (p, m, n)] = dNdxi_p[a, m]
dNdxi_p[b, n], 1024 x 243; D~ the tangent pulled back by Jinv, 243 x 9 per element),
followed by the slot mixing A^T K^ A of each element.

    python bench/stiffness_gemm.py [--mesh 12x20x4] [--chunk 16]

``--chunk`` evaluates the elements that many at a time (``lax.map``), as
``model.over_element_chunks`` does on meshes of 128 elements or more. Prints the largest
difference between the two (relative) and the best and median of 10 calls, three rounds.

Measured 2026-12-08 (2 cores, CPU reference 1.4-1.9 s): R2's mesh in chunks of 16, einsum
93-99 ms, matrix product 138-145 ms; the tube 4x8x1 unchunked, 3.1-3.9 ms both; equal to
1.8e-15. The shared product does 1.4x the einsum's flops (the einsum contracts G's factors
one at a time) and its transposes and slot mixing cost more than its faster kernel saves.
Not kept.
"""
from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np

from dejax import element as el
from dejax import scenarios


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--mesh", default="12x20x4")
    ap.add_argument("--chunk", type=int, default=16)
    a = ap.parse_args()
    m = scenarios.rolled("IV", 30.0, 50e3, shape=tuple(int(s) for s in a.mesh.split("x"))).model
    dN = m.dNdxi
    n_el, n_gp = m.dV.shape
    rng = np.random.default_rng(0)
    R = rng.standard_normal((n_el, n_gp, 9, 9))
    D = jnp.asarray((R + R.transpose(0, 1, 3, 2)).reshape(n_el, n_gp, 3, 3, 3, 3))  # D[k, l, i, j]
    H = jnp.einsum("gam,gbn->abgmn", dN, dN).reshape(1024, -1)

    def einsum_form(dV, Jinv, dXdxi, D):
        G = el.gradients_from_factors(dN, Jinv, dXdxi)
        return jnp.einsum("eg,egaj,egklij,egbl->eaibk", dV, G, D, G).reshape(-1, 96, 96)

    def product_form(dV, Jinv, dXdxi, D):
        ne = D.shape[0]
        Dt = jnp.einsum("eg,egmj,egnl,egklij->gmneik", dV, Jinv, Jinv, D).reshape(-1, ne * 9)
        Kh = jnp.transpose((H @ Dt).reshape(32, 32, ne, 3, 3), (2, 0, 3, 1, 4))  # e, a, i, b, k
        K1 = el.cartesian_slots(Kh.reshape(ne, 32, 3 * 96), dXdxi)  # rows to Cartesian slots
        K1 = jnp.transpose(K1.reshape(ne, 96, 32, 3), (0, 2, 3, 1)).reshape(ne, 32, 3 * 96)
        K2 = el.cartesian_slots(K1, dXdxi).reshape(ne, 32, 3, 96)  # columns, now leading
        return jnp.transpose(K2, (0, 3, 1, 2)).reshape(ne, 96, 96)

    def chunked(f):
        if not a.chunk:
            return f
        k = n_el // a.chunk
        return lambda *x: jax.lax.map(lambda y: f(*y), tuple(v.reshape((k, a.chunk) + v.shape[1:]) for v in x)
                                      ).reshape(-1, 96, 96)

    args = (m.dV, m.Jinv, m.dXdxi, D)
    fa, fb = jax.jit(chunked(einsum_form)), jax.jit(chunked(product_form))
    Ka, Kb = fa(*args), fb(*args)
    print(f"mesh {a.mesh}, {n_el} elements, chunk {a.chunk}: largest difference "
          f"{float(jnp.max(jnp.abs(Ka - Kb)) / jnp.max(jnp.abs(Ka))):.1e} (relative)")
    for _ in range(3):
        for name, f in (("einsum", fa), ("shared product", fb)):
            ts = []
            for _ in range(10):
                tic = time.perf_counter()
                jax.block_until_ready(f(*args))
                ts.append(time.perf_counter() - tic)
            print(f"  {name:15s} {1e3 * min(ts):7.2f} ms (median {1e3 * np.median(ts):.2f})")


if __name__ == "__main__":
    main()
