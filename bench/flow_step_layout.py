"""The BDF2 flow step (``material.bdf2_flow_step`` vmapped over R2's 25,920 points x 4 units,
as ``model.flow_step`` runs it) against the same step with the components leading (Cv and
Cv_prev moved to (3, 3, ...) once, everything elementwise on contiguous rows, moved back),
and ``inv3`` vmapped against its components-leading form; alternated in one process, best
and median of 30 calls. Tried 2026-12-08 and not kept (docs/performance.md).

    python bench/flow_step_layout.py
"""
import time

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)
from dejax import material as mat  # noqa: E402
from dejax import tensor as tn  # noqa: E402

N, H = 25920, 6.6e-4


def sym(key):
    A = jnp.eye(3) + 0.01 * jax.random.normal(jax.random.PRNGKey(key), (N, 4, 3, 3))
    return 0.5 * (A + jnp.swapaxes(A, -1, -2))


def adjugate(B):
    (a, b, c), (d, e, f), (g, h, i) = B[0], B[1], B[2]
    return jnp.stack([jnp.stack([e * i - f * h, c * h - b * i, b * f - c * e]),
                      jnp.stack([f * g - d * i, a * i - c * g, c * d - a * f]),
                      jnp.stack([d * h - e * g, b * g - a * h, a * e - b * d])])


def det(M):
    return (M[0, 0] * (M[1, 1] * M[2, 2] - M[1, 2] * M[2, 1]) - M[0, 1] * (M[1, 0] * M[2, 2] - M[1, 2] * M[2, 0])
            + M[0, 2] * (M[1, 0] * M[2, 1] - M[1, 1] * M[2, 0]))


def inv_leading(A):
    T = jnp.moveaxis(A, (-2, -1), (0, 1))
    adj = adjugate(T)
    return jnp.moveaxis(adj / det(T), (0, 1), (-2, -1))


def bdf2_leading(Cv, Cvp, h, h_prev):
    """``bdf2_flow_step``'s fields (base, base_inv, det_base, det_old, dt), components leading."""
    T, Tp = jnp.moveaxis(Cv, (-2, -1), (0, 1)), jnp.moveaxis(Cvp, (-2, -1), (0, 1))
    det_old = det(T)
    usable = (h_prev > 0) & (h <= 2.0 * h_prev)
    w = h / jnp.where(usable, h_prev, h)
    b, c = w * w / (1.0 + 2.0 * w), (1.0 + w) / (1.0 + 2.0 * w)
    B = T + b * (T - Tp)
    m1 = B[0, 0] / T[0, 0]
    m2 = (B[0, 0] * B[1, 1] - B[0, 1] * B[1, 0]) / (T[0, 0] * T[1, 1] - T[0, 1] * T[1, 0])
    det_base = det(B)
    ok = usable & (m1 > 0.25) & (m2 > 0.25 ** 2) & (det_base / det_old > 0.25 ** 3)
    B = jnp.where(ok, B, T)
    det_base = jnp.where(ok, det_base, det_old)
    back = lambda X: jnp.moveaxis(X, (0, 1), (-2, -1))  # noqa: E731
    return back(B), back(adjugate(B) / det(B)), det_base, det_old, jnp.where(ok, c * h, h)


def timed(fn, *args, n=30):
    jax.block_until_ready(fn(*args))
    ts = []
    for _ in range(n):
        tic = time.perf_counter()
        jax.block_until_ready(fn(*args))
        ts.append(time.perf_counter() - tic)
    return f"best {1e3 * min(ts):.2f} ms, median {1e3 * np.median(ts):.2f} ms"


def main():
    Cv, Cvp = sym(0), sym(1)
    vmapped = jax.jit(lambda C, Cp: jax.vmap(lambda a, b: mat.bdf2_flow_step(a, b, H, H))(C, Cp))
    leading = jax.jit(lambda C, Cp: bdf2_leading(C, Cp, H, H))
    inv_vmapped = jax.jit(lambda C: jax.vmap(jax.vmap(tn.inv3))(C))
    inv_lead = jax.jit(inv_leading)
    ref, new = vmapped(Cv, Cvp), leading(Cv, Cvp)
    for a, b in zip((ref.base, ref.base_inv, ref.det_base, ref.det_old, ref.dt), new):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(inv_vmapped(Cv), inv_lead(Cv), rtol=1e-12, atol=1e-14)
    for _ in range(2):
        print("bdf2_flow_step vmapped  ", timed(vmapped, Cv, Cvp))
        print("components leading      ", timed(leading, Cv, Cvp))
        print("inv3 vmapped            ", timed(inv_vmapped, Cv))
        print("inv3 components leading ", timed(inv_lead, Cv))


if __name__ == "__main__":
    main()
