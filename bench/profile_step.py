"""Where a step's time goes (issue 10, point 2): component timings of one Newton iteration.

    python bench/profile_step.py [--mesh 4x8x1] [--steps 200]

Times (ms, after compilation, median of repeats) of: the residual (element forces +
viscous update), the element system (forces + consistent tangent), condensation +
dense/sparse assembly, the factorization, one solve with it, and a whole step of the
rolled tube (Model IV, 50 kV, 30 Hz, dt = 1e-4 s unless --dt) from a state part-way into the run.

With ``--lanes N`` also the floor of a forward-mode derivative step with N tangent lanes (G1:
12): what the implicit derivative of each step must add to the forward step, at the least,
timed piece by piece: the element system at the converged state (consistent tangent), its
condensation, assembly and factorization, N solves, and the residual's jvp along N
directions (here coordinate directions: the parameter lanes push at least this through the
material law, plus the parameters' own tangents). The floor ratio (forward step + floor) /
forward step bounds what G1 / R1 can reach with exact per-step derivatives, before any of the
lanes' bookkeeping (state tangents, BDF2 history, layout copies).
"""
from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np

from dejax import integrate as it
from dejax import linsolve, scenarios
from dejax import model as mdl


def timed(f, *args, repeat=20, before=None):
    """(median ms of ``repeat`` calls of f(*args) after a first one, its output); ``before()``
    runs untimed ahead of each call (e.g. clearing the sparse factorization cache)."""
    out = jax.block_until_ready(f(*args))  # compile + first run
    ts = []
    for _ in range(repeat):
        if before is not None:
            before()
        tic = time.perf_counter()
        jax.block_until_ready(f(*args))
        ts.append(time.perf_counter() - tic)
    return 1e3 * float(np.median(ts)), out


def loaded_step(shape, steps, dt, model="IV"):
    """The rolled tube (``model``, 50 kV, 30 Hz) ``steps`` steps of ``dt`` into its loading:
    (problem, solver, state, ctx, z) with the next step's context and predicted iterate."""
    p = scenarios.rolled(model, 30.0, 50e3, shape=shape)
    m, load, scheme = p.model, p.loading, p.scheme()
    solver = linsolve.choose_solver(m.structure)
    state = it.simulate(m, load, it.time_grid(steps * dt, dt), p.output_fn, scheme, solver=solver).check().final
    t1 = state.t + dt
    ctx = it._StepContext(state=state, t1=jnp.asarray(t1), phi1=load.phi(t1),
                          u1=load.u(t1) if m.prescribed_dirs.shape[0] else jnp.zeros(0),
                          f_ext=mdl.external_force(m), flow=mdl.flow_step(m, state, dt, scheme.flow_update))
    return p, solver, state, ctx, scheme.predict(state, dt, "velocity")[m.structure.free]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--mesh", default="4x8x1")
    ap.add_argument("--steps", type=int, default=100, help="steps run before profiling (a loaded state)")
    ap.add_argument("--model", default="IV")
    ap.add_argument("--dt", type=float, default=1e-4, help="time step (s)")
    ap.add_argument("--lanes", type=int, default=0, help="also time a forward-mode derivative step's floor with "
                    "this many tangent lanes (G1: 12)")
    a = ap.parse_args()
    shape = tuple(int(s) for s in a.mesh.split("x"))
    dt = a.dt
    p, solver, state, ctx, z = loaded_step(shape, a.steps, dt, a.model)
    m, load, scheme = p.model, p.loading, p.scheme()
    pr = state.p
    print(f"mesh {a.mesh}: {m.dV.shape[0]} elements, {m.dV.size} Gauss points, {m.structure.n_free} unknowns, "
          f"{m.material.n_units} viscous units, solver {type(solver).__name__}")
    res = jax.jit(lambda z, p: it._residual(m, scheme, ctx, z, p))
    t_res, _ = timed(res, z, pr)
    sysf = jax.jit(lambda z, p: it._system(m, scheme, ctx, z, p))
    t_sys, sys = timed(sysf, z, pr)
    cond = jax.jit(lambda s: mdl.condense(s.Ke, s.kup, mdl.newton_kpp(m, s.kpp)))
    t_cond, Kc = timed(cond, sys)
    fac = jax.jit(lambda K: solver.factor(m, K))
    t_fac, F = timed(fac, Kc, repeat=5)
    rhs = jnp.ones(m.structure.n_free)
    sol_f = jax.jit(lambda F, r: solver.solve_factored(m, F, r))
    t_sol, _ = timed(sol_f, F, rhs)
    if isinstance(solver, linsolve.DenseSolver):
        asm = jax.jit(lambda K: mdl.assemble_dense(m, K))
        t_asm, _ = timed(asm, Kc)
    else:
        t_asm = float("nan")
    # material point only: stress+update and tangent+update over all points
    F_ = mdl.deformation_gradients(m, mdl.full_coordinates(m, z, ctx.u1))
    E = mdl.nominal_field(m, ctx.phi1)
    pg = mdl.pressure_at_points(m, pr)
    wmax = mdl.initial_history(m)  # no Mullins softening in Model IV: the history is unused
    from dejax import material as mat
    pt_res = jax.jit(lambda F_: mdl._per_point_mixed(mat.mixed_stress_and_update)(F_, E, ctx.flow, dt, pg, m.material, wmax))
    pt_tan = jax.jit(lambda F_: mdl._per_point_mixed(mat.mixed_tangent_and_update)(F_, E, ctx.flow, dt, pg, m.material, wmax))
    t_pres, _ = timed(pt_res, F_)
    t_ptan, _ = timed(pt_tan, F_)
    adm = jax.jit(lambda z: it._admissible(m, ctx, z))
    t_adm, _ = timed(adm, z)
    step = it.make_step(scheme, it.NewtonOptions(), solver)
    stepj = jax.jit(lambda s, f, v: step(m, load, s, s.t + dt, f, v))
    fac0 = it._empty_fac(m, solver)
    t_step_fresh, out = timed(stepj, state, fac0, False, repeat=5)
    t_step_reuse, out2 = timed(stepj, state, out[4], True, repeat=10)
    print(f"{'residual (forces + viscous update)':<44} {t_res:9.2f} ms")
    print(f"{'  of which material points only':<44} {t_pres:9.2f} ms")
    print(f"{'element system (forces + tangent)':<44} {t_sys:9.2f} ms")
    print(f"{'  of which material points only':<44} {t_ptan:9.2f} ms")
    print(f"{'admissibility check':<44} {t_adm:9.2f} ms")
    print(f"{'condensation':<44} {t_cond:9.2f} ms")
    print(f"{'dense assembly':<44} {t_asm:9.2f} ms")
    print(f"{'factorization (incl. assembly)':<44} {t_fac:9.2f} ms")
    print(f"{'solve with the factorization':<44} {t_sol:9.2f} ms")
    print(f"{'one step, fresh factorization':<44} {t_step_fresh:9.2f} ms  ({int(out[1])} it, {int(out[2])} fact.)")
    print(f"{'one step, reused factorization':<44} {t_step_reuse:9.2f} ms  ({int(out2[1])} it, {int(out2[2])} fact.)")
    if a.lanes:
        n = a.lanes
        dz = jnp.asarray(np.random.default_rng(0).standard_normal((n, z.size))) * mdl.dof_scale(m) * 1e-3
        jvp_n = jax.jit(jax.vmap(lambda d: jax.jvp(lambda z_: it._residual(m, scheme, ctx, z_, pr)[0], (z,), (d,))[1]))
        t_jvp, _ = timed(jvp_n, dz)
        sol_n = jax.jit(lambda F, r: solver.solve_factored(m, F, r.T))
        t_soln, _ = timed(sol_n, F, dz)
        floor = t_sys + t_cond + t_fac + t_soln + t_jvp
        print(f"forward-mode derivative floor, {n} lanes (what each step adds at the least):")
        print(f"{'  residual jvp along ' + str(n) + ' directions':<44} {t_jvp:9.2f} ms")
        print(f"{'  ' + str(n) + ' solves with the factorization':<44} {t_soln:9.2f} ms")
        print(f"{'  + element system, condensation, factorization':<44} {t_sys + t_cond + t_fac:9.2f} ms")
        print(f"{'  floor':<44} {floor:9.2f} ms: derivative run >= {(t_step_reuse + floor) / t_step_reuse:.1f}x "
              f"the forward run (its step: {t_step_reuse:.2f} ms, reused factorization)")


if __name__ == "__main__":
    main()
