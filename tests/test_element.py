"""Tests of the ANCF 8-node solid element (dejax/element.py).

1. Project Chrono's ANCF 3843 reference data (mass, gravity, internal forces,
   stiffness Jacobians; St. Venant-Kirchhoff steel cube), reproduced with an
   exact 7x7x7 Gauss rule. Forces and Jacobians come from automatic
   differentiation of the element energy built on dejax's kinematics
   (``element_reference_data`` + ``deformation_gradient``); expected values come
   only from the Chrono files.
2. Affine motions are reproduced exactly (F = R U at every Gauss point), for a
   cube and a distorted element.
3. Total mass = rho V, V from an independent trilinear-hexahedron volume.
4. Shape-function derivatives vs finite differences, explicit formulas, nodal
   interpolation properties (parametric and Cartesian).
5. Gauss rule exactness.
"""
from __future__ import annotations

import itertools
import sys
from pathlib import Path

import numpy as np
import pytest

import dejax  # noqa: F401  (enables float64)
import jax
import jax.numpy as jnp
from dejax import element as el
from dejax.verification import data_path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import svk  # noqa: E402  (test-only material, tests/svk.py)

# --------------------------------------------------------------------------------------
# helpers (independent of dejax)
# --------------------------------------------------------------------------------------
CORNERS = np.array(
    [[-1, -1, -1], [1, -1, -1], [1, 1, -1], [-1, 1, -1], [-1, -1, 1], [1, -1, 1], [1, 1, 1], [-1, 1, 1]],
    dtype=float,
)  # node order A..H, written out again here on purpose (not taken from dejax)

# Gauss-Legendre 3-point rule, hard-coded (exact to degree 5 per direction)
_G3_P = np.array([-np.sqrt(0.6), 0.0, np.sqrt(0.6)])
_G3_W = np.array([5.0 / 9.0, 8.0 / 9.0, 5.0 / 9.0])


def trilinear_jacobian(Xc, xi):
    """dX/dxi (3x3, [m, k]) of the trilinear map through corners Xc (8, 3) at xi (3,)."""
    out = np.zeros((3, 3))
    f = 1.0 + CORNERS * xi  # (8, 3)
    for k in range(3):
        others = [j for j in range(3) if j != k]
        dL = CORNERS[:, k] * f[:, others[0]] * f[:, others[1]] / 8.0
        out[:, k] = dL @ Xc
    return out


def trilinear_volume(Xc):
    """Volume of the trilinear hexahedron (det of its Jacobian has degree <= 2 per direction)."""
    V = 0.0
    for (i, wi), (j, wj), (k, wk) in itertools.product(enumerate(_G3_W), repeat=3):
        V += wi * wj * wk * np.linalg.det(trilinear_jacobian(Xc, np.array([_G3_P[i], _G3_P[j], _G3_P[k]])))
    return V


def unit_cube():
    """Corners (8, 3) and nodal dX/dxi (8, 3, 3) of Chrono's 1 m cube."""
    X = 0.5 * (CORNERS + 1.0)
    dXdxi = np.broadcast_to(0.5 * np.eye(3), (8, 3, 3)).copy()
    return X, dXdxi


def distorted_element(seed=1, amp=0.15):
    """Randomly perturbed unit cube; nodal dX/dxi from its trilinear map (det > 0 checked)."""
    rng = np.random.default_rng(seed)
    X = 0.5 * (CORNERS + 1.0) + amp * rng.uniform(-1.0, 1.0, (8, 3))
    dXdxi = np.stack([trilinear_jacobian(X, c) for c in CORNERS])
    dets = [np.linalg.det(J) for J in dXdxi]
    p3 = np.array(list(itertools.product(_G3_P, repeat=3)))
    dets += [np.linalg.det(trilinear_jacobian(X, p)) for p in p3]
    assert min(dets) > 0.05, "distorted test element is inverted or degenerate"
    return X, dXdxi


def random_rotation(rng):
    Q, Rr = np.linalg.qr(rng.normal(size=(3, 3)))
    Q = Q * np.sign(np.diag(Rr))
    if np.linalg.det(Q) < 0:
        Q[:, 0] = -Q[:, 0]
    return Q


def random_stretch(rng):
    Q = random_rotation(rng)
    return Q @ np.diag(rng.uniform(0.6, 1.6, 3)) @ Q.T


def rel_err(a, ref):
    a, ref = np.asarray(a), np.asarray(ref)
    return float(np.max(np.abs(a - ref)) / np.max(np.abs(ref)))


# --------------------------------------------------------------------------------------
# 1. Chrono ANCF 3843 reference data
# --------------------------------------------------------------------------------------
# shipped with the package (dejax/verification/data): the tests fail, not skip, without it
CHRONO_DIR = data_path("chrono-ancf3843")

E_YOUNG, NU, RHO = 210e9, 0.3, 7850.0
LAM, MU = svk.lame(E_YOUNG, NU)
GRAV = (0.0, 0.0, -9.80665)
ALPHA = 0.01
TOL_CHRONO = 1e-9
IDX_BZ = 12 * 1 + 3 * 0 + 2  # node B, position, z  (= 14)


def load_chrono(name, shape):
    txt = (CHRONO_DIR / f"UT_ANCFBrick_3843_{name}.txt").read_text()
    return np.array(txt.split(), dtype=float).reshape(shape)


def build_chrono():
    """Reference data of the cube at 7x7x7 Gauss points and jitted autodiff element functions."""
    X, dXdxi = unit_cube()
    pts, wts = el.gauss_rule(7)
    N, G, dV = el.element_reference_data(jnp.asarray(X), jnp.asarray(dXdxi), pts, wts)
    q0 = np.asarray(el.reference_element_coordinates(jnp.asarray(X))).reshape(-1)

    def F_of(q):
        return el.deformation_gradient(q.reshape(32, 3), G)  # (n_gp, 3, 3)

    def energy(q):  # U(e) = sum_gp dV psi(F(e))
        return jnp.sum(dV * jax.vmap(lambda F: svk.psi_svk_voigt(F, LAM, MU))(F_of(q)))

    def dissipation(q, qdot):  # Rayleigh pseudo-potential; F_dot = e_dot^T G
        return jnp.sum(
            dV * jax.vmap(lambda F, Fd: svk.rayleigh_density(F, Fd, LAM, MU, ALPHA))(F_of(q), F_of(qdot))
        )

    def stress_force(q, qdot):  # Chrono's Q = -int F S G^T dV, with the damped S
        S = jax.vmap(lambda F, Fd: svk.pk2_damped(F, Fd, LAM, MU, ALPHA))(F_of(q), F_of(qdot))
        P = jnp.einsum("gij,gjk->gik", F_of(q), S)
        return -jnp.einsum("g,gik,gak->ai", dV, P, G).reshape(-1)

    def tangent_contraction(q):  # sum_gp dV G_aj D_ijkl G_bl with D = d2psi/dF2 (3x3x3x3)
        D = jax.vmap(jax.hessian(lambda F: svk.psi_svk_voigt(F, LAM, MU)))(F_of(q))
        K4 = jnp.einsum("g,gaj,gijkl,gbl->aibk", dV, G, D, G)
        return K4.reshape(96, 96)

    return dict(
        N=N,
        G=G,
        dV=dV,
        q0=q0,
        force=jax.jit(lambda q: -jax.grad(energy)(q)),
        damping_force=jax.jit(lambda q, qd: -jax.grad(dissipation, argnums=1)(q, qd)),
        stress_force=jax.jit(stress_force),
        hessian=jax.jit(jax.hessian(energy)),
        tangent_contraction=jax.jit(tangent_contraction),
    )


@pytest.fixture(scope="module")
def chrono():
    return build_chrono()


def case3_state(q0):
    q = q0.copy()
    q[IDX_BZ] += 0.001
    return q


def test_chrono_mass_matrix(chrono):
    ref = load_chrono("MassMatrix", (32, 32))
    Mc = np.asarray(el.element_mass(chrono["N"], chrono["dV"], RHO))
    assert rel_err(Mc, ref) < TOL_CHRONO
    full = np.kron(Mc, np.eye(3))
    assert rel_err(full, np.kron(ref, np.eye(3))) < TOL_CHRONO
    # position-position block sums to rho V = 7850 kg
    assert np.isclose(Mc[::4, ::4].sum(), RHO * 1.0, rtol=1e-12)


def test_chrono_gravity(chrono):
    ref = load_chrono("Grav", (96,))
    Qg = np.asarray(el.element_gravity(chrono["N"], chrono["dV"], RHO, GRAV)).reshape(-1)
    assert rel_err(Qg, ref) < TOL_CHRONO
    # README's closed form for the cube (independent of the file as well)
    assert np.isclose(Qg[2], -RHO * 9.80665 / 8.0, rtol=1e-12)


def test_chrono_internal_force_at_rest_is_zero(chrono):
    Q = np.asarray(chrono["force"](jnp.asarray(chrono["q0"])))
    assert np.max(np.abs(Q)) < 1e-3  # Chrono's own check (N)


def test_chrono_internal_force_small_displacement(chrono):
    ref = load_chrono("IntFrcSmallDispNoVel", (96,))
    q = jnp.asarray(case3_state(chrono["q0"]))
    Q = np.asarray(chrono["force"](q))
    assert rel_err(Q, ref) < TOL_CHRONO
    # the stress-based form (alpha irrelevant at zero velocity) agrees with autodiff
    Qs = np.asarray(chrono["stress_force"](q, jnp.zeros(96)))
    assert rel_err(Qs, ref) < TOL_CHRONO


def test_chrono_internal_force_small_velocity_damped(chrono):
    ref = load_chrono("IntFrcNoDispSmallVel", (96,))
    q = jnp.asarray(chrono["q0"])
    qdot = np.zeros(96)
    qdot[IDX_BZ] = 0.001
    qdot = jnp.asarray(qdot)
    Q = np.asarray(chrono["force"](q) + chrono["damping_force"](q, qdot))
    assert rel_err(Q, ref) < TOL_CHRONO
    Qs = np.asarray(chrono["stress_force"](q, qdot))  # Chrono's damped stress S = D (eps + alpha eps_dot)
    assert rel_err(Qs, ref) < TOL_CHRONO


@pytest.mark.parametrize("case", ["NoDisp", "SmallDisp"])
def test_chrono_stiffness_jacobian(chrono, case):
    ref = load_chrono(f"Jac{case}NoVelNoDamping", (96, 96))
    q = chrono["q0"] if case == "NoDisp" else case3_state(chrono["q0"])
    q = jnp.asarray(q)
    K = np.asarray(chrono["hessian"](q))
    assert rel_err(K, ref) < TOL_CHRONO
    # secondary: the cheap Gauss-point contraction with d2psi/dF2 equals the full hessian
    Kc = np.asarray(chrono["tangent_contraction"](q))
    assert rel_err(Kc, K) < 1e-12
    if case == "NoDisp":  # 6 rigid-body zero modes at the reference shape
        ev = np.linalg.eigvalsh(0.5 * (K + K.T)) / np.max(np.abs(K))
        assert np.sum(np.abs(ev) < 1e-10) == 6 and ev.min() > -1e-10


def test_svk_voigt_equals_tensor_form():
    rng = np.random.default_rng(3)
    for _ in range(5):
        F = jnp.asarray(np.eye(3) + 0.3 * rng.normal(size=(3, 3)))
        a = svk.psi_svk_voigt(F, LAM, MU)
        b = svk.psi_svk(F, LAM, MU)
        assert np.isclose(a, b, rtol=1e-13, atol=0.0)
        np.testing.assert_allclose(
            jax.grad(svk.psi_svk_voigt)(F, LAM, MU), jax.grad(svk.psi_svk)(F, LAM, MU), rtol=1e-12, atol=1e-3
        )
        # the damped stress is F^-1 d(psi + phi)/dF and d(psi + phi)/dF_dot in Chrono's sense
        Fd = jnp.asarray(rng.normal(size=(3, 3)))
        S = svk.pk2_damped(F, Fd, LAM, MU, ALPHA)
        P = jax.grad(svk.psi_svk)(F, LAM, MU) + jax.grad(svk.rayleigh_density, argnums=1)(F, Fd, LAM, MU, ALPHA)
        np.testing.assert_allclose(F @ S, P, rtol=1e-11, atol=1e-11 * float(jnp.max(jnp.abs(P))))


# --------------------------------------------------------------------------------------
# 2. Affine motions are exact
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("geometry", ["cube", "distorted"])
def test_affine_motion_exact(geometry):
    X, dXdxi = unit_cube() if geometry == "cube" else distorted_element()
    rng = np.random.default_rng(7)
    Fa = random_rotation(rng) @ random_stretch(rng)
    c = rng.normal(size=3)
    e = np.zeros((32, 3))
    for i in range(8):
        e[4 * i] = Fa @ X[i] + c
        e[4 * i + 1 : 4 * i + 4] = Fa.T  # rows: dr/dX, dr/dY, dr/dZ = columns of Fa
    pts, wts = el.gauss_rule(4)
    N, G, dV = el.element_reference_data(jnp.asarray(X), jnp.asarray(dXdxi), pts, wts)
    assert np.min(np.asarray(dV)) > 0.0
    F = np.asarray(el.deformation_gradient(jnp.asarray(e), G))
    assert np.max(np.abs(F - Fa)) < 1e-12
    # positions are reproduced too: r(xi) = Fa X(xi) + c with X(xi) the trilinear map
    r = np.asarray(N) @ e
    Xq = np.stack([np.prod(1.0 + CORNERS * p, axis=1) / 8.0 @ X for p in pts])
    assert np.max(np.abs(r - (Xq @ Fa.T + c))) < 1e-12


@pytest.mark.parametrize("geometry", ["cube", "distorted"])
def test_factored_gradients_reproduce_affine_motion(geometry):
    """G kept in its factors (the model's route: element coordinates to parametric slots,
    contracted with the shared parametric shape gradients, then Jinv) gives the exact F of
    an affine motion, as the assembled G does; and ``cartesian_slots`` is the transpose of
    ``parametric_slots`` (<A e, f> = <e, A^T f> for random e, f)."""
    X, dXdxi = unit_cube() if geometry == "cube" else distorted_element()
    rng = np.random.default_rng(11)
    Fa = random_rotation(rng) @ random_stretch(rng)
    e = np.zeros((32, 3))
    for i in range(8):
        e[4 * i] = Fa @ X[i]
        e[4 * i + 1 : 4 * i + 4] = Fa.T
    pts, wts = el.gauss_rule(3)
    N, Jinv, dV = el.element_reference_factors(jnp.asarray(X), jnp.asarray(dXdxi), pts, wts)
    dNdxi = jax.vmap(el.parametric_shape_gradients)(jnp.asarray(pts))
    J = jnp.asarray(dXdxi)
    Fxi = jnp.einsum("ai,gak->gik", el.parametric_slots(jnp.asarray(e), J), dNdxi)
    F = np.asarray(jnp.einsum("gik,gkj->gij", Fxi, Jinv))
    assert np.max(np.abs(F - Fa)) < 1e-12
    a, f = rng.normal(size=(32, 3)), rng.normal(size=(32, 3))
    lhs = float(jnp.sum(el.parametric_slots(jnp.asarray(a), J) * f))
    rhs = float(jnp.sum(jnp.asarray(a) * el.cartesian_slots(jnp.asarray(f), J)))
    assert abs(lhs - rhs) < 1e-12 * max(1.0, abs(lhs))
    # the same as the matrix A of slot_transform
    A = np.asarray(el.slot_transform(J))
    np.testing.assert_allclose(np.asarray(el.parametric_slots(jnp.asarray(a), J)), A @ a, rtol=0, atol=1e-14)


# --------------------------------------------------------------------------------------
# 3. Total mass
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("geometry", ["cube", "distorted"])
def test_total_mass(geometry):
    X, dXdxi = unit_cube() if geometry == "cube" else distorted_element()
    V = trilinear_volume(X)
    if geometry == "cube":
        assert np.isclose(V, 1.0, rtol=1e-14)
    rho = 1100.0
    pts, wts = el.gauss_rule(4)
    N, G, dV = el.element_reference_data(jnp.asarray(X), jnp.asarray(dXdxi), pts, wts)
    Mc = np.asarray(el.element_mass(N, dV, rho))
    np.testing.assert_allclose(Mc, Mc.T, rtol=0, atol=1e-14 * np.max(np.abs(Mc)))
    assert np.isclose(Mc[::4, ::4].sum(), rho * V, rtol=1e-12)  # rigid translation: sum of position block
    assert np.isclose(rho * float(jnp.sum(dV)), rho * V, rtol=1e-12)
    # consistent with gravity: total vertical force on positions = -rho V g
    Qg = np.asarray(el.element_gravity(N, dV, rho, GRAV))
    assert np.isclose(Qg[::4, 2].sum(), rho * V * GRAV[2], rtol=1e-12)


# --------------------------------------------------------------------------------------
# 4. Shape functions
# --------------------------------------------------------------------------------------
def explicit_shape_functions(xi):
    """README formulas (alternative factorised form of the gradient functions), a = b = c = 2."""
    out = np.zeros(32)
    for i, ci in enumerate(CORNERS):
        f = 1.0 + ci * xi
        P = np.prod(f)
        out[4 * i] = P * (2.0 + ci @ xi - xi @ xi) / 16.0
        for k in range(3):
            o = [j for j in range(3) if j != k]
            out[4 * i + 1 + k] = (2.0 / 32.0) * ci[k] * f[k] ** 2 * (ci[k] * xi[k] - 1.0) * f[o[0]] * f[o[1]]
    return out


def test_shape_functions_explicit_formulas():
    rng = np.random.default_rng(11)
    for xi in rng.uniform(-1.0, 1.0, (20, 3)):
        s = np.asarray(el.parametric_shape_functions(jnp.asarray(xi)))
        np.testing.assert_allclose(s, explicit_shape_functions(xi), rtol=0, atol=1e-15)


def test_shape_gradients_vs_finite_differences():
    rng = np.random.default_rng(5)
    h = 1e-5
    f = jax.jit(el.parametric_shape_functions)
    for xi in rng.uniform(-1.0, 1.0, (10, 3)):
        dN = np.asarray(el.parametric_shape_gradients(jnp.asarray(xi)))
        assert dN.shape == (32, 3)
        fd = np.zeros((32, 3))
        for k in range(3):
            d = np.zeros(3)
            d[k] = h
            fd[:, k] = (np.asarray(f(jnp.asarray(xi + d))) - np.asarray(f(jnp.asarray(xi - d)))) / (2 * h)
        assert np.max(np.abs(dN - fd)) < 1e-8


def test_parametric_nodal_interpolation():
    for j, cj in enumerate(CORNERS):
        s = np.asarray(el.parametric_shape_functions(jnp.asarray(cj)))
        ds = np.asarray(el.parametric_shape_gradients(jnp.asarray(cj)))
        for i in range(8):
            assert np.isclose(s[4 * i], float(i == j), atol=1e-15)
            np.testing.assert_allclose(s[4 * i + 1 : 4 * i + 4], 0.0, atol=1e-15)
            np.testing.assert_allclose(ds[4 * i], 0.0, atol=1e-15)
            expected = np.eye(3) if i == j else np.zeros((3, 3))
            np.testing.assert_allclose(ds[4 * i + 1 : 4 * i + 4], expected, atol=1e-15)
    # partition of unity of the position functions
    for xi in np.random.default_rng(2).uniform(-1, 1, (5, 3)):
        assert np.isclose(float(jnp.sum(el.parametric_shape_functions(jnp.asarray(xi))[::4])), 1.0, atol=1e-14)


@pytest.mark.parametrize("geometry", ["box", "distorted"])
def test_cartesian_nodal_interpolation(geometry):
    """At node j, Cartesian-slot N and G = dN/dX pick exactly node j's position and gradients."""
    if geometry == "box":  # a != b != c
        X = 0.5 * (CORNERS + 1.0) * np.array([2.0, 0.5, 0.3])
        dXdxi = np.broadcast_to(np.diag([1.0, 0.25, 0.15]), (8, 3, 3)).copy()
    else:
        X, dXdxi = distorted_element(seed=4)
    N, G, dV = el.element_reference_data(jnp.asarray(X), jnp.asarray(dXdxi), CORNERS, np.ones(8))
    N, G = np.asarray(N), np.asarray(G)
    for j in range(8):
        for i in range(8):
            d = float(i == j)
            assert np.isclose(N[j, 4 * i], d, atol=1e-14)
            np.testing.assert_allclose(N[j, 4 * i + 1 : 4 * i + 4], 0.0, atol=1e-14)
            np.testing.assert_allclose(G[j, 4 * i], 0.0, atol=1e-12)
            np.testing.assert_allclose(G[j, 4 * i + 1 : 4 * i + 4], d * np.eye(3), atol=1e-12)
    np.testing.assert_allclose(np.asarray(dV), [np.linalg.det(J) for J in dXdxi], rtol=1e-12)


# --------------------------------------------------------------------------------------
# 5. Gauss rule
# --------------------------------------------------------------------------------------
def _exact_1d(p):
    return 0.0 if p % 2 else 2.0 / (p + 1)


@pytest.mark.parametrize("n", [1, 2, 3, 4, 5, 7])
def test_gauss_rule(n):
    P, W = el.gauss_rule(n)
    assert P.shape == (n**3, 3) and W.shape == (n**3,)
    assert np.isclose(W.sum(), 8.0, rtol=1e-14)
    assert np.all(np.abs(P) < 1.0) and np.all(W > 0)
    degs = range(2 * n)  # exact up to 2n - 1 in each direction
    for a, b, c in itertools.product(degs, repeat=3):
        val = np.sum(W * P[:, 0] ** a * P[:, 1] ** b * P[:, 2] ** c)
        assert abs(val - _exact_1d(a) * _exact_1d(b) * _exact_1d(c)) < 1e-13, (a, b, c)
    # but not for degree 2n (so it really has n points per direction)
    for k in range(3):
        val = np.sum(W * P[:, k] ** (2 * n))
        assert abs(val - 4.0 * _exact_1d(2 * n)) > 1e-6


def test_gauss_rule_rejects_bad_order():
    for bad in (0, -1, 2.5):
        with pytest.raises(ValueError):
            el.gauss_rule(bad)


# --------------------------------------------------------------------------------------
# Consistent face loads (dead tractions)
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("axis, side", [(0, 1), (1, -1), (2, 1)])
def test_face_load_virtual_work_of_linear_fields(axis, side):
    """f . dq = int_face t . du dA for every linear field du = H X + c (positions H X_a + c,
    gradient slots the columns of H): the load is consistent, gradient slots included."""
    dims = np.array([2e-3, 1e-3, 0.5e-3])
    X = 0.5 * (CORNERS + 1.0) * dims
    dXdxi = np.broadcast_to(0.5 * np.diag(dims), (8, 3, 3)).copy()
    t = np.array([3e3, -1e3, 2e3])
    f = np.asarray(el.face_load(jnp.asarray(X), jnp.asarray(dXdxi), axis, side, t))  # (32, 3)
    rng = np.random.default_rng(axis)
    a, b = [k for k in range(3) if k != axis]
    area = dims[a] * dims[b]
    centroid = 0.5 * dims.copy()
    centroid[axis] = dims[axis] if side > 0 else 0.0
    for _ in range(3):
        H, c = rng.standard_normal((3, 3)), rng.standard_normal(3)
        dq = np.concatenate([np.concatenate([(H @ x + c)[None], H.T], axis=0) for x in X])  # (32, 3): r, dr/dX_k
        assert np.sum(f * dq) == pytest.approx(t @ (H @ centroid + c) * area, rel=1e-12)
