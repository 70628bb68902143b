"""Is a single-precision factorization a lever for N1? (issue 10: a faster factorization)

    python bench/mixed_precision_factor.py [--mesh 12x20x4] [--sweeps 8]

R2's iteration matrix (tube 12x20x4, Model IV, tangent plus a mass term of a step) is
factorized by MKL Pardiso's Cholesky in double precision and in single precision
(``iparm[27] = 1``: values, factor and solves in float32); then, for three right-hand
sides, the relative residual |A x - b| / |b| of the single-precision solve and of each sweep
of iterative refinement against the double-precision matrix. Printed: factorization and
solve times (best of 3) and the refinement histories. Needs pypardiso (MKL).

Measured (2026-12-05, 2 cores): factorization 0.16 s in single against 0.29-0.33 s in
double precision; but the matrix's condition (diagonal 1e-2 to 5e7; symmetric diagonal
scaling changes nothing) leaves a single-precision solve of a generic right-hand side at a
relative residual of 50-60, and refinement gains a factor of about 10 per sweep (a sweep:
one sparse product, 2.4 ms, and one single-precision solve, 3.9 ms). A Newton direction to
1e-6 then takes 7-8 sweeps, and every later solve with the reused factorization (R2 reuses
one factorization for the whole run) the same, where a double-precision solve takes 6 ms.
N1 measured with it (Newton directions to 1e-6, at most 4 sweeps, double precision where
refinement stalls): 0.60-0.64 s against 0.72 s, FElupe 0.36 s: not kept.
"""
from __future__ import annotations

import argparse
import time

import jax.numpy as jnp
import numpy as np

from dejax import linsolve, scenarios
from dejax import model as mdl


def best(f, repeat=3):
    ts = []
    for _ in range(repeat):
        tic = time.perf_counter()
        out = f()
        ts.append(time.perf_counter() - tic)
    return min(ts), out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--mesh", default="12x20x4")
    ap.add_argument("--sweeps", type=int, default=8)
    a = ap.parse_args()
    m = scenarios.rolled("IV", 30.0, 50e3, shape=tuple(int(s) for s in a.mesh.split("x"))).model
    E = mdl.nominal_field(m, jnp.zeros(m.field_dirs.shape[0]))
    _, Ke, _ = mdl.element_tangents(m, m.q0, E, mdl.initial_viscous_state(m), 1e-3)
    Ke = Ke + (4.0 / (1.0 / 1500.0) ** 2) * mdl.mass_elements(m)  # beta' M of a step of 1/1500 s
    pattern = mdl.assembly(m.structure)
    values = np.asarray(mdl.assemble_values(m, Ke))
    A = linsolve._csc(pattern, values)
    d = A.diagonal()
    print(f"mesh {a.mesh}: {pattern.n} unknowns, {values.size} nonzeros, diagonal {d.min():.2e} .. {d.max():.2e}")

    lib = linsolve._mkl()
    handles = {}
    for name, dtype in (("double", np.float64), ("single", np.float32)):
        h = linsolve._PardisoPattern(lib, pattern)
        h.iparm[27] = int(dtype == np.float32)
        av = np.ascontiguousarray(values[pattern.upper], dtype=dtype)
        z = np.zeros((h.n, 1), dtype=dtype, order="F")
        linsolve._check_mkl(h.call(11, 1, av, z)[1], 11)
        t_fac, _ = best(lambda: linsolve._check_mkl(h.call(22, 1, av, z)[1], 22))
        handles[name] = (h, av, dtype)
        b = np.ones((h.n, 1), dtype=dtype, order="F")
        t_sol, _ = best(lambda: h.call(33, 1, av, b))
        print(f"{name:>6} precision: factorization {t_fac:.3f} s, solve {1e3 * t_sol:.1f} ms")
    t_mv, _ = best(lambda: A @ np.ones(pattern.n))
    print(f"sparse product A x (double, scipy): {1e3 * t_mv:.1f} ms")

    h, av, dtype = handles["single"]

    def solve32(r):
        x, err = h.call(33, 1, av, np.asfortranarray(r.astype(dtype)[:, None]))
        linsolve._check_mkl(err, 33)
        return x[:, 0].astype(np.float64)

    rng = np.random.default_rng(0)
    for name, b in (("A @ random", A @ rng.standard_normal(pattern.n)), ("ones", np.ones(pattern.n)),
                    ("random", rng.standard_normal(pattern.n))):
        x, hist = solve32(b), []
        for _ in range(a.sweeps):
            r = b - A @ x
            hist.append(np.linalg.norm(r) / np.linalg.norm(b))
            x = x + solve32(r)
        print(f"b = {name:<11} relative residual by sweep: " + " ".join(f"{v:.1e}" for v in hist))
    for h, av, dtype in handles.values():
        h.call(-1, 1, av, np.zeros((h.n, 1), dtype=dtype, order="F"))


if __name__ == "__main__":
    main()
