"""A fill-reducing ordering for the sparse Cholesky factorization: nested dissection of a
symmetric sparsity pattern by spectral bisection, on its supervariables.

An ANCF node's 12 coordinates have the same row pattern (every coordinate of a node
couples to every coordinate of the nodes it shares an element with), so the pattern is
compressed to its supervariables (columns with identical row sets) first: R2's 14,100
unknowns are 1,175 supervariables. Each level splits the current set along its graph
Laplacian's Fiedler vector, at the threshold (within the middle half) that gives the
smallest vertex separator for the balance it leaves; the two sides are ordered first, the
separator last. On a structured mesh the Fiedler vector varies along the mesh's longest
direction, so the separators are its node planes (on a tube a ring, then axial lines).

R2's iteration matrix (`cd bench && python pardiso_ordering.py`, 2026-12-08): 12.04 GFLOP
and 11.3 million factor entries against MKL's METIS ordering's 15.14 GFLOP and 12.9
million; ordered in 0.4-0.5 s, once per sparsity pattern. ``linsolve`` hands MKL Pardiso
whichever of the two orderings MKL counts fewer operations for, and SuperLU this one.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.csgraph as csgraph
import scipy.sparse.linalg as sla

DENSE_EIGEN_UP_TO = 2000
"""Sets of at most this many supervariables take their Fiedler vector from a dense
eigensolver; larger ones from a shift-invert Lanczos (scipy's eigsh)."""


def supervariables(n: int, rows: np.ndarray, indptr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(group (n,), first (n_groups,)): the columns of a CSC pattern (n x n; rows (nnz,),
    indptr (n + 1,)) grouped by identical row sets, numbered in order of first appearance,
    and each group's first column."""
    key = {}
    group = np.empty(n, dtype=np.int64)
    first = []
    for j in range(n):
        col = rows[indptr[j]:indptr[j + 1]]
        h = (col.size, hash(col.tobytes()))
        g = key.get(h)
        if g is not None and not np.array_equal(rows[indptr[first[g]]:indptr[first[g] + 1]], col):
            g = None  # a hash collision: a group of its own
        if g is None:
            g = len(first)
            key.setdefault(h, g)
            first.append(j)
        group[j] = g
    return group, np.asarray(first, dtype=np.int64)


def _fiedler(L: sp.csr_matrix) -> np.ndarray:
    """The eigenvector of the connected graph Laplacian L's second-smallest eigenvalue."""
    n = L.shape[0]
    if n <= DENSE_EIGEN_UP_TO:
        return np.linalg.eigh(L.toarray())[1][:, 1]
    w, v = sla.eigsh(L.tocsc(), k=2, sigma=-1e-3, which="LM")
    return v[:, np.argsort(w)[1]]


def _split(A: sp.csr_matrix, weight: np.ndarray, f: np.ndarray, candidates: int = 64):
    """(side, separator) boolean masks: the threshold on f within its middle half (at most
    ``candidates`` tried) whose separator (one side's vertices adjacent to the other side)
    has the least weight for the smaller remaining side's weight; None if no threshold
    separates."""
    fs = np.unique(np.sort(f)[f.size // 4: 3 * f.size // 4 + 1])
    if fs.size > candidates:
        fs = fs[np.linspace(0, fs.size - 1, candidates).astype(int)]
    best = None
    for t in fs:
        a = f <= t
        b = ~a
        touches_b = (A @ b.astype(float)) > 0
        touches_a = (A @ a.astype(float)) > 0
        for sep in (a & touches_b, b & touches_a):
            rest_a, rest_b = weight[a & ~sep].sum(), weight[b & ~sep].sum()
            if min(rest_a, rest_b) <= 0:
                continue
            score = weight[sep].sum() / min(rest_a, rest_b)
            if best is None or score < best[0]:
                best = (score, a, sep)
    return None if best is None else best[1:]


def _dissect(A: sp.csr_matrix, weight: np.ndarray, vertices: np.ndarray, leaf: int, out: list) -> None:
    """Append ``vertices`` (indices into A) to ``out`` in nested-dissection order."""
    if vertices.size <= leaf:
        out.extend(vertices.tolist())
        return
    sub = A[vertices][:, vertices]
    n_parts, label = csgraph.connected_components(sub, directed=False)
    if n_parts > 1:
        for k in range(n_parts):
            _dissect(A, weight, vertices[label == k], leaf, out)
        return
    degree = np.asarray(sub.sum(axis=1)).ravel()
    f = np.round(_fiedler(sp.diags(degree) - sub), 10)  # rounded: equal entries of a symmetric mesh tie
    cut = _split(sub, weight[vertices], f)
    if cut is None:
        out.extend(vertices.tolist())
        return
    side, sep = cut
    _dissect(A, weight, vertices[side & ~sep], leaf, out)
    _dissect(A, weight, vertices[~side & ~sep], leaf, out)
    out.extend(vertices[sep].tolist())


def nested_dissection(n: int, rows: np.ndarray, indptr: np.ndarray, leaf: int = 4) -> np.ndarray:
    """(n,) elimination order (the original index of each position) of the symmetric
    pattern in CSC form (rows (nnz,), indptr (n + 1,); both triangles): nested dissection on
    the supervariables down to sets of ``leaf`` of them, each supervariable's columns kept
    together in their original order."""
    rows, indptr = np.asarray(rows), np.asarray(indptr)
    group, first = supervariables(n, rows, indptr)
    n_groups = first.size
    # the groups' adjacency from each group's first column (every column of a group has its rows)
    length = indptr[first + 1] - indptr[first]
    at = np.repeat(indptr[first] - np.cumsum(length) + length, length) + np.arange(int(length.sum()))
    g_r, g_c = group[rows[at]], np.repeat(np.arange(n_groups), length)
    off = g_r != g_c
    A = sp.csr_matrix((np.ones(int(off.sum())), (g_r[off], g_c[off])), shape=(n_groups, n_groups))
    A.data[:] = 1.0  # duplicates summed: back to an adjacency
    weight = np.bincount(group, minlength=n_groups).astype(float)
    order_groups: list = []
    _dissect(A, weight, np.arange(n_groups), leaf, order_groups)
    rank = np.empty(n_groups, dtype=np.int64)
    rank[np.asarray(order_groups, dtype=np.int64)] = np.arange(n_groups)
    return np.lexsort((np.arange(n), rank[group])).astype(np.int32)
