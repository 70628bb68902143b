"""MKL Pardiso's Cholesky of R2's iteration matrix (tube 12 x 20 x 4) with MKL's own
nested-dissection ordering (METIS on the 14,100-unknown graph) against dejax's
(``ordering.nested_dissection``: spectral nested dissection on the 1,175 supervariables,
handed to MKL with ``iparm[4] = 1``), in one process, the factorizations alternated.

    cd bench && python pardiso_ordering.py [--repeat 10]

Prints per ordering: the time to compute it, the analysis, the factor's nonzeros and MKL's
MFLOP count (iparm 18/19), the factorizations' best and median times, and the solve's
relative residual.

Measured 2026-12-08 (2 cores, CPU reference 1.2-1.4 s): see docs/performance.md. A
geometric nested dissection of the tube's node-column grid (rings, then axial lines)
gave 13.4 GFLOP, the spectral one without the separator search (split at the median)
16.8 GFLOP.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from pardiso_options import r2_matrix

from dejax import linsolve, ordering


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=10)
    args = ap.parse_args()
    lib = linsolve._mkl()
    pattern, values = r2_matrix()
    tic = time.perf_counter()
    order = ordering.nested_dissection(pattern.n, pattern.rows, pattern.indptr)
    order_s = time.perf_counter() - tic
    a = np.ascontiguousarray(values[pattern.upper])
    z = np.zeros((pattern.n, 1), order="F")
    handles, info = {}, {}
    for name, perm in (("METIS (MKL's)", None), ("dejax nested dissection", order)):
        h = linsolve._PardisoPattern(lib, pattern)
        h.perm, h.iparm[4] = perm, 0 if perm is None else 1
        h.iparm[17] = h.iparm[18] = -1  # report the factor's nonzeros and operations
        tic = time.perf_counter()
        linsolve._check_mkl(h.call(11, 1, a, z)[1], 11)
        info[name] = [time.perf_counter() - tic, int(h.iparm[17]), int(h.iparm[18])]
        handles[name] = h
    times = {name: [] for name in handles}
    for _ in range(args.repeat):
        for name, h in handles.items():
            tic = time.perf_counter()
            linsolve._check_mkl(h.call(22, 1, a, z)[1], 22)
            times[name].append(time.perf_counter() - tic)
    A = linsolve._csc(pattern, values)
    b = np.asfortranarray(np.random.default_rng(0).standard_normal((pattern.n, 1)))
    print(f"R2 matrix: n = {pattern.n}, nnz = {values.size}; dejax's ordering computed in {order_s:.2f} s")
    print(f"{'ordering':<26} {'analysis s':>10} {'nnz(L)':>10} {'GFLOP':>6} {'factor s best':>13} {'median':>7} "
          f"{'residual':>9}")
    for name, h in handles.items():
        x, err = h.call(33, 1, a, b)
        linsolve._check_mkl(err, 33)
        res = np.linalg.norm(A @ x[:, 0] - b[:, 0]) / np.linalg.norm(b)
        an, nnz, mflop = info[name]
        print(f"{name:<26} {an:10.3f} {nnz:10d} {mflop / 1e3:6.2f} {min(times[name]):13.3f} "
              f"{np.median(times[name]):7.3f} {res:9.1e}")
        h.call(-1, 1, a, z)


if __name__ == "__main__":
    main()
