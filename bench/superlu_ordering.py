"""scipy's SuperLU on R2's iteration matrix (tube 12 x 20 x 4): COLAMD with partial pivoting
(dejax's choice before 2026-12-08) against dejax's nested-dissection order with diagonal
pivots (``linsolve._superlu``), and symmetric-mode pivoting thresholds above zero; also a
matrix made indefinite by one negated diagonal entry. The sparse path of a machine without
MKL (``pip install dejax`` without the ``fast`` extra).

    cd bench && python superlu_ordering.py

Prints per variant: the factorization's time, the entries of L + U and the normwise
backward error of a solve, ||b - A x|| / (||A||_F ||x||).

Measured 2026-12-08 (2 cores, CPU reference 1.2-1.4 s): COLAMD 8.59 s, 47.2 million, 6.6e-22;
nested dissection without pivoting 1.84-1.93 s, 21.8 million, 2.8e-22 (the indefinite
matrix 2.00 s, 2.8e-22); with thresholds 1e-3, 1e-2, 0.1: 10.5-11.5 s, 58.5-59.2 million
(the threshold pivots off the diagonal: positions and gradients have different scales).
"""
import time

import numpy as np
import scipy.sparse.linalg as sla

from pardiso_options import r2_matrix

from dejax import linsolve, ordering


def main():
    pattern, values = r2_matrix()
    A = linsolve._csc(pattern, values)
    order = ordering.nested_dissection(pattern.n, pattern.rows, pattern.indptr)
    diag = np.flatnonzero(pattern.rows == pattern.cols)
    indefinite = values.copy()
    indefinite[diag[diag.size // 2]] *= -1.0
    b = np.random.default_rng(0).standard_normal(pattern.n)

    def report(name, M, **kw):
        tic = time.perf_counter()
        lu = sla.splu(M, **kw)
        t = time.perf_counter() - tic
        x = lu.solve(b)
        backward = np.linalg.norm(b - M @ x) / (sla.norm(M) * np.linalg.norm(x))
        print(f"{name:44s} {t:6.2f} s  L+U {lu.L.nnz + lu.U.nnz:>10d}  backward error {backward:.1e}", flush=True)

    print(f"R2 matrix: n = {pattern.n}, nnz = {pattern.nnz}")
    report("COLAMD, partial pivoting", A, permc_spec="COLAMD")
    for thresh in (0.0, 1e-3, 1e-2, 1e-1):
        for label, v in (("", values), (", indefinite", indefinite)):
            M = linsolve._csc(pattern, v)[order][:, order].tocsc()
            report(f"nested dissection, threshold {thresh:g}{label}", M, permc_spec="NATURAL",
                   diag_pivot_thresh=thresh, options=dict(SymmetricMode=True))


if __name__ == "__main__":
    main()
