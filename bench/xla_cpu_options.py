"""XLA:CPU compiler options against each other on dejax's programs (issue 10, point 3).

    python bench/xla_cpu_options.py [--mesh 4x8x1] [--steps 100] [--reps 5]

Compiles the same lowered programs under each option set and runs them alternately in
one process (min and median of the repeats), so that the machine's drift hits every
variant alike: the element residual, the element system (forces + consistent tangent)
and ``--steps`` time steps of the rolled tube (Model IV, 50 kV, 30 Hz, dt = 5e-4 s, the
R1 loading) from a state part-way into the run.

Variants: "dejax" (what importing dejax sets, ``dejax.CPU_XLA_FLAGS``), "xla-default"
(XLA's own YNNPACK fusions: elementwise and reductions as well), "no-ynn" (none),
"emitters" (dejax's, with XLA:CPU's MLIR fusion emitters back on). Compilation times of
the step scan are printed too.
"""
from __future__ import annotations

import argparse
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from dejax import integrate as it
from dejax import linsolve, scenarios
from dejax import model as mdl

KEY = "xla_cpu_experimental_ynn_fusion_type"
# "xla-default" overrides the flag dejax sets with XLA's default list (elementwise,
# reductions and products): the same programs compiled as without dejax's setting
VARIANTS = {
    "dejax": {KEY: "LIBRARY_FUSION_TYPE_DOT"},
    "xla-default": {KEY: "LIBRARY_FUSION_TYPE_DOT,LIBRARY_FUSION_TYPE_ELTWISE,LIBRARY_FUSION_TYPE_REDUCE"},
    "no-ynn": {KEY: ""},
    "emitters": {KEY: "LIBRARY_FUSION_TYPE_DOT", "xla_cpu_use_fusion_emitters": True},
}


def alternate(compiled: dict, args, reps: int) -> dict:
    """{variant: seconds per call, each repeat} running the variants in turn."""
    out = {k: [] for k in compiled}
    for _ in range(reps):
        for k, c in compiled.items():
            tic = time.perf_counter()
            jax.block_until_ready(c(*args))
            out[k].append(time.perf_counter() - tic)
    return out


def report(name: str, times: dict, per: int = 1, unit: str = "ms") -> None:
    cells = [f"{k} {1e3 * min(v) / per:8.2f} / {1e3 * np.median(v) / per:8.2f}" for k, v in times.items()]
    print(f"{name:<24} " + "   ".join(cells) + f"   ({unit}: min / median)", flush=True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--mesh", default="4x8x1")
    ap.add_argument("--steps", type=int, default=100)
    ap.add_argument("--reps", type=int, default=5)
    a = ap.parse_args()
    shape = tuple(int(s) for s in a.mesh.split("x"))
    p = scenarios.rolled("IV", 30.0, 50e3, shape=shape)
    m, load, scheme, dt = p.model, p.loading, p.scheme(), 5e-4
    solver = linsolve.choose_solver(m.structure)
    step = it.make_step(scheme, it.NewtonOptions(tol=1e-4), solver)
    run = eqx.filter_jit(it.make_scan(step, p.output_fn, it.StepControl()))
    times = it.time_grid(1.0 / 3.0, dt)
    n = a.steps
    s0 = it.initial_state(m, load, 0.0)
    carry = it.initial_carry(m, s0, solver, 1)
    first, second = jnp.asarray(times[1:n + 1]), jnp.asarray(times[n + 1:2 * n + 1])
    active = jnp.ones(n, bool)
    lowered = run.lower(m, load, carry, first, active)
    runs, compile_s = {}, {}
    for k, o in VARIANTS.items():
        tic = time.perf_counter()
        runs[k] = lowered.compile(compiler_options=o)
        compile_s[k] = time.perf_counter() - tic
    print("compile of the step scan (s): " + "   ".join(f"{k} {v:.1f}" for k, v in compile_s.items()), flush=True)
    carry, _ = runs["dejax"](m, load, carry, first, active)  # a loaded state
    state = carry.state
    ctx = it._StepContext(state=state, t1=state.t + dt, phi1=load.phi(state.t + dt), u1=jnp.zeros(0),
                          f_ext=mdl.external_force(m), flow=mdl.flow_step(m, state, dt, scheme.flow_update))
    z, pr = state.q[m.structure.free], state.p
    print(f"tube {a.mesh}: {m.structure.n_free} unknowns, {m.dV.size} Gauss points; variants: "
          + ", ".join(f"{k} ({v[KEY] or 'none'})" for k, v in VARIANTS.items()))
    for name, f in (("residual", it._residual), ("element system", it._system)):
        low = jax.jit(lambda z, p, f=f: f(m, scheme, ctx, z, p)).lower(z, pr)
        report(name, alternate({k: low.compile(compiler_options=o) for k, o in VARIANTS.items()}, (z, pr), 3 * a.reps))
    report(f"{n} steps, per step", alternate(runs, (m, load, carry, second, active), a.reps), per=n)


if __name__ == "__main__":
    main()
