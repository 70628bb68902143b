"""Linear solvers for the Newton iteration matrix, behind one interface (``LinearSolver``).

The time stepper (``dejax.integrate``) factorizes the reduced iteration matrix T^T K T
of the element matrices, carries the factorization through ``lax.scan`` and reuses it
over Newton iterations and steps, and solves exactly (differentiably) for the implicit
derivative of each step. ``DenseSolver`` (Cholesky, LU where the matrix is indefinite)
serves small and fit-scale meshes, ``SparseSolver`` (SuperLU or MKL Pardiso on the host)
large ones; ``choose_solver`` picks one by name or by size.
"""
from __future__ import annotations

import abc
import concurrent.futures
import ctypes
import functools
import warnings
import weakref

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from . import model as mdl
from . import ordering


class LinearSolver(eqx.Module):
    """What the time stepper needs of a linear solver of the reduced iteration matrix
    A = T^T K T. Arguments: ``model`` (``dejax.model.Model``; n_free =
    ``model.structure.n_free`` reduced unknowns), ``Ke`` the element iteration matrices
    (n_el, 96, 96), ``rhs`` (n_free,) (many right-hand sides: ``jax.vmap``). Solvers hold
    static fields only, so that equal solvers hash equal and share one compiled stepper."""

    @abc.abstractmethod
    def factor(self, model, Ke):
        """A factorization of A: a pytree of arrays, carried through ``lax.scan`` and reused
        over Newton iterations and steps."""

    @abc.abstractmethod
    def empty(self, model):
        """A placeholder with the pytree structure, shapes and dtypes of ``factor``'s result."""

    @abc.abstractmethod
    def solve_factored(self, model, fac, rhs):
        """x (n_free,) with A x = rhs, A the matrix ``fac`` factorizes (possibly that of an
        earlier iterate or step). Not differentiated: Newton directions only."""

    @abc.abstractmethod
    def solve(self, model, Ke, rhs):
        """x (n_free,) with A x = rhs, A assembled from ``Ke``: exact and differentiable in
        ``Ke`` and ``rhs`` (jvp and transpose), for the implicit derivative of a step."""


def _lu_from_cholesky(L):
    """The LU storage (unit lower L_u below the diagonal, U on and above it) of A = L L^T:
    L_u = L D^-1, U = D L^T with D = diag(L), so that A = L_u U without pivoting."""
    d = jnp.diagonal(L)
    return jnp.tril(L / d[None, :], -1) + jnp.triu(d[:, None] * L.T)


def dense_factor(A):
    """(lu (n, n), perm (n,)) with A[perm] = L U (L unit lower, both in ``lu``) for a
    symmetric A: Cholesky where A is positive definite (half the work of LU: 5 ms against
    10 ms at 720 unknowns), else LU with partial pivoting (an indefinite matrix: past an
    instability). Under ``jax.vmap`` with a batched A both are computed (``lax.cond``)."""
    L = jax.lax.linalg.cholesky(A, symmetrize_input=False)  # NaN where not positive definite
    n = A.shape[-1]

    def lu():
        lu_, _, perm = jax.lax.linalg.lu(A)
        return lu_, perm

    return jax.lax.cond(jnp.all(jnp.isfinite(jnp.diagonal(L))),
                        lambda: (_lu_from_cholesky(L), jnp.arange(n, dtype=jnp.int32)), lu)


def dense_solve_factored(fac, rhs):
    """x with A x = rhs from ``dense_factor(A)``: two triangular solves, rhs (n,) or (n, k)."""
    # L y = b[perm], U x = y, written with the transposed factor: LAPACK reads its matrix
    # column-major, which the transpose of a row-major (n, n) array is without a copy
    # (solving with lu itself copied it, transposed, at every solve)
    lut, perm = fac[0].T, fac[1]
    b = rhs[perm]
    b2 = b[:, None] if b.ndim == 1 else b
    tri = jax.lax.linalg.triangular_solve
    y = tri(lut, b2, left_side=True, lower=False, transpose_a=True, unit_diagonal=True)
    x = tri(lut, y, left_side=True, lower=True, transpose_a=True)
    return x[:, 0] if rhs.ndim == 1 else x


def dense_solve(A, rhs):
    """x with A x = rhs (A symmetric (n, n), rhs (n,)) by ``dense_factor``, differentiable in
    A and rhs (``jax.lax.custom_linear_solve``: jvp, transpose, vmap)."""
    fac = jax.lax.stop_gradient(dense_factor(A))
    return jax.lax.custom_linear_solve(lambda x: A @ x, rhs, lambda _, b: dense_solve_factored(fac, b), symmetric=True)


def spd_solve(A, rhs):
    """x with A x = rhs for a symmetric positive definite A (n, n) (a mass matrix, a
    regularized Gram matrix), rhs (n,): Cholesky and two triangular solves, differentiable
    in A and rhs (``custom_linear_solve``). No pivoting loop in the compiled program, where
    ``jnp.linalg.solve``'s LU forms its permutation in one."""
    L = jax.lax.stop_gradient(jax.lax.linalg.cholesky(A, symmetrize_input=False))

    def solve(_, b):
        tri = jax.lax.linalg.triangular_solve
        y = tri(L, b[:, None], left_side=True, lower=True)
        return tri(L, y, left_side=True, lower=True, transpose_a=True)[:, 0]

    return jax.lax.custom_linear_solve(lambda x: A @ x, rhs, solve, symmetric=True)


class DenseSolver(LinearSolver):
    """Dense solver of the assembled matrix: for small and fit-scale meshes (up to a few
    thousand unknowns). The iteration matrix is symmetric for every material option
    (viscous dCv/dF and condensed pressures included; tests/test_model.py asserts it):
    ``dense_factor`` factorizes it by Cholesky where it is positive definite and by LU
    with partial pivoting where it is not (past an instability), both backward stable.

    An explicit inverse, tried for speed (a solve becomes one matrix-vector product, 7x to
    12x faster than XLA's CPU triangular solves at 720-1,500 unknowns), lost the torsional
    strip 12x2x2 (K/mu = 4e5): Newton failed its first increment (406 iterations, 17
    cut-backs; with a symmetric diagonal scaling no increment converged in 400 s; the cause
    is not isolated: the inverse's backward error at the reference tangent is 5e-18). The
    scaled inverse with one sweep of iterative refinement against the assembled matrix
    converged there (same twist to 1e-9): a lever to measure on every robustness case
    before it replaces the factorization."""

    def factor(self, model, Ke):
        """(lu (n, n), perm (n,)) of the assembled matrix (``dense_factor``).

        The permutation is formed here, once per factorization: ``jax.scipy.linalg.lu_solve``
        forms it from the pivots at every solve, an n-iteration loop of tiny kernels that
        cost more than both triangular solves together (tube 4x8x1: 720 iterations)."""
        return dense_factor(mdl.assemble_dense(model, Ke))

    def empty(self, model):
        n = model.structure.n_free
        return jnp.eye(n), jnp.arange(n, dtype=jnp.int32)

    def solve_factored(self, model, fac, rhs):
        return dense_solve_factored(fac, rhs)

    def solve(self, model, Ke, rhs):
        return dense_solve(mdl.assemble_dense(model, Ke), rhs)


# ----------------------------------------------------------------------------- sparse


class _FactorCache:
    """Host-side LRU of factorizations keyed by the matrix values, so that
    ``solve_factored(values, rhs)`` is a pure function of its inputs while a factorization
    is reused for as long as the same values are passed (modified Newton). A lookup
    compares a strided sample of the values, then all of them (exact; 4 ms on the paper's
    tube's 3.7 million values, where hashing them cost 21 ms at every solve)."""

    def __init__(self, size: int = 4):
        self.size = size
        self.entries: list = []
        self.factorizations = 0

    def get(self, pattern: mdl.Assembly, values: np.ndarray, backend: str):
        sample = values[:: _SAMPLE_STRIDE]
        for p, b, stored, f in self.entries:
            if p is pattern and b == backend and np.array_equal(stored[:: _SAMPLE_STRIDE], sample) \
                    and np.array_equal(stored, values):
                return f
        if len(self.entries) >= self.size:
            _, _, _, old = self.entries.pop(0)
            getattr(old, "free", lambda: None)()  # MKL keeps a factorization until told to free it
        f = _factorize(pattern, values, backend)
        self.factorizations += 1
        self.entries.append((pattern, backend, values.copy(), f))
        return f

    def clear(self):
        """Free every cached factorization (the next solve of any matrix factorizes)."""
        for *_, f in self.entries:
            getattr(f, "free", lambda: None)()
        self.entries = []


_SAMPLE_STRIDE = 97


_CACHE = _FactorCache()
_HOST_THREAD = concurrent.futures.ThreadPoolExecutor(max_workers=1, thread_name_prefix="dejax-sparse")
"""Every host factorization, solve and eviction runs here (see ``SparseSolver._host_solve``)."""


def _csc(pattern: mdl.Assembly, values: np.ndarray):
    import scipy.sparse as sp

    return sp.csc_matrix((values, pattern.rows, pattern.indptr), shape=(pattern.n, pattern.n))


def assemble_scipy(model, Ke):
    """Host (scipy CSC) copy of the reduced matrix T^T K T of element matrices Ke (n_el, 96, 96)."""
    return _csc(mdl.assembly(model.structure), np.asarray(mdl.assemble_values(model, Ke)))


class _PardisoFactor:
    """An MKL Pardiso LU factorization (pypardiso, real nonsymmetric): call to solve;
    ``free()`` releases MKL's memory (the Python object's garbage collection does not)."""

    def __init__(self, solver, A):
        self.solver, self.A = solver, A
        solver.factorize(A)

    def __call__(self, b):
        return self.solver.solve(self.A, b)

    def free(self):
        self.solver.free_memory(everything=True)


class _UpperPattern:
    """The upper triangle of a structurally symmetric CSC pattern as a zero-based CSR
    pattern (for a symmetric matrix, CSC column j's rows i >= j are CSR row j's columns),
    whose values are ``pattern.upper``'s (``model.assemble_upper``)."""

    def __init__(self, pattern: mdl.Assembly):
        upper = pattern.upper
        self.indices = np.ascontiguousarray(pattern.rows[upper], dtype=np.int32)
        self.indptr = np.searchsorted(pattern.cols[upper], np.arange(pattern.n + 1)).astype(np.int32)
        self.pattern = pattern

    @functools.cached_property
    def full(self) -> np.ndarray:
        """(nnz,) the position in the upper values of every entry of the full CSC pattern
        (its own, or its transpose's): ``upper_values[full]`` is the symmetric matrix's CSC
        value array."""
        rows, cols, n = self.pattern.rows, self.pattern.cols, self.pattern.n
        key = cols.astype(np.int64) * n + rows  # sorted: the CSC order
        mirror = np.searchsorted(key, rows.astype(np.int64) * n + cols)
        if not np.array_equal(key[np.minimum(mirror, key.size - 1)], rows.astype(np.int64) * n + cols):
            raise ValueError("the sparsity pattern is not structurally symmetric")
        number = np.full(key.size, -1, dtype=np.int64)
        number[self.pattern.upper] = np.arange(self.pattern.upper.size)
        return np.where(rows >= cols, number, number[mirror])


class _PardisoPattern:
    """MKL Pardiso's handle for one sparsity pattern: the upper triangle (``_UpperPattern``),
    its symbolic analysis (a nested-dissection ordering, MKL's or dejax's, ``_analyse``;
    phase 11: 0.06-0.11 s on the paper's tube, done once) and up to ``MAX_FACTORS``
    numerical Cholesky factorizations of matrices with that pattern (matrix type 2, real
    symmetric positive definite), each in its own slot.

    A freed slot keeps MKL's memory for the next factorization, which overwrites it: a
    factorization into a slot used before skips the allocation and first touch of its
    factor (R2's matrix, 12.9 million factor entries: 0.155 s against 0.175 s after MKL's
    release, 0.19-0.33 s into fresh slots; ``python bench/pardiso_options.py``)."""

    MAX_FACTORS = 8

    def __init__(self, lib, pattern: mdl.Assembly):
        self.lib, self.upper, self.n = lib, _UpperPattern(pattern), pattern.n
        self.pt = np.zeros(64, dtype=np.int64)
        self.iparm = np.zeros(64, dtype=np.int32)
        self.iparm[0] = 1  # iparm supplied: everything else at MKL's zero meaning
        self.iparm[1] = 2  # nested-dissection ordering (METIS)
        self.iparm[34] = 1  # zero-based ia, ja
        self.free_slots = list(range(1, self.MAX_FACTORS + 1))
        self.analysed = False
        self.perm = None  # the elimination order handed to MKL (iparm[4] = 1), None: MKL's METIS
        self.ordering = None  # the ordering's name, once analysed
        self.factor_mflop = {}  # MKL's operation count of the factorization (MFLOP) by ordering

    def call(self, phase: int, slot: int, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, int]:
        """One call of MKL's ``pardiso`` on matrix ``slot`` (values ``a`` in the upper
        pattern's order, right-hand sides ``b`` (n, k) Fortran order): (x, MKL's error code)."""
        x = np.zeros_like(b)
        err = ctypes.c_int32(0)
        i32, f64 = ctypes.POINTER(ctypes.c_int32), ctypes.POINTER(ctypes.c_double)
        ref = lambda v: ctypes.byref(ctypes.c_int32(v))  # noqa: E731
        self.lib.pardiso(self.pt.ctypes.data_as(ctypes.POINTER(ctypes.c_int64)), ref(self.MAX_FACTORS), ref(slot),
                         ref(2), ref(phase), ref(self.n), a.ctypes.data_as(f64),
                         self.upper.indptr.ctypes.data_as(i32), self.upper.indices.ctypes.data_as(i32),
                         None if self.perm is None else self.perm.ctypes.data_as(i32), ref(b.shape[1]),
                         self.iparm.ctypes.data_as(i32), ref(0), b.ctypes.data_as(f64), x.ctypes.data_as(f64),
                         ctypes.byref(err))
        return x, err.value

    def cholesky(self, upper_values: np.ndarray) -> "_PardisoCholesky | None":
        """The Cholesky factorization of the symmetric matrix with upper triangle
        ``upper_values`` (``model.assemble_upper``'s order), or None where MKL finds it not
        positive definite (error -4)."""
        a = np.ascontiguousarray(upper_values, dtype=np.float64)
        z = np.zeros((self.n, 1), order="F")
        if not self.analysed:
            self._analyse(a, z)
        if not self.free_slots:
            raise RuntimeError("MKL Pardiso: every factorization slot of this pattern is in use")
        slot = self.free_slots.pop()  # the most recently freed: its memory is warm
        err = self.call(22, slot, a, z)[1]
        if err == -4:
            self.release(slot)
            return None
        _check_mkl(err, 22)
        return _PardisoCholesky(self, slot, a)

    def _analyse(self, a: np.ndarray, z: np.ndarray):
        """The symbolic analysis (phase 11) with the ordering MKL counts fewer operations for:
        its own METIS nested dissection, or ``ordering.nested_dissection``'s on the
        pattern's supervariables (R2's matrix: 12.0 against 15.1 GFLOP)."""
        candidates = {"metis": None, "nested dissection": _elimination_order(self.upper.pattern)}

        def analyse(name):
            if self.factor_mflop:  # the previous analysis released first: a fresh handle
                self.call(-1, 1, np.zeros(0), z)
                self.pt[:] = 0
            self.perm = candidates[name]
            self.iparm[4] = 0 if self.perm is None else 1
            self.iparm[18] = -1  # report the factorization's operation count
            _check_mkl(self.call(11, 1, a, z)[1], 11)
            self.factor_mflop[name] = int(self.iparm[18])

        for name in candidates:
            analyse(name)
        best = min(candidates, key=lambda k: self.factor_mflop[k])
        if best != name:  # analysed last with the other one
            analyse(best)
        self.ordering = best
        self.analysed = True

    def release(self, slot: int):
        """Mark ``slot`` free; MKL keeps its memory for the next factorization (see above)."""
        self.free_slots.append(slot)

    def __del__(self):
        # phase -1: MKL releases everything this handle holds (every slot, the analysis),
        # when the pattern's handle is dropped (``_PARDISO`` holds it weakly by the pattern)
        if self.analysed:
            try:
                self.call(-1, 1, np.zeros(0), np.zeros((self.n, 1), order="F"))
            except Exception:  # at interpreter shutdown ctypes may already be gone
                pass


def _check_mkl(err: int, phase: int):
    if err != 0:
        raise RuntimeError(f"MKL Pardiso failed in phase {phase}: error {err}")


class _PardisoCholesky:
    """A Cholesky factorization held in a ``_PardisoPattern``'s slot: call to solve (b (n,)
    or (n, k)); ``free()`` releases the slot. Half the fill and about half the time of the
    LU on the paper's tube (tube 12x20x4: 0.33 s against 0.58 s numerical factorization,
    0.08 s against 0.20 s analysis, 2 cores)."""

    def __init__(self, handle: _PardisoPattern, slot: int, a: np.ndarray):
        self.handle, self.slot, self.a = handle, slot, a

    def __call__(self, b):
        B = np.asfortranarray(b.reshape(self.handle.n, -1), dtype=np.float64)
        x, err = self.handle.call(33, self.slot, self.a, B)
        _check_mkl(err, 33)
        return x.reshape(b.shape)

    def free(self):
        if self.slot:
            self.handle.release(self.slot)
            self.slot = 0


def _mkl():
    """MKL's runtime library (as pypardiso finds it), with ``pardiso``'s argument types."""
    global _MKL
    if _MKL is None:
        import pypardiso  # optional

        lib = pypardiso.PyPardisoSolver().libmkl
        i32 = ctypes.POINTER(ctypes.c_int32)
        lib.pardiso.argtypes = [ctypes.POINTER(ctypes.c_int64), i32, i32, i32, i32, i32, ctypes.c_void_p, i32, i32,
                                i32, i32, i32, i32, ctypes.c_void_p, ctypes.c_void_p, i32]
        lib.pardiso.restype = None
        _MKL = lib
    return _MKL


_MKL = None


def _factorize(pattern: mdl.Assembly, values: np.ndarray, backend: str):
    """A solve function of the matrix with ``values``: CSC values (``model.assemble_values``)
    for SuperLU; for Pardiso the upper triangle of the symmetric matrix
    (``model.assemble_upper``)."""
    if backend == "pardiso":
        import pypardiso  # optional

        handle = _PARDISO.get(pattern)
        if handle is None:
            handle = _PARDISO[pattern] = _PardisoPattern(_mkl(), pattern)
        f = handle.cholesky(values)
        if f is not None:
            return f
        # not positive definite (past an instability): LU of the whole symmetric matrix
        return _PardisoFactor(pypardiso.PyPardisoSolver(), _csc(pattern, values[handle.upper.full]).tocsr())
    return _superlu(pattern, values)


_ORDER: "weakref.WeakKeyDictionary[mdl.Assembly, np.ndarray]" = weakref.WeakKeyDictionary()


def _elimination_order(pattern: mdl.Assembly) -> np.ndarray:
    """``ordering.nested_dissection`` of the pattern, computed once per pattern (Pardiso's
    analysis and SuperLU share it)."""
    order = _ORDER.get(pattern)
    if order is None:
        order = _ORDER[pattern] = ordering.nested_dissection(pattern.n, pattern.rows, pattern.indptr)
    return order


class _SymmetricOrder:
    """The symmetric permutation of a CSC pattern by ``_elimination_order``: ``order`` (n,),
    and the permuted matrix's pattern (``indices``, ``indptr``) with the position in the
    original values of each of its entries (``source``)."""

    def __init__(self, pattern: mdl.Assembly):
        import scipy.sparse as sp

        self.order = _elimination_order(pattern)
        number = sp.csc_matrix((np.arange(1, pattern.nnz + 1, dtype=np.int64), pattern.rows, pattern.indptr),
                               shape=(pattern.n, pattern.n))
        P = number[self.order][:, self.order].tocsc()
        P.sort_indices()
        self.indices, self.indptr, self.source = P.indices, P.indptr, P.data - 1


_SUPERLU_ORDER: "weakref.WeakKeyDictionary[mdl.Assembly, _SymmetricOrder]" = weakref.WeakKeyDictionary()
SUPERLU_BACKWARD_BOUND = 1e-12
"""A SuperLU factorization without pivoting whose solve of a test vector has a larger
normwise backward error ||b - A x|| / (||A||_F ||x|| + ||b||) is made again with COLAMD
and partial pivoting."""


def _superlu(pattern: mdl.Assembly, values: np.ndarray):
    """SuperLU's LU of the CSC matrix ``values``: a solve function (b (n,) or (n, k)).

    In dejax's nested-dissection order with diagonal pivots (``SymmetricMode``, no pivoting
    threshold), checked by a test solve, else (an unstable factorization) COLAMD with
    partial pivoting. R2's matrix (`cd bench && python superlu_ordering.py`, 2026-12-08): 1.9 s
    and 21.8 million entries in L + U against COLAMD's 8.6 s and 47.2 million, backward
    error 2.8e-22 against 6.6e-22. (Any pivoting threshold above zero, 1e-3 to 0.1, pivots
    off the diagonal, the positions' and gradients' scales being apart, and fills 58
    million; SymmetricMode with minimum degree on A^T + A measured 164 s on 2026-12-01 with
    the default threshold.)"""
    import scipy.sparse as sp
    from scipy.sparse.linalg import norm as sparse_norm
    from scipy.sparse.linalg import splu

    A = _csc(pattern, values)
    perm = _SUPERLU_ORDER.get(pattern)
    if perm is None:
        perm = _SUPERLU_ORDER[pattern] = _SymmetricOrder(pattern)
    Ap = sp.csc_matrix((values[perm.source], perm.indices, perm.indptr), shape=A.shape)
    try:
        lu = splu(Ap, permc_spec="NATURAL", diag_pivot_thresh=0.0, options=dict(SymmetricMode=True))
    except RuntimeError:  # singular in this order (SuperLU pivots off a zero diagonal, not off a tiny one)
        lu = None
    if lu is not None:
        order = perm.order

        def solve(b):
            x = np.empty_like(b, dtype=np.float64)
            x[order] = lu.solve(np.ascontiguousarray(b[order], dtype=np.float64))
            return x

        b = np.random.default_rng(0).standard_normal(pattern.n)
        x = solve(b)
        backward = np.linalg.norm(b - A @ x) / (sparse_norm(A) * np.linalg.norm(x) + np.linalg.norm(b))
        if np.isfinite(backward) and backward <= SUPERLU_BACKWARD_BOUND:
            return solve
    return splu(A, permc_spec="COLAMD").solve


_PARDISO: "weakref.WeakKeyDictionary[mdl.Assembly, _PardisoPattern]" = weakref.WeakKeyDictionary()


def _available_backend(requested: str, warn: bool = True) -> str:
    if requested == "pardiso":
        if pardiso_available():
            return "pardiso"
        if warn:
            warnings.warn("pypardiso is not installed: falling back to scipy SuperLU", RuntimeWarning, stacklevel=3)
    return "superlu"


class SparseSolver(LinearSolver):
    """Sparse direct solver for large meshes.

    The sparsity pattern of T^T K T is static (from the connectivity, numpy, once); the
    values are summed from the element matrices inside jit; the factorization runs on the
    host (scipy SuperLU with a COLAMD ordering, or MKL Pardiso if pypardiso is installed
    and it is requested: Cholesky where the matrix is positive definite, LU where not)
    through ``jax.pure_callback``. ``factor`` returns the value array: for Pardiso the
    upper triangle alone (``model.assemble_upper``; the iteration matrix is symmetric, as
    the second derivative of the step's energy with the pressures condensed, asserted for
    every material option in tests/test_model.py): half the gather and no symmetry check
    on the host (N1 0.583/0.573 -> 0.516/0.510 s in alternated runs of ``bench.case_N1``).
    ``solve_factored`` looks the factorization up by those values, so a stale
    factorization carried through the scan is reused without refactoring. ``solve`` is
    wrapped in ``jax.lax.custom_linear_solve`` (symmetric) so jvp, vjp and vmap work.
    """

    backend: str = eqx.field(default="superlu", static=True)

    def _upper(self) -> bool:
        """Whether the values are the upper triangle alone (Pardiso's Cholesky reads it)."""
        return _available_backend(self.backend, warn=False) == "pardiso"

    def factor(self, model, Ke):
        return mdl.assemble_upper(model, Ke) if self._upper() else mdl.assemble_values(model, Ke)

    def empty(self, model):
        a = mdl.assembly(model.structure)
        return jnp.zeros(a.upper.size if self._upper() else a.nnz)

    def _host_solve(self, pattern, values, rhs):
        # on one dedicated thread: XLA runs host callbacks on varying threads, and a SuperLU
        # factorization freed on another thread than the one that made it was never released
        # (+1 factorization of memory per factorization: 22 GB on the 48x8x2 strip;
        # bench/leak_superlu_callback.py)
        return _HOST_THREAD.submit(self._host_solve_here, pattern, np.asarray(values), np.asarray(rhs)).result()

    def _host_solve_here(self, pattern, values, rhs):
        """values (..., nnz), rhs (..., n) with broadcastable leading (vmapped) axes: one
        factorization and one multi-right-hand-side solve where the values are shared (the
        tangent lanes of a forward-mode derivative), else one per matrix."""
        backend = _available_backend(self.backend)
        n, nnz = rhs.shape[-1], values.shape[-1]
        lead = np.broadcast_shapes(values.shape[:-1], rhs.shape[:-1])
        B = np.broadcast_to(rhs, lead + (n,)).reshape(-1, n)
        if values.size == nnz:
            X = _CACHE.get(pattern, values.reshape(nnz), backend)(np.ascontiguousarray(B.T))
            X = X.reshape(n, -1).T
        else:
            V = np.broadcast_to(values, lead + (nnz,)).reshape(-1, nnz)
            X = np.stack([_CACHE.get(pattern, v, backend)(b) for v, b in zip(V, B)])
        return X.reshape(lead + (n,)).astype(rhs.dtype)

    def solve_factored(self, model, values, rhs):
        p = mdl.assembly(model.structure)
        return jax.pure_callback(
            functools.partial(self._host_solve, p), jax.ShapeDtypeStruct(rhs.shape, rhs.dtype), values, rhs,
            vmap_method="expand_dims",  # one host call for all lanes (``_host_solve_here``)
        )

    def solve(self, model, Ke, rhs):
        p = mdl.assembly(model.structure)
        values = self.factor(model, Ke)
        if self._upper():
            matvec = functools.partial(_upper_matvec, p, values)
        else:
            rows, cols = jnp.asarray(p.rows), jnp.asarray(p.cols)

            def matvec(x):
                return jax.ops.segment_sum(values * x[cols], rows, num_segments=p.n)

        def solve(_, b):
            return self.solve_factored(model, jax.lax.stop_gradient(values), b)

        return jax.lax.custom_linear_solve(matvec, rhs, solve, symmetric=True)


def _upper_matvec(pattern: mdl.Assembly, upper_values, x):
    """A x for the symmetric matrix A with upper triangle ``upper_values``
    (``model.assemble_upper``): each off-diagonal entry stands for itself and its mirror."""
    rows, cols = jnp.asarray(pattern.rows[pattern.upper]), jnp.asarray(pattern.cols[pattern.upper])
    half = jnp.where(rows == cols, 0.5, 1.0) * upper_values
    return (jax.ops.segment_sum(half * x[cols], rows, num_segments=pattern.n)
            + jax.ops.segment_sum(half * x[rows], cols, num_segments=pattern.n))


def clear_factorizations() -> None:
    """Drop the sparse solver's cached host factorizations (a benchmark that times a
    factorization calls this between repetitions of the same matrix)."""
    _HOST_THREAD.submit(_CACHE.clear).result()


def host_factorizations() -> int:
    """How many factorizations the sparse solver has made on the host in this process (cache
    hits not counted): a benchmark's check that a timed call factorized what it claims."""
    return _CACHE.factorizations


def pardiso_available() -> bool:
    try:
        import pypardiso  # noqa: F401
    except ImportError:
        return False
    return True


def choose_solver(structure, which: str = "auto") -> LinearSolver:
    """``"dense"``, ``"sparse"`` (SuperLU), ``"pardiso"`` or ``"auto"``: dense up to 2,500
    reduced unknowns (measured faster there), above that MKL Pardiso where pypardiso is
    installed (``pip install -e ".[fast]"``; Cholesky where the matrix is symmetric positive
    definite, ``_PardisoPattern``), else SuperLU (COLAMD). Measured on 2 cores: the paper's
    tube 12x20x4 factorizes in 0.3-0.4 s against SuperLU's 13-16 s; whole runs of the
    torsional strip 24x4x2 (100 steps) 12.0 against 16.2 s and 48x8x2 (30 steps) 8.5
    against 9.7 s. (With Pardiso's LU the 24x4x2 strip had been slower, 34 s against 15 s.)
    On a GPU (any non-CPU backend) ``"auto"`` is dense up to ``DENSE_MAX_ACCELERATOR``
    unknowns."""
    if which == "dense":
        return DenseSolver()
    if which == "sparse":
        return SparseSolver()
    if which == "pardiso":
        return SparseSolver("pardiso")
    if which != "auto":
        raise ValueError(f"linear solver must be auto, dense, sparse or pardiso; got {which!r}")
    if jax.default_backend() != "cpu":
        # on an accelerator the dense factorization stays on the device (the sparse solvers
        # run on the host, a round trip per solve): up to DENSE_MAX_ACCELERATOR unknowns
        return DenseSolver() if structure.n_free <= DENSE_MAX_ACCELERATOR else SparseSolver()
    if structure.n_free <= 2500:
        return DenseSolver()
    return SparseSolver("pardiso" if pardiso_available() else "superlu")


DENSE_MAX_ACCELERATOR = 40_000
"""Largest reduced system ``choose_solver("auto")`` factorizes densely on a GPU: 12.8 GB
per copy of the matrix in float64 (the paper's tube 12x20x4 has 14,100: 1.6 GB)."""
