"""The fill-reducing ordering (``dejax.ordering``): supervariables, a permutation, less fill
than independent orderings where nested dissection should win, and MKL Pardiso handed the
cheaper of its own ordering and this one."""
import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.csgraph import reverse_cuthill_mckee
from scipy.sparse.linalg import norm as sparse_norm, spsolve

from dejax import linsolve, ordering, scenarios
from dejax import model as mdl
from helpers import tube_system  # noqa: E402  (tests/helpers.py)


def _grid_pattern(dims, dofs):
    """CSC pattern of a structured grid of nodes (dims (3,)) coupled to their 26 neighbours,
    ``dofs`` unknowns per node (node-major)."""
    X = np.stack(np.meshgrid(*[np.arange(d) for d in dims], indexing="ij"), -1).reshape(-1, 3)
    near = np.max(np.abs(X[:, None, :] - X[None, :, :]), axis=-1) <= 1
    A = sp.kron(sp.csr_matrix(near.astype(float)), np.ones((dofs, dofs))).tocsc()
    A.sort_indices()
    return A


def _cholesky_fill(A, order):
    """Entries of the dense Cholesky factor of an SPD matrix with A's pattern (its graph
    Laplacian plus the identity) in the elimination order ``order``: numpy, independent of
    the ordering code."""
    M = -A.toarray()
    np.fill_diagonal(M, 0.0)
    np.fill_diagonal(M, -M.sum(axis=1) + 1.0)
    L = np.linalg.cholesky(M[np.ix_(order, order)])
    return int(np.sum(np.abs(L) > 1e-13 * np.abs(L).max()))


def _pardiso_of_tube(shape):
    """(factorization, its pattern's Pardiso handle, check) for the iteration matrix of the
    tube ``shape`` (``helpers.tube_system``) factorized by MKL Pardiso; check(f) is whether
    f's solve of a random right-hand side has a backward error (Frobenius norm of A) at
    most 10x that of scipy's LU."""
    m, Ke = tube_system(shape)
    pattern = mdl.assembly(m.structure)
    values = np.asarray(mdl.assemble_values(m, Ke))
    f = linsolve._factorize(pattern, values[pattern.upper], "pardiso")
    A = linsolve._csc(pattern, values)
    b = np.random.default_rng(1).standard_normal(pattern.n)

    def backward(y):
        return np.linalg.norm(A @ y - b) / (sparse_norm(A) * np.linalg.norm(y))

    return f, linsolve._PARDISO[pattern], lambda g: backward(g(b)) <= 10.0 * max(backward(spsolve(A, b)), 1e-17)


@pytest.mark.parametrize("shape", [(2, 4, 1), (2, 4, 2)])
def test_supervariables_of_the_tube_are_its_nodes(shape):
    """A node's free coordinates share one row pattern (a supervariable), and nodes share
    one only where they lie in the same elements (one element through the wall: the inner
    and outer node of each column): checked against the connectivity."""
    m = scenarios.rolled("IV", 30.0, 50e3, shape=shape).model
    a = mdl.assembly(m.structure)
    group, first = ordering.supervariables(a.n, a.rows, a.indptr)
    node = np.asarray(m.structure.free) // 12
    elements_of = {int(k): frozenset(np.flatnonzero((m.structure.conn == k).any(axis=1))) for k in np.unique(node)}
    group_of_node = {}
    for k, g in zip(node, group):
        assert group_of_node.setdefault(int(k), int(g)) == g  # one group per node
    for g in range(first.size):
        members = {int(k) for k in node[group == g]}
        assert len({elements_of[k] for k in members}) == 1
    if shape[2] == 2:  # every node column has distinct element sets: one node per group
        assert first.size == len(elements_of)


@pytest.mark.parametrize("dims, dofs, dense_up_to", [((30, 30, 1), 2, 2000), ((8, 8, 8), 3, 2000),
                                                    ((30, 30, 1), 2, 100)])
def test_nested_dissection_fills_less_than_natural_and_rcm_orderings(dims, dofs, dense_up_to, monkeypatch):
    """On square and cubic grids (where nested dissection is asymptotically better than any
    banded ordering) the order is a permutation keeping each node's unknowns together and
    its Cholesky factor has fewer entries than with the natural (lexicographic) ordering
    and with scipy's reverse Cuthill-McKee (measured: 87,012 against 109,956 and 128,990 on
    the 30 x 30 grid; 263,532 against 297,408 and 370,200 on the 8^3 cube). The last case
    takes the Fiedler vectors of sets above 100 supervariables from the sparse eigensolver
    (the path of meshes above ``DENSE_EIGEN_UP_TO`` nodes)."""
    monkeypatch.setattr(ordering, "DENSE_EIGEN_UP_TO", dense_up_to)
    A = _grid_pattern(dims, dofs)
    n = A.shape[0]
    order = ordering.nested_dissection(n, A.indices, A.indptr)
    assert order.shape == (n,) and np.array_equal(np.sort(order), np.arange(n))
    blocks = order.reshape(-1, dofs) // dofs
    assert np.all(blocks == blocks[:, :1])  # a node's unknowns stay side by side
    nd = _cholesky_fill(A, order)
    assert nd < _cholesky_fill(A, np.arange(n))
    assert nd < _cholesky_fill(A, reverse_cuthill_mckee(A.tocsr(), symmetric_mode=True))


def test_pardiso_takes_the_ordering_with_fewer_operations():
    """MKL Pardiso's analysis counts the factorization's operations for its METIS ordering
    and for dejax's, and keeps the cheaper; on the tube 8x12x2 that is dejax's (MKL's counts:
    586 against 645 MFLOP), and the factorization with it solves to round-off."""
    pytest.importorskip("pypardiso")
    f, handle, solves_as_scipy = _pardiso_of_tube((8, 12, 2))
    counts = handle.factor_mflop
    assert set(counts) == {"metis", "nested dissection"}
    assert handle.ordering == min(counts, key=counts.get) == "nested dissection"
    assert counts["nested dissection"] < counts["metis"]
    assert solves_as_scipy(f)
    f.free()


def test_pardiso_keeps_metis_where_dejax_ordering_is_worse(monkeypatch):
    """With a random permutation in place of dejax's ordering MKL counts more operations for
    it, so the analysis is made again with METIS (MKL's memory of the first released), and
    the factorization solves as well as scipy's LU."""
    pytest.importorskip("pypardiso")
    monkeypatch.setattr(ordering, "nested_dissection",
                        lambda n, rows, indptr, leaf=4: np.random.default_rng(0).permutation(n).astype(np.int32))
    f, handle, solves_as_scipy = _pardiso_of_tube((3, 8, 1))  # a pattern no other test analyses
    assert handle.ordering == "metis" and handle.perm is None
    assert handle.factor_mflop["metis"] < handle.factor_mflop["nested dissection"]
    assert solves_as_scipy(f)
    f.free()
