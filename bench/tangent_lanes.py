"""The consistent tangent through six C lanes against nine F lanes (``material.C_LANES``, only
with ``git apply bench/patches/c_lanes_tangent.patch``; revert it afterwards), in
one process, alternating: the material points' tangent and the element system (forces,
tangent, stiffness) of the rolled tube (Model IV, 50 kV, 30 Hz) at a state part-way in.

    python bench/tangent_lanes.py [--mesh 12x20x4] [--rounds 3]

Prints per round and variant the median time (ms) of each, and the largest relative
difference of the element matrices between the variants (they agree to round-off).

Measured 2026-12-05 (2 cores): not kept. Tube 12x20x4, material points 183-207 ms (C) against
188-234 ms (F), element system 233-254 against 244-263 ms; tube 4x8x1 element system 5.9-6.2
against 5.4-6.3 ms; N1 alternated three times in one process 0.641/0.648/0.649 s (C) against
0.657/0.612/0.633 s (F). A third fewer lanes did not take a third of the time: the per-point
law at 25,920 points is a chain of memory-bound loops over (points, lanes, units, 3, 3)
arrays (``bench/profile_ops.py``-style trace: no operation above 7 % of 258 ms), and dP/dF at
fixed Cv (56 ms), dCv/dF (63 ms) and their cross term (~40 ms) each cost several times
their primal (P 5.8 ms, the flow update 13 ms).
"""
from __future__ import annotations

import argparse

import jax
import numpy as np

from dejax import integrate as it
from dejax import material as mat
from dejax import model as mdl
from profile_step import loaded_step, timed


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--mesh", default="12x20x4")
    ap.add_argument("--steps", type=int, default=5, help="steps run before timing (a loaded state)")
    ap.add_argument("--rounds", type=int, default=3)
    a = ap.parse_args()
    if not hasattr(mat, "_tangent_lanes_via_C"):
        raise SystemExit("the C lanes need `git apply bench/patches/c_lanes_tangent.patch`")
    shape = tuple(int(s) for s in a.mesh.split("x"))
    dt = 1e-4
    p, _, state, ctx, z = loaded_step(shape, a.steps, dt)
    m, scheme = p.model, p.scheme()
    F = mdl.deformation_gradients(m, mdl.full_coordinates(m, z, ctx.u1))
    E = mdl.nominal_field(m, ctx.phi1)
    pg = mdl.pressure_at_points(m, state.p)
    wmax = mdl.initial_history(m)
    print(f"mesh {a.mesh}: {m.dV.shape[0]} elements, {m.dV.size} Gauss points, {m.material.n_units} units, "
          f"mixed {m.structure.mixed}")
    Ke = {}
    for r in range(a.rounds):
        for flag in (False, True):
            mat.C_LANES = flag
            jax.clear_caches()
            if m.structure.mixed:
                pt = jax.jit(lambda F_: mdl._per_point_mixed(mat.mixed_tangent_and_update)(
                    F_, E, ctx.flow, dt, pg, m.material, wmax))
            else:
                pt = jax.jit(lambda F_: mdl._per_point(mat.stress_tangent_update_and_flow_tangent)(
                    F_, E, ctx.flow, dt, m.material, wmax))
            t_pt, _ = timed(pt, F, repeat=10)
            sysf = jax.jit(lambda z, p: it._system(m, scheme, ctx, z, p))
            t_sys, s = timed(sysf, z, state.p, repeat=10)
            Ke[flag] = np.asarray(s.Ke)
            name = "6 C lanes" if flag else "9 F lanes"
            print(f"round {r}: {name}: material points {t_pt:8.2f} ms, element system {t_sys:8.2f} ms")
    mat.C_LANES = True
    print(f"max |Ke(C) - Ke(F)| / max |Ke(F)| = {np.max(np.abs(Ke[True] - Ke[False])) / np.max(np.abs(Ke[False])):.1e}")


if __name__ == "__main__":
    main()
