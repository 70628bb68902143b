"""A block-tridiagonal Cholesky in XLA for the implicit derivative's tangent, against the dense
and MKL Pardiso paths, in one process.

    python bench/banded_solve.py [--shapes 4x8x1] [--repeat 30]

The unknowns are ordered by the level sets of a breadth-first search of the matrix's graph from
a pseudo-peripheral unknown: an entry couples only unknowns of the same or of neighbouring
levels, so the matrix is block tridiagonal with one block per level (padded to the widest).
This pays only where the levels are narrow, as in a slender mesh. The tube 4x8x1 (4 axial by 8
circumferential elements) is not slender: its 720 unknowns fall into 5 levels of at most 288,
about 279 MFLOP against 124 for a dense Cholesky. Timed, for the condensed exact tangent at a
state 20 steps into R1's loading: assembly, factorization and 12 solves (G1's lanes), each path
jitted; and the relative error of each path's solution against numpy's dense LU.

Measured 2026-12-07 (2 cores, CPU reference 1.7 s): banded 18.8-22.8 ms, dense 7.9-8.9 ms,
Pardiso 4.6 ms, every error 3.0e-8 (the reference's own limit). Not kept.
"""
from __future__ import annotations

import argparse

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)

from dejax import linsolve  # noqa: E402
from dejax import model as mdl  # noqa: E402
from derivative_solver import condensed_tangent  # noqa: E402
from profile_step import timed  # noqa: E402


def _levels(rows, cols, n, start):
    """Level of every unknown in a breadth-first search from ``start`` (numpy)."""
    import scipy.sparse as sp
    g = sp.csr_matrix((np.ones(rows.size), (rows, cols)), shape=(n, n))
    g = (g + g.T).tocsr()
    level = np.full(n, -1)
    level[start], front, k = 0, np.array([start]), 0
    while front.size:
        nb = np.unique(g[front].indices)
        nb = nb[level[nb] < 0]
        k += 1
        level[nb] = k
        front = nb
    return level


def block_plan(pattern: mdl.Assembly):
    """(perm, level, local, N, m): the unknowns ordered by level, each unknown's block and its
    place in it, the number of blocks and their (padded) size."""
    n, start, ecc = pattern.n, 0, -1
    while True:  # pseudo-peripheral start: restart from the last level until it stops growing
        level = _levels(pattern.rows, pattern.cols, n, start)
        if level.max() <= ecc:
            break
        ecc = int(level.max())
        last = np.flatnonzero(level == ecc)
        start = int(last[0])
    perm = np.lexsort((np.arange(n), level))
    counts = np.bincount(level)
    local = np.empty(n, dtype=np.int64)
    local[perm] = np.arange(n) - np.concatenate([[0], np.cumsum(counts)[:-1]])[level[perm]]
    return perm, level, local, counts.size, int(counts.max())


class BlockGather:
    """The gathers from the (CSC) value array into the diagonal blocks D (N, m, m) (padding
    rows: the identity) and the sub-diagonal blocks S (N, m, m) (S[k] = A[level k+1, level
    k], S[N-1] = 0)."""

    def __init__(self, pattern: mdl.Assembly):
        perm, level, local, N, m = block_plan(pattern)
        self.N, self.m, self.n = N, m, pattern.n
        zero, one = pattern.nnz, pattern.nnz + 1
        D = np.full((N, m, m), zero, dtype=np.int64)
        D[:, np.arange(m), np.arange(m)] = one  # padding: identity (overwritten where real)
        S = np.full((N, m, m), zero, dtype=np.int64)
        r, c = pattern.rows, pattern.cols
        lr, lc = level[r], level[c]
        same, below = lr == lc, lr == lc + 1
        assert np.all(np.abs(lr - lc) <= 1)
        D[lr[same], local[r[same]], local[c[same]]] = np.flatnonzero(same)
        S[lc[below], local[r[below]], local[c[below]]] = np.flatnonzero(below)
        self.D, self.S = D, S
        # rhs (n,) -> (N, m) and back
        pos = np.full(N * m, self.n, dtype=np.int64)  # self.n: a padded zero
        pos[level * m + local] = np.arange(self.n)
        self.to_blocks, self.from_blocks = pos, level * m + local

    def blocks(self, values):
        v = jnp.concatenate([values, jnp.zeros(1), jnp.ones(1)])
        return v[self.D], v[self.S]

    def rhs(self, b):  # b (n, k) -> (N, m, k)
        return jnp.concatenate([b, jnp.zeros((1,) + b.shape[1:])])[self.to_blocks].reshape(self.N, self.m, -1)

    def back(self, x):  # (N, m, k) -> (n, k)
        return x.reshape(self.N * self.m, -1)[self.from_blocks]


def block_cholesky(D, S):
    """L's diagonal blocks Ld (N, m, m) and sub-diagonal blocks Ls (N, m, m) of the block
    tridiagonal A = L L^T (Ls[k] = L[k+1, k])."""
    tri = jax.lax.linalg.triangular_solve

    def body(C, ds):
        d, s = ds
        Lkk = jax.lax.linalg.cholesky(d - C @ C.T, symmetrize_input=False)
        C1 = tri(Lkk, s, left_side=False, lower=True, transpose_a=True)  # s Lkk^-T
        return C1, (Lkk, C1)

    _, (Ld, Ls) = jax.lax.scan(body, jnp.zeros_like(D[0]), (D, S))
    return Ld, Ls


def block_solve(Ld, Ls, B):
    """X (N, m, k) with L L^T X = B (N, m, k)."""
    tri = jax.lax.linalg.triangular_solve

    def fwd(y_prev, a):
        Lkk, Lprev, b = a
        y = tri(Lkk, b - Lprev @ y_prev, left_side=True, lower=True)
        return y, y

    Lprev = jnp.concatenate([jnp.zeros_like(Ls[:1]), Ls[:-1]])  # L[k, k-1]
    _, Y = jax.lax.scan(fwd, jnp.zeros_like(B[0]), (Ld, Lprev, B))

    def bwd(x_next, a):
        Lkk, Lnext, y = a
        x = tri(Lkk, y - Lnext.T @ x_next, left_side=True, lower=True, transpose_a=True)
        return x, x

    _, X = jax.lax.scan(bwd, jnp.zeros_like(B[0]), (Ld, Ls, Y), reverse=True)
    return X


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--shapes", default="4x8x1")
    ap.add_argument("--repeat", type=int, default=30)
    a = ap.parse_args()
    for sh in a.shapes.split(","):
        shape = tuple(int(x) for x in sh.split("x"))
        m, Kc = condensed_tangent(shape)
        pat = mdl.assembly(m.structure)
        n = pat.n
        bg = BlockGather(pat)
        # per block: its Cholesky m^3/3, the sub-diagonal block's triangular solve (m
        # right-hand sides) m^3 and the Schur update C C^T m^3 (counted as symmetric)
        mflop = bg.N * (7 / 3) * bg.m**3 / 1e6
        print(f"tube {sh}: {n} unknowns, {bg.N} blocks of at most {bg.m} "
              f"(~{mflop:.1f} MFLOP against {n**3 / 3 / 1e6:.0f} dense)")
        A = np.asarray(jax.jit(lambda K: mdl.assemble_dense(m, K))(Kc))
        rng = np.random.default_rng(0)
        B12 = jnp.asarray(rng.standard_normal((12, n)))
        X_ref = np.linalg.solve(A, np.asarray(B12).T).T

        def banded12(K, B):
            Ld, Ls = block_cholesky(*bg.blocks(mdl.assemble_values(m, K)))
            return bg.back(block_solve(Ld, Ls, bg.rhs(B.T))).T

        paths = {"banded": banded12}
        for name, solver in (("dense", linsolve.DenseSolver()), ("pardiso", linsolve.SparseSolver("pardiso"))):
            if name == "pardiso" and not linsolve.pardiso_available():
                continue
            paths[name] = (lambda s: lambda K, B: jax.vmap(lambda b: s.solve_factored(m, s.factor(m, K), b))(B))(solver)
        for name, f in paths.items():
            fj = jax.jit(f)
            t, X = timed(fj, Kc, B12, repeat=a.repeat, before=linsolve.clear_factorizations)
            err = np.max(np.abs(np.asarray(X) - X_ref)) / np.max(np.abs(X_ref))
            print(f"  {name:<8} assembly + factorization + 12 solves {t:6.2f} ms, error {err:.1e}", flush=True)


if __name__ == "__main__":
    main()
