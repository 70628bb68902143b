"""N1's step with the Newton matrices stored by component against the (96, 96) layout, in one
process (needs ``git apply bench/patches/stiffness_by_component.patch``; the old way is
``_condensed_system_of`` as before the patch). See bench/stiffness_layout.py.

    python bench/stiffness_by_component_ab.py [rounds]
"""
import sys, time, jax, jax.numpy as jnp, numpy as np
jax.config.update("jax_enable_x64", True)
from dejax import bench, linsolve, model as mdl
orig = mdl._condensed_system_of
def old_of(material, N, dNdxi, dt, c, dV, dXdxi, Jinv, F, E, Cv_old, p, wmax, mass_e, kpp_newton):
    s = mdl._element_system_of(material, N, dNdxi, dt, c, dV, dXdxi, Jinv, F, E, Cv_old, p, wmax, mass_e)
    kpp = s.kpp if kpp_newton is None else kpp_newton
    return mdl.CondensedSystem(mdl._condense_of(s.Ke, s.kup, kpp), s.kup, kpp, s.fe, s.g, s.Cv_new)
progs = {}
for name, fn in (("old", old_of), ("new", orig)):
    mdl._condensed_system_of = fn
    jax.clear_caches()
    p, solv, one, s0, fac0 = bench.n1_step()
    o = jax.block_until_ready(one(s0, fac0))
    progs[name] = (one, s0, fac0); print(name, "status", int(o[3]))
    progs[name + "_q"] = o[0].q
mdl._condensed_system_of = orig
print("max |dq| / max |q|:", float(jnp.max(jnp.abs(progs["new_q"] - progs["old_q"])) / jnp.max(jnp.abs(progs["old_q"]))))
res = {"old": [], "new": []}
for r in range(int(sys.argv[1]) if len(sys.argv) > 1 else 10):
    for name in ("old", "new"):
        one, s0, fac0 = progs[name]
        linsolve.clear_factorizations()
        tic = time.perf_counter(); jax.block_until_ready(one(s0, fac0)); res[name].append(time.perf_counter() - tic)
for name, v in res.items(): print(f"{name}: best {min(v):.3f} s, median {np.median(v):.3f} s")
