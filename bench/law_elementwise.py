"""The point law with its 3 x 3 reductions (mm3, gram3, trace, full contractions, dots)
written as explicit sums of slices (no reduce operations) against the current form, at 864
and 25,920 points: XLA's bytes accessed and flops, and the time (best and median of 7,
alternated in one process). Tried 2026-12-06 and not kept (docs/performance.md).

    python bench/law_elementwise.py
"""
import types, time, jax, jax.numpy as jnp, numpy as np
from dejax import material as m, tensor as tn, scenarios

def mm3_e(A, B):
    return A[:, 0:1] * B[0:1, :] + A[:, 1:2] * B[1:2, :] + A[:, 2:3] * B[2:3, :]
def gram3_e(F):
    return F[0][:, None] * F[0][None, :] + F[1][:, None] * F[1][None, :] + F[2][:, None] * F[2][None, :]
def sum_e(x, axis=None, **kw):
    x = jnp.asarray(x)
    if axis is None and not kw and x.shape == (3, 3):
        r = x[0] + x[1] + x[2]
        return r[0] + r[1] + r[2]
    if axis is None and not kw and x.shape == (3,):
        return x[0] + x[1] + x[2]
    return jnp.sum(x, axis=axis, **kw)
def trace_e(x, *a, **kw):
    x = jnp.asarray(x)
    if x.shape == (3, 3) and not a and not kw:
        return x[0, 0] + x[1, 1] + x[2, 2]
    return jnp.trace(x, *a, **kw)
def dot_e(a, b):
    a, b = jnp.asarray(a), jnp.asarray(b)
    if a.shape == (3,) and b.shape == (3,):
        return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
    if a.shape == (3, 3) and b.shape == (3,):
        return a[:, 0] * b[0] + a[:, 1] * b[1] + a[:, 2] * b[2]
    return jnp.dot(a, b)
jnp_e = types.SimpleNamespace(**{k: getattr(jnp, k) for k in dir(jnp) if not k.startswith('__')})
jnp_e.sum, jnp_e.trace, jnp_e.dot = sum_e, trace_e, dot_e
ORIG = dict(mm3=m.mm3, gram3=m.gram3, jnp=m.jnp, tmm3=tn.mm3, tjnp=tn.jnp)
def use(elementwise):
    m.mm3, m.gram3, m.jnp = (mm3_e, gram3_e, jnp_e) if elementwise else (ORIG['mm3'], ORIG['gram3'], ORIG['jnp'])
    tn.mm3, tn.jnp = (mm3_e, jnp_e) if elementwise else (ORIG['tmm3'], ORIG['tjnp'])
    jax.clear_caches()

mat = scenarios.rolled_material("IV")
rng = np.random.default_rng(0)
def data(n):
    F = jnp.asarray(np.eye(3) + 0.05 * rng.standard_normal((n, 3, 3)))
    E = jnp.asarray(rng.standard_normal((n, 3)) * 1e6)
    Cv = jnp.asarray(np.broadcast_to(np.eye(3), (n, mat.n_units, 3, 3)).copy() + 1e-3 * rng.standard_normal((n, mat.n_units, 3, 3)))
    Cv = 0.5 * (Cv + jnp.swapaxes(Cv, -1, -2))
    return F, E, Cv, Cv, jnp.zeros(n)
dt = 1 / 1500
def flow(Cv, Cvp): return jax.vmap(lambda a, b: m.bdf2_flow_step(a, b, dt, dt))(Cv, Cvp)
def primal(F, E, Cv, Cvp, p):
    return jax.vmap(lambda F, E, fl, p: m.mixed_stress_and_update(F, E, fl, dt, p, mat))(F, E, flow(Cv, Cvp), p)
def tangent(F, E, Cv, Cvp, p):
    return jax.vmap(lambda F, E, fl, p: m.mixed_tangent_and_update(F, E, fl, dt, p, mat))(F, E, flow(Cv, Cvp), p)
def lanes12(F, E, Cv, Cvp, p, dCv):
    f = lambda Cv_: primal(F, E, Cv_, Cvp, p)
    return jax.vmap(lambda t: jax.jvp(f, (Cv,), (t,))[1])(dCv)
for n in (864, 25920):
    args = data(n)
    dCv = jnp.asarray(rng.standard_normal((12,) + args[2].shape) * 1e-3)
    cases = {"primal": (primal, args), "tangent": (tangent, args)}
    if n == 864:
        cases["12 lanes"] = (lanes12, args + (dCv,))
    progs, outs = {}, {}
    for ew in (False, True):
        use(ew)
        for name, (fn, a) in cases.items():
            c = jax.jit(fn).lower(*a).compile()
            ca = c.cost_analysis(); ca = ca[0] if isinstance(ca, list) else ca
            progs[(name, ew)] = (c, a, ca.get('bytes accessed', 0), ca.get('flops', 0))
            outs[(name, ew)] = jax.tree.leaves(c(*a))
    use(False)
    times = {k: [] for k in progs}
    for _ in range(7):
        for k, (c, a, *_r) in progs.items():
            t = time.perf_counter(); jax.block_until_ready(c(*a)); times[k].append(time.perf_counter() - t)
    for name in cases:
        d = max(float(jnp.max(jnp.abs(x - y)) / (jnp.max(jnp.abs(x)) + 1e-300)) for x, y in zip(outs[(name, False)], outs[(name, True)]))
        for ew in (False, True):
            c, a, b, fl = progs[(name, ew)]
            print(f"n={n:6d} {name:9s} {'elementwise' if ew else 'current    '} {min(times[(name, ew)])*1e3:8.3f} ms (median {np.median(times[(name, ew)])*1e3:8.3f})"
                  f"  bytes {b/1e6:8.2f} MB  flops {fl/1e6:8.2f} M" + (f"  max rel diff {d:.1e}" if ew else ""), flush=True)
