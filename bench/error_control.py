"""Error-controlled steps on R1 (issue 10, point 3: a lever weighed by measurement).

    python bench/error_control.py 1/1500:none 1/300:1e-4 1/300:1e-3 [DT:TOL ...]

Each argument runs R1's loading (tube 4x8x1, Model IV, 50 kV, 30 Hz, ten cycles, Newton to
1e-2 as ``dejax bench``) on an output grid of step DT (s), with ``StepControl(tol=TOL)``
(``none``: the fixed grid, no error control). Printed: accepted sub-steps, rejected
ones, Newton iterations, factorizations, smallest sub-step, run time (after compiling)
and the deviation of x_P **at the output times** from the bench's reference (dt = 1e-4 s,
Newton to 1e-10), max |x_P - x_P,ref| / max |x_P,ref|. (``dejax bench``'s deviation
interpolates x_P linearly between outputs, which a coarse output grid would dominate.)
"""
import sys
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from dejax import bench, integrate as it, linsolve, scenarios


def main(argv):
    p = scenarios.rolled("IV", 30.0, 50e3, shape=(4, 8, 1))
    t_end = 10 / 30.0
    t_ref, x_ref = bench.reference_trace(f"tube-4x8x1-IV-50kV-30Hz-{p.scheme().flow_update}-{t_end:.6g}s", p, t_end)
    solver = linsolve.choose_solver(p.model.structure, "auto")
    newton = it.NewtonOptions(tol=bench.TUBE_NEWTON_TOL)
    for arg in argv:
        dt_text, tol_text = arg.split(":")
        num, _, den = dt_text.partition("/")
        dt = float(num) / float(den) if den else float(num)
        tol = None if tol_text == "none" else float(tol_text)
        times = it.time_grid(t_end, dt)
        step = it.make_step(p.scheme(), newton, solver)
        scan = eqx.filter_jit(it.make_scan(step, p.output_fn, it.StepControl(tol=tol)))
        s0 = eqx.filter_jit(it.initial_state)(p.model, p.loading, jnp.asarray(0.0))
        carry = it.initial_carry(p.model, s0, step.solver, 1)
        tt, on = jnp.asarray(times[1:]), jnp.ones(times.size - 1, bool)
        run = scan.lower(p.model, p.loading, carry, tt, on).compile()
        tic = time.perf_counter()
        end, (out, its, nfac, ncut, _) = jax.block_until_ready(run(p.model, p.loading, carry, tt, on))
        run_s = time.perf_counter() - tic
        x = np.asarray(out["x_P"])
        dev = np.max(np.abs(x - np.interp(times[1:], t_ref, x_ref))) / np.max(np.abs(x_ref))
        print(f"output dt {dt:.4g} s, tol {tol}: status {int(end.status)}, {int(end.n_sub)} sub-steps, "
              f"{int(np.sum(ncut))} rejected, {int(np.sum(its))} Newton iterations, {int(np.sum(nfac))} "
              f"factorizations, smallest {float(end.h_smallest):.3g} s, run {run_s:.2f} s, deviation at the "
              f"outputs {100 * dev:.3f} %", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:] or ["1/1500:none", "1/300:1e-4", "1/300:1e-3"])
