"""MKL Pardiso's options on R2's iteration matrix (tube 12 x 20 x 4, Model IV), in one
process: symbolic analysis, Cholesky factorization and solve for each variant, beside
MKL's own dgemm rate on the same cores (the ceiling a supernodal Cholesky approaches).

    python bench/pardiso_options.py [--repeat 5]

Prints per variant: analysis s, factorization s (best of ``repeat``), solve s, the
factor's nonzeros and MKL's factorization MFLOP count (iparm 18/19), GFLOP/s, and the
solve's relative residual; then the factorization into one slot of the current handle,
repeated (its memory reused), with MKL's release (phase 0) between, and into a fresh slot
each time.
"""

import argparse
import ctypes
import time

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

from dejax import integrate as it, linsolve, scenarios  # noqa: E402
from dejax.bench import TUBE_DT  # noqa: E402


def r2_matrix():
    """R2's first iteration matrix: (pattern, CSC values)."""
    got = {}
    orig = linsolve._factorize

    def grab(pattern, values, backend):
        # Pardiso is handed the upper triangle (model.assemble_upper): the whole CSC values
        got.setdefault("m", (pattern, np.array(values)[linsolve._UpperPattern(pattern).full]))
        return orig(pattern, values, backend)

    linsolve._factorize = grab
    try:
        p = scenarios.rolled("IV", 30.0, 50e3, shape=(12, 20, 4))
        m = p.model
        solv = linsolve.choose_solver(m.structure, "pardiso")
        step = it.make_step(p.scheme(), it.NewtonOptions(reuse=False, max_iter=1, line_search=False), solv)
        s0 = it.initial_state(m, p.loading, 0.0)
        fac0 = it.initial_carry(m, s0, solv).fac
        linsolve.clear_factorizations()
        jax.block_until_ready(step(m, p.loading, s0, s0.t + TUBE_DT, fac0, False))
    finally:
        linsolve._factorize = orig
    return got["m"]


def dgemm_gflops(lib, n=2000, repeat=5):
    """MKL's cblas_dgemm on n x n matrices: GFLOP/s (best of ``repeat``)."""
    a, b = np.random.rand(n, n), np.random.rand(n, n)
    c = np.zeros((n, n))
    f = lib.cblas_dgemm
    f.restype = None
    p = lambda x: x.ctypes.data_as(ctypes.c_void_p)  # noqa: E731
    best = np.inf
    for _ in range(repeat):
        tic = time.perf_counter()
        f(101, 111, 111, n, n, n, ctypes.c_double(1.0), p(a), n, p(b), n, ctypes.c_double(0.0), p(c), n)
        best = min(best, time.perf_counter() - tic)
    assert np.allclose(c[:3, :3], a[:3] @ b[:, :3])
    return 2 * n**3 / best / 1e9


def run_variant(lib, pattern, values, iparm_set, repeat):
    h = linsolve._PardisoPattern(lib, pattern)
    for k, v in iparm_set.items():
        h.iparm[k] = v
    h.iparm[17] = -1  # report the factor's nonzeros
    h.iparm[18] = -1  # report the factorization's MFLOP
    a = np.ascontiguousarray(values[pattern.upper])
    z = np.zeros((h.n, 1), order="F")
    tic = time.perf_counter()
    linsolve._check_mkl(h.call(11, 1, a, z)[1], 11)
    analysis = time.perf_counter() - tic
    fact = np.inf
    for _ in range(repeat):
        tic = time.perf_counter()
        linsolve._check_mkl(h.call(22, 1, a, z)[1], 22)
        fact = min(fact, time.perf_counter() - tic)
    nnz_l, mflop = int(h.iparm[17]), int(h.iparm[18])
    A = linsolve._csc(pattern, values)
    b = np.asfortranarray(np.random.default_rng(0).standard_normal((h.n, 1)))
    tic = time.perf_counter()
    x, err = h.call(33, 1, a, b)
    solve = time.perf_counter() - tic
    linsolve._check_mkl(err, 33)
    res = np.linalg.norm(A @ x[:, 0] - b[:, 0]) / np.linalg.norm(b)
    h.call(-1, 1, a, z)
    return analysis, fact, solve, nnz_l, mflop, res


VARIANTS = {
    "current (METIS, classic)": {},
    "parallel METIS (iparm[1]=3)": {1: 3},
    "minimum degree (iparm[1]=0)": {1: 0},
    "two-level factorization (iparm[23]=1)": {23: 1},
    "parallel METIS + two-level": {1: 3, 23: 1},
    "variable-block storage (iparm[36]=-80)": {36: -80},
    "variable-block storage (iparm[36]=-95)": {36: -95},
}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    lib = linsolve._mkl()
    pattern, values = r2_matrix()
    print(f"R2 matrix: n = {pattern.n}, nnz = {values.size}, MKL threads = {lib.MKL_Get_Max_Threads()}")
    print(f"MKL dgemm 2000^3: {dgemm_gflops(lib):.1f} GFLOP/s")
    print(f"{'variant':<40} {'analysis s':>10} {'factor s':>9} {'solve s':>8} {'nnz(L)':>10} {'GFLOP':>6} "
          f"{'GFLOP/s':>8} {'residual':>9}")
    for name, iparm_set in VARIANTS.items():
        an, fa, so, nnz, mf, res = run_variant(lib, pattern, values, iparm_set, args.repeat)
        print(f"{name:<40} {an:10.3f} {fa:9.3f} {so:8.4f} {nnz:10d} {mf / 1e3:6.2f} {mf / 1e3 / fa:8.1f} {res:9.1e}")
    slot_memory(lib, pattern, values, args.repeat)


def slot_memory(lib, pattern, values, repeat):
    """Factorization times (s) into a reused slot, after MKL's release, into fresh slots."""
    h = linsolve._PardisoPattern(lib, pattern)
    a = np.ascontiguousarray(values[pattern.upper])
    z = np.zeros((h.n, 1), order="F")
    linsolve._check_mkl(h.call(11, 1, a, z)[1], 11)
    for mode in ("same slot, memory reused", "MKL's release (phase 0) between", "a fresh slot each time"):
        ts = []
        for k in range(repeat):
            slot = 1 + k if mode.startswith("a fresh") else 1
            tic = time.perf_counter()
            linsolve._check_mkl(h.call(22, slot, a, z)[1], 22)
            ts.append(time.perf_counter() - tic)
            if mode.startswith("MKL"):
                h.call(0, slot, np.zeros(0), z)
        for slot in range(1, repeat + 1):
            h.call(0, slot, np.zeros(0), z)
        print(f"{mode:<40} " + " ".join(f"{t:.3f}" for t in ts))
    h.call(-1, 1, a, z)


if __name__ == "__main__":
    main()
