"""The sparse direct solver path agrees with the dense one, forward and in derivatives."""
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from dejax import integrate as it
from dejax import linsolve, scenarios
from dejax import model as mdl
from helpers import tube_system  # noqa: E402  (tests/helpers.py)

# one compiled program, not hundreds of eagerly dispatched operations (20-30 s each call)
element_tangents = eqx.filter_jit(mdl.element_tangents)


@pytest.fixture(scope="module")
def problem():
    return scenarios.block(phi_max=12e3, shape=(1, 1, 1), t_ramp=0.05)


@pytest.mark.parametrize("volumetric", ["mixed", "displacement"])
def test_sparse_solve_equals_dense_and_transposes(volumetric):
    """Both solvers are backward stable on the block's iteration matrix (residual at
    round-off) and agree to within its condition number times the machine epsilon."""
    m = scenarios.block(phi_max=12e3, shape=(1, 1, 1), t_ramp=0.05, volumetric=volumetric).model
    E = mdl.nominal_field(m, jnp.array([8e3]))
    q = m.q0 + 1e-5 * jax.random.normal(jax.random.PRNGKey(1), m.q0.shape)
    _, Ke, _ = element_tangents(m, q, E, mdl.initial_viscous_state(m), 1e-3)
    Ke = Ke + 1e3 * mdl.mass_elements(m)
    K = np.asarray(mdl.assemble_dense(m, Ke))
    b = jax.random.normal(jax.random.PRNGKey(2), (m.structure.n_free,))
    xd = linsolve.DenseSolver().solve(m, Ke, b)
    sp = linsolve.SparseSolver()
    xs = sp.solve(m, Ke, b)
    xf = sp.solve_factored(m, sp.factor(m, Ke), b)
    bound = 10 * np.linalg.cond(K) * np.finfo(float).eps
    for x in (xd, xs, xf):
        x = np.asarray(x)
        assert np.linalg.norm(K @ x - np.asarray(b)) <= 1e-13 * np.linalg.norm(K, 2) * np.linalg.norm(x)
    for x in (xs, xf):
        assert np.linalg.norm(np.asarray(x) - np.asarray(xd)) <= bound * np.linalg.norm(np.asarray(xd))
    # derivative with respect to the right-hand side (custom_linear_solve transposition)
    c = jax.random.normal(jax.random.PRNGKey(3), b.shape)
    gd = jax.grad(lambda b: c @ linsolve.DenseSolver().solve(m, Ke, b))(b)
    gs = jax.grad(lambda b: c @ sp.solve(m, Ke, b))(b)
    assert np.linalg.norm(np.asarray(gs) - np.asarray(gd)) <= bound * np.linalg.norm(np.asarray(gd))


def test_dense_factor_cholesky_where_positive_definite_lu_where_not():
    """A symmetric positive definite matrix is factorized without pivoting (Cholesky: LU
    with partial pivoting would swap its rows), an indefinite one with pivoting; both
    solve to round-off, and the differentiable solve's jvp (in the matrix and the
    right-hand side) and transpose equal those of jnp.linalg.solve."""
    rng = np.random.default_rng(0)
    L = np.tril(rng.standard_normal((12, 12))) + 3.0 * np.eye(12)
    L[0, 0] = 0.01  # A[0, 0] = 1e-4 < |A[i, 0]| = 0.01 |L[i, 0]|: partial pivoting swaps rows
    spd = L @ L.T
    Q, _ = np.linalg.qr(rng.standard_normal((12, 12)))
    indef = Q @ np.diag(np.linspace(-5.0, 7.0, 12) + 0.3) @ Q.T
    assert np.linalg.eigvalsh(spd).min() > 0 and np.linalg.eigvalsh(indef).min() < 0
    assert int(jax.lax.linalg.lu(jnp.asarray(spd))[2][0]) != 0  # LU would pivot
    f = jax.jit(linsolve.dense_factor)
    b = rng.standard_normal(12)
    for A, pivoted in ((spd, False), (indef, True)):
        lu, perm = f(jnp.asarray(A))
        assert bool(np.any(np.asarray(perm) != np.arange(12))) == pivoted
        x = np.asarray(linsolve.dense_solve_factored((lu, perm), jnp.asarray(b)))
        assert np.linalg.norm(A @ x - b) <= 1e-13 * np.linalg.norm(A, 2) * np.linalg.norm(x)
        X = np.asarray(linsolve.dense_solve_factored((lu, perm), jnp.asarray(np.stack([b, 2 * b], 1))))
        np.testing.assert_allclose(X, np.stack([x, 2 * x], 1), rtol=1e-12)

    solve = linsolve.dense_solve  # DenseSolver.solve of the assembled matrix
    dA = rng.standard_normal((12, 12))
    dA = dA + dA.T
    c = rng.standard_normal(12)
    for A in (spd, indef):
        args, tans = (jnp.asarray(A), jnp.asarray(b)), (jnp.asarray(dA), jnp.asarray(c))
        x, dx = jax.jvp(solve, args, tans)
        x_ref, dx_ref = jax.jvp(jnp.linalg.solve, args, tans)
        np.testing.assert_allclose(np.asarray(x), np.asarray(x_ref), rtol=1e-10)
        np.testing.assert_allclose(np.asarray(dx), np.asarray(dx_ref), rtol=1e-9)
        g = jax.grad(lambda b_: c @ solve(args[0], b_))(args[1])
        g_ref = jax.grad(lambda b_: c @ jnp.linalg.solve(args[0], b_))(args[1])
        np.testing.assert_allclose(np.asarray(g), np.asarray(g_ref), rtol=1e-9)


def test_sparse_simulation_matches_dense(problem):
    times = it.time_grid(0.1, 5e-3)
    out = {}
    for solver in (linsolve.DenseSolver(), linsolve.SparseSolver()):
        sol = it.simulate(problem.model, problem.loading, times, problem.output_fn, solver=solver).check()
        out[type(solver).__name__] = np.asarray(sol.outputs["lateral_stretch"])
    np.testing.assert_allclose(out["SparseSolver"], out["DenseSolver"], rtol=1e-10)


def test_choose_solver():
    s = scenarios.block().model.structure
    assert isinstance(linsolve.choose_solver(s), linsolve.DenseSolver)
    assert isinstance(linsolve.choose_solver(s, "sparse"), linsolve.SparseSolver)
    with pytest.raises(ValueError, match="linear solver must be"):
        linsolve.choose_solver(s, "magic")


def test_choose_solver_on_an_accelerator(monkeypatch):
    """On a GPU "auto" stays dense (on the device) up to DENSE_MAX_ACCELERATOR unknowns,
    the paper's tube 12x20x4 (14,100) included, where the CPU takes the host's sparse solver;
    an explicit choice is kept."""
    from types import SimpleNamespace

    tube, huge = SimpleNamespace(n_free=14_100), SimpleNamespace(n_free=linsolve.DENSE_MAX_ACCELERATOR + 1)
    monkeypatch.setattr(jax, "default_backend", lambda: "cpu")
    assert isinstance(linsolve.choose_solver(tube), linsolve.SparseSolver)
    for installed in (True, False):  # the CPU's sparse solver: Pardiso where installed, else SuperLU
        monkeypatch.setattr(linsolve, "pardiso_available", lambda: installed)
        assert linsolve.choose_solver(tube).backend == ("pardiso" if installed else "superlu")
    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    assert isinstance(linsolve.choose_solver(tube), linsolve.DenseSolver)
    assert isinstance(linsolve.choose_solver(huge), linsolve.SparseSolver)
    assert isinstance(linsolve.choose_solver(tube, "sparse"), linsolve.SparseSolver)


@pytest.mark.slow
def test_grad_through_sparse_solver_viscous_matches_finite_differences():
    """Reverse mode through the sparse path on a viscous model: custom_linear_solve with
    the symmetric iteration matrix (asserted for every material option in test_model.py)
    transposes correctly. d lambda(t_end) / d eta_1 of the paper's viscous block
    (about 1.5 minutes of compilation: run with --runslow)."""
    times = it.time_grid(0.04, 1e-2)

    def final_stretch(eta):
        p = scenarios.block(phi_max=16e3, t_ramp=0.05, material=scenarios.block_material(eta=[eta]))
        sol = it.simulate(p.model, p.loading, times, p.output_fn, solver=linsolve.SparseSolver(), control=None)
        return sol.outputs["lateral_stretch"][-1]

    eta = 3000.0
    g = float(jax.grad(final_stretch)(eta))
    h = 1e-3 * eta
    fd = (float(final_stretch(eta + h)) - float(final_stretch(eta - h))) / (2 * h)
    assert g == pytest.approx(fd, rel=1e-5)
    assert abs(g) > 0



def test_dense_solver_converges_the_torsional_strip_first_increment():
    """Regression: with an explicit-inverse dense solve (tried for speed) Newton failed the
    first increment of the 12x2x2 strip (406 iterations, 17 cut-backs); LU takes 4."""
    p = scenarios.torsional(0.5, 1.0, viscous=False, shape=(12, 2, 2))
    assert isinstance(linsolve.choose_solver(p.model.structure), linsolve.DenseSolver)
    sol = it.simulate(p.model, p.loading, np.array([0.0, 0.1]), p.output_fn, it.QuasiStatic(), it.NewtonOptions(),
                      solver=linsolve.DenseSolver())
    assert sol.ok and sol.n_cutbacks == 0
    assert int(np.asarray(sol.iterations)[0]) <= 6


def _rss_bytes():
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmRSS"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


def test_sparse_factorizations_through_the_callback_are_freed():
    """Regression: every factorization made through the host callback stayed resident
    (~30 MB each here; 22 GB on the paper's torsional strip). 15 factorizations of the
    24x4x2 strip's tangent (cache of 4; leaked: ~450 MB) must not grow the process by more
    than a few."""
    if _rss_bytes() is None:
        pytest.skip("needs /proc/self/status")
    m = scenarios.torsional(0.5, 1.0, viscous=False, shape=(24, 4, 2)).model
    E = mdl.nominal_field(m, jnp.zeros(m.field_dirs.shape[0]))
    Ke = element_tangents(m, m.q0, E, mdl.initial_viscous_state(m), 1.0, mdl.initial_pressure(m))[1]
    solver = linsolve.SparseSolver()
    values = solver.factor(m, Ke)
    b = jnp.asarray(np.random.default_rng(0).standard_normal(m.structure.n_free))
    solve = jax.jit(lambda v, r: solver.solve_factored(m, v, r))
    for k in range(6):  # warm up: compilation, the cache filled
        jax.block_until_ready(solve(values * (1.0 + 1e-3 * k), b))
    before = _rss_bytes()
    for k in range(15):
        jax.block_until_ready(solve(values * (1.0 + 1e-3 * (k + 10)), b))
    assert _rss_bytes() - before < 200e6


def test_every_solver_offers_the_linear_solver_interface():
    """choose_solver returns LinearSolver modules: abstract base, equal solvers hash equal
    (one compiled stepper), and ``empty`` has the structure of ``factor`` (carried through
    lax.scan in its place)."""
    with pytest.raises(TypeError, match="abstract"):
        linsolve.LinearSolver()

    class Partial(linsolve.LinearSolver):
        def factor(self, model, Ke):
            return Ke

    with pytest.raises(TypeError, match="abstract"):
        Partial()
    m = scenarios.block(shape=(1, 1, 1)).model
    Ke = element_tangents(m, m.q0, mdl.nominal_field(m, jnp.zeros(1)), mdl.initial_viscous_state(m), 1e-3)[1]
    for which in ("auto", "dense", "sparse", "pardiso"):
        solver = linsolve.choose_solver(m.structure, which)
        assert isinstance(solver, linsolve.LinearSolver)
        again = linsolve.choose_solver(m.structure, which)
        assert solver == again and hash(solver) == hash(again) and not jax.tree_util.tree_leaves(solver)
        shape = lambda tree: jax.tree_util.tree_map(lambda a: (a.shape, a.dtype), tree)  # noqa: E731
        assert shape(solver.empty(m)) == shape(solver.factor(m, Ke)), which
    assert linsolve.SparseSolver("pardiso") != linsolve.SparseSolver()


def test_pardiso_cholesky_of_a_symmetric_positive_definite_matrix():
    """MKL Pardiso factorizes the symmetric positive definite iteration matrix by Cholesky
    of its upper triangle (``model.assemble_upper``, the entries of the whole CSC matrix
    with row >= column), one symbolic analysis shared by every factorization of the
    pattern: solves (one and several right-hand sides) to the same backward error as
    scipy's LU on the whole matrix; a matrix that is not positive definite falls back to LU
    and still solves; slots are released, so more factorizations than slots never fail."""
    pytest.importorskip("pypardiso")
    m, Ke = tube_system()
    values, pattern = np.asarray(mdl.assemble_values(m, Ke)), mdl.assembly(m.structure)
    upper = np.asarray(mdl.assemble_upper(m, Ke))
    np.testing.assert_array_equal(upper, values[pattern.rows >= pattern.cols])
    mirrored = upper[linsolve._UpperPattern(pattern).full]  # the whole matrix from its upper triangle
    assert np.max(np.abs(mirrored - values)) <= 1e-13 * np.max(np.abs(values))  # symmetric to round-off
    A = linsolve._csc(pattern, values)
    b = np.random.default_rng(0).standard_normal((pattern.n, 3))

    def backward_error(A, x, b):
        return np.linalg.norm(A @ x - b) / (np.linalg.norm(A.toarray(), 2) * np.linalg.norm(x))

    f = linsolve._factorize(pattern, upper, "pardiso")
    assert isinstance(f, linsolve._PardisoCholesky)
    x = f(b[:, 0])
    assert x.shape == (pattern.n,) and backward_error(A, x, b[:, 0]) < 1e-14
    X = f(b)
    assert X.shape == b.shape and np.max(np.abs(X[:, 0] - x)) <= 1e-12 * np.max(np.abs(x))
    assert backward_error(A, X[:, 2], b[:, 2]) < 1e-14
    # a second matrix of the same pattern in another slot; the first still solves
    g = linsolve._factorize(pattern, 2.0 * upper, "pardiso")
    assert isinstance(g, linsolve._PardisoCholesky) and g.slot != f.slot
    assert np.max(np.abs(2.0 * g(b[:, 0]) - x)) <= 1e-9 * np.max(np.abs(x))
    assert np.array_equal(f(b[:, 0]), x)
    f.free(), g.free()

    # indefinite (one diagonal entry negated): LU of the whole symmetric matrix
    diag = np.flatnonzero(pattern.rows == pattern.cols)
    indef = values.copy()
    indef[diag[diag.size // 2]] *= -1.0
    f = linsolve._factorize(pattern, indef[pattern.upper], "pardiso")
    assert isinstance(f, linsolve._PardisoFactor)
    assert backward_error(linsolve._csc(pattern, indef), f(b[:, 0]), b[:, 0]) < 1e-12
    f.free()

    handle = linsolve._PARDISO[pattern]
    for k in range(2 * handle.MAX_FACTORS):
        linsolve._factorize(pattern, (1.0 + k) * upper, "pardiso").free()
    assert sorted(handle.free_slots) == list(range(1, handle.MAX_FACTORS + 1))


def test_pardiso_solver_through_the_callback_equals_dense():
    """``SparseSolver("pardiso")`` inside jit (host callback, factorization cache) solves the
    tube's iteration matrix as the dense solver does, and a repeated solve reuses the
    factorization."""
    pytest.importorskip("pypardiso")
    m, Ke = tube_system()
    K = np.asarray(mdl.assemble_dense(m, Ke))
    b = jnp.asarray(np.random.default_rng(1).standard_normal(m.structure.n_free))
    solver = linsolve.SparseSolver("pardiso")
    solve = jax.jit(lambda v, r: solver.solve_factored(m, v, r))
    values = solver.factor(m, Ke)
    linsolve.clear_factorizations()
    before = linsolve._CACHE.factorizations
    x1, x2 = np.asarray(solve(values, b)), np.asarray(solve(values, 2.0 * b))
    assert linsolve._CACHE.factorizations == before + 1
    xd = np.asarray(linsolve.DenseSolver().solve(m, Ke, b))
    bound = 10 * np.linalg.cond(K) * np.finfo(float).eps
    assert np.linalg.norm(x1 - xd) <= bound * np.linalg.norm(xd)
    assert np.max(np.abs(x2 - 2.0 * x1)) <= 1e-12 * np.max(np.abs(x1))
    # the differentiable solve, whose matrix-vector product reads the upper triangle alone:
    # d/ds (s K)^-1 b = -K^-1 b at s = 1 (its jvp applies the product to x)
    xs, dxs = jax.jit(jax.jvp, static_argnums=0)(lambda s: solver.solve(m, s * Ke, b), (1.0,), (1.0,))
    assert np.linalg.norm(np.asarray(xs) - xd) <= bound * np.linalg.norm(xd)
    assert np.linalg.norm(np.asarray(dxs) + xd) <= bound * np.linalg.norm(xd)
    Kx = np.asarray(jax.jit(lambda v: linsolve._upper_matvec(mdl.assembly(m.structure), v, b))(values))
    assert np.max(np.abs(Kx - K @ np.asarray(b))) <= 1e-12 * np.max(np.abs(K @ np.asarray(b)))


def test_vmapped_sparse_solve_shares_one_factorization():
    """Under ``jax.vmap`` the callback sees every lane at once: right-hand sides over one
    matrix are solved by one factorization (the tangent lanes of a forward-mode
    derivative), each equal to its own unbatched solve; lanes over different matrices
    (batched values) are each solved with their own matrix, checked against numpy."""
    m = scenarios.block(phi_max=12e3, shape=(1, 1, 1), t_ramp=0.05).model
    E = mdl.nominal_field(m, jnp.array([8e3]))
    _, Ke, _ = element_tangents(m, m.q0, E, mdl.initial_viscous_state(m), 1e-3)
    Ke = Ke + 1e3 * mdl.mass_elements(m)
    sp = linsolve.SparseSolver()
    values = sp.factor(m, Ke)
    B = jnp.asarray(np.random.default_rng(4).standard_normal((5, m.structure.n_free)))
    linsolve.clear_factorizations()
    before = linsolve._CACHE.factorizations
    X = np.asarray(jax.jit(jax.vmap(lambda b: sp.solve_factored(m, values, b)))(B))
    assert linsolve._CACHE.factorizations == before + 1
    for x, b in zip(X, B):
        x1 = np.asarray(sp.solve_factored(m, values, b))
        assert np.max(np.abs(x - x1)) <= 1e-13 * np.max(np.abs(x1))
    # two matrices (the second with one element's mass doubled), one right-hand side each
    K = np.asarray(mdl.assemble_dense(m, Ke))
    Ke2 = Ke.at[0].add(1e3 * mdl.mass_elements(m)[0])
    V = jnp.stack([values, sp.factor(m, Ke2)])
    X2 = np.asarray(jax.jit(jax.vmap(lambda v, b: sp.solve_factored(m, v, b)))(V, B[:2]))
    for x, Kk, b in zip(X2, (K, np.asarray(mdl.assemble_dense(m, Ke2))), B[:2]):
        xn = np.linalg.solve(Kk, np.asarray(b))
        assert np.linalg.norm(x - xn) <= 1e-8 * np.linalg.norm(xn)


def test_implicit_derivative_with_pardiso_equals_dense(monkeypatch):
    """A dense forward run hands its steps' implicit derivatives to MKL Pardiso from
    ``DERIVATIVE_SPARSE_FROM`` unknowns: forward-mode derivatives (three lanes, one host
    call each step) and reverse mode equal the all-dense ones to round-off."""
    pytest.importorskip("pypardiso")
    times = it.time_grid(6e-3, 1e-3)

    def x_end(theta):
        mat = scenarios.rolled_material("IV", mu_inf=theta[0], eta=theta[1:] * jnp.ones(4))
        p = scenarios.rolled(mat, 30.0, 50e3, h=2e-3, shape=(2, 4, 1))
        return it.simulate(p.model, p.loading, times, p.output_fn).outputs["x_P"][-1]

    theta = jnp.array([scenarios.rolled_material("IV").mu_inf, 2.0e3])
    monkeypatch.setattr(it, "DERIVATIVE_SPARSE_FROM", 10**9)
    dense_f = np.asarray(jax.jit(jax.jacfwd(x_end))(theta))
    monkeypatch.setattr(it, "DERIVATIVE_SPARSE_FROM", 0)
    jax.clear_caches()
    before = linsolve._CACHE.factorizations
    sparse_f = np.asarray(jax.jit(jax.jacfwd(x_end))(theta))
    sparse_r = np.asarray(jax.jit(jax.grad(x_end))(theta))
    assert linsolve._CACHE.factorizations > before  # Pardiso did factorize
    assert np.all(np.abs(dense_f) > 0)
    assert np.max(np.abs(sparse_f - dense_f)) <= 1e-10 * np.max(np.abs(dense_f))
    assert np.max(np.abs(sparse_r - dense_f)) <= 1e-10 * np.max(np.abs(dense_f))


def test_host_factorizations_count_new_matrices_not_cache_hits(problem):
    """``host_factorizations`` (the check of bench N1's amortized figure): a solve with new
    values factorizes once, the same values again reuse it, and after
    ``clear_factorizations`` the same values factorize again."""
    m = problem.model
    E = mdl.nominal_field(m, jnp.array([8e3]))
    Ke = element_tangents(m, m.q0, E, mdl.initial_viscous_state(m), 1e-3, mdl.initial_pressure(m))[1]
    Ke = Ke + 1e3 * mdl.mass_elements(m)
    solver = linsolve.SparseSolver()
    values = solver.factor(m, Ke)
    b = jnp.ones(m.structure.n_free)
    linsolve.clear_factorizations()
    n0 = linsolve.host_factorizations()
    x = solver.solve_factored(m, values, b)
    assert linsolve.host_factorizations() - n0 == 1
    np.testing.assert_array_equal(np.asarray(solver.solve_factored(m, values, b)), np.asarray(x))
    assert linsolve.host_factorizations() - n0 == 1
    solver.solve_factored(m, values * 2.0, b)
    assert linsolve.host_factorizations() - n0 == 2
    linsolve.clear_factorizations()
    solver.solve_factored(m, values, b)
    assert linsolve.host_factorizations() - n0 == 3


def test_superlu_in_nested_dissection_order_and_its_fallback():
    """SuperLU factorizes in dejax's nested-dissection order without pivoting (half the fill
    of COLAMD on the tube 8x12x2) and solves to round-off (backward error as COLAMD's with
    partial pivoting, scipy's default, the reference); where that order is unstable (a
    tiny pivot) it falls back to COLAMD and still solves."""
    from scipy.sparse.linalg import norm as sparse_norm
    from scipy.sparse.linalg import splu

    m, Ke = tube_system(shape=(8, 12, 2))
    pattern, values = mdl.assembly(m.structure), np.asarray(mdl.assemble_values(m, Ke))
    b = np.random.default_rng(3).standard_normal((pattern.n, 2))

    def backward(A, x):
        return np.linalg.norm(b - A @ x) / (sparse_norm(A) * np.linalg.norm(x))

    A = linsolve._csc(pattern, values)
    colamd = splu(A, permc_spec="COLAMD")
    x = linsolve._factorize(pattern, values, "superlu")(b)
    assert x.shape == b.shape and backward(A, x) <= 10.0 * backward(A, colamd.solve(b))
    order = linsolve._SUPERLU_ORDER[pattern]
    Ap = linsolve._csc(pattern, values)[order.order][:, order.order].tocsc()
    nd = splu(Ap, permc_spec="NATURAL", diag_pivot_thresh=0.0, options=dict(SymmetricMode=True))
    assert nd.L.nnz + nd.U.nnz < 0.75 * (colamd.L.nnz + colamd.U.nnz)

    # the first unknown's diagonal entry made tiny: without pivoting the factorization is
    # unstable (its test solve fails the bound), so SuperLU is run again with COLAMD and
    # partial pivoting, which solves it
    tiny = values.copy()
    first = order.order[0]
    tiny[np.flatnonzero((pattern.rows == first) & (pattern.cols == first))] *= 1e-30
    At = linsolve._csc(pattern, tiny)
    unstable = splu(At[order.order][:, order.order].tocsc(), permc_spec="NATURAL", diag_pivot_thresh=0.0,
                    options=dict(SymmetricMode=True))
    y = np.empty_like(b)
    y[order.order] = unstable.solve(b[order.order])
    assert not backward(At, y) <= linsolve.SUPERLU_BACKWARD_BOUND
    x = linsolve._factorize(pattern, tiny, "superlu")(b)
    assert backward(At, x) <= 10.0 * backward(At, splu(At, permc_spec="COLAMD").solve(b))
