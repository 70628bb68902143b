"""Tests of the hyper-viscoelastic Gent dielectric elastomer (dejax/material.py).

References are independent of the code under test: closed forms derived by hand
from the free energy in docs/paper-notes.md (written out again below in
numpy), central finite differences, and invariance laws.

1. Rest state: zero energy and stress at F = I, E = 0, Cv = I (0, 1, 4 units).
2. Objectivity: psi(QF) = psi(F), P(QF) = Q P(F), Cv_new(QF) = Cv_new(F),
   D(QF) = Q D(F) Q; balance of angular momentum P F^T symmetric.
3. Closed forms: simple shear, incompressible uniaxial, pure dilatation,
   electrostatic (Maxwell) stress, the equal-biaxial block of docs/paper-notes.md
   (equilibrium and evolution equations).
4. Consistent tangent vs finite differences of ``stress_and_update``, on Model IV
   and on a soft-bulk variant where the dCv/dF part is ~10 % of D (with K ~ 1e5 mu
   it is ~1e-5 of D and no FD comparison can see it); symmetry of the frozen-Cv
   (hyperelastic) tangent; asymmetry of the consistent one is printed, not asserted.
5. Viscous update: det Cv preserved, SPD, first-order consistency with the flow
   rule (and O(dt^2) agreement per step with literal backward Euler), relaxation
   to Cv ~ C, forward- and reverse-mode implicit derivatives vs finite differences.
6. Gent limit: GentLimitError from ``evaluate`` / ``check_state``; finite
   placeholders when jitted.
7. ``Material`` validation.
8. Batched (vmap) evaluation equals the loop.

Two tests guard bugs found and fixed in dejax/material.py (traced Material
construction; NaN states passing check_state).

Run time: compilations are shared between tests (module-level jitted functions,
few distinct numbers of viscous units, float64 array arguments throughout), and
XLA backend optimisation is off for these one-off compilations.
"""
from __future__ import annotations

import numpy as np
import pytest

import dejax  # noqa: F401  (float64)
import jax
import jax.numpy as jnp
from dejax import material as m
from dejax.material import GentLimitError, Material

# --------------------------------------------------------------------------------------
# parameters (paper Table 2, Model IV; rolled-DEA constants)
# --------------------------------------------------------------------------------------
MU_INF, K_INF, JM_INF, EPS, RHO = 72e3, 3e9, 15.0, 3.4e-11, 1500.0
MU_S = [10e3, 10e3, 80e3, 80e3]
ETA_S = [5000.0, 2000.0, 300.0, 100.0]
K_S, JM_S = 7.5e9, 5.0


def model_iv(units=(0, 1, 2, 3), K_inf=K_INF, K_s=K_S):
    """Model IV restricted to the given viscous units (() = hyperelastic)."""
    units = list(units)
    return Material(
        MU_INF, K_inf, JM_INF, EPS, RHO,
        mu=[MU_S[i] for i in units], K=[K_s] * len(units), Jm=[JM_S] * len(units),
        eta=[ETA_S[i] for i in units],
    )


MAT0 = model_iv(())                 # hyperelastic
MAT1 = model_iv((0,))               # one unit
MAT2 = model_iv((1, 2))             # two units: tau = 0.2 s and 3.75 ms
MAT4 = model_iv()                   # full Model IV
MAT2_SOFT = model_iv((1, 2), K_inf=1e5, K_s=2.5e5)  # bulk ~ shear: viscous tangent visible

# jitted entry points, shared by the tests (one compilation per number of units).
# The tests run each compiled function a handful of times: XLA's backend
# optimisation would cost more compile time than it saves (same arithmetic, same
# float64 semantics; only scheduling/fusion differ).
_JIT_OPTS = {"xla_backend_optimization_level": 0}


def _jit(f):
    return jax.jit(f, compiler_options=_JIT_OPTS)


_psi = _jit(m.free_energy)
_P = _jit(jax.grad(m.free_energy))
_stu = _jit(m.stress_tangent_and_update)
_margin = _jit(m.min_gent_margin)
_vu_jit = _jit(m.viscous_update)
_vrate_jit = _jit(m.viscous_rate)


def _f64(*args):
    """All arguments as float64 numpy arrays: Python floats (weakly typed) and numpy
    scalars would otherwise each trigger their own compilation."""
    return tuple(np.asarray(a, dtype=np.float64) for a in args)


def _vu(F, Cv_old, dt, mu, eta, Jm):
    return np.asarray(_vu_jit(*_f64(F, Cv_old, dt, mu, eta, Jm)))


def _vrate(F, Cv, mu, eta, Jm):
    return np.asarray(_vrate_jit(*_f64(F, Cv, mu, eta, Jm)))


# --------------------------------------------------------------------------------------
# independent helpers (numpy, from docs/paper-notes.md)
# --------------------------------------------------------------------------------------
def rel(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return np.linalg.norm(a - b) / np.linalg.norm(b)


def random_rotation(rng):
    Q, R = np.linalg.qr(rng.standard_normal((3, 3)))
    Q = Q * np.sign(np.diag(R))
    if np.linalg.det(Q) < 0:
        Q[:, 0] *= -1
    return Q


def random_spd(rng, s=0.2, det=1.0):
    Q = random_rotation(rng)
    A = Q @ np.diag(np.exp(s * rng.standard_normal(3))) @ Q.T
    return A * (det / np.linalg.det(A)) ** (1.0 / 3.0)


def random_F(rng, s=0.1):
    F = np.eye(3) + s * rng.standard_normal((3, 3))
    assert np.linalg.det(F) > 0
    return F


def rate_np(F, Cv, mu, eta, Jm):
    """Flow rule of docs/paper-notes.md: (2 mu/eta) Je^(-2/3)/H (C - tr(C Cv^-1)/3 Cv)."""
    C = F.T @ F
    Je = np.linalg.det(F) / np.sqrt(np.linalg.det(Cv))
    I1e = np.trace(C @ np.linalg.inv(Cv))
    H = 1.0 - (Je ** (-2.0 / 3.0) * I1e - 3.0) / Jm
    return 2.0 * mu / eta * Je ** (-2.0 / 3.0) / H * (C - I1e / 3.0 * Cv)


def fd_jacobian(f, x, h):
    """Central differences of f (array-valued) with respect to every entry of x."""
    x = np.asarray(x, dtype=float)
    f0 = np.asarray(f(x))
    out = np.zeros(f0.shape + x.shape)
    for idx in np.ndindex(*x.shape):
        d = np.zeros_like(x)
        d[idx] = h
        out[(...,) + idx] = (np.asarray(f(x + d)) - np.asarray(f(x - d))) / (2 * h)
    return out


def _scan_updates(Fs, Cv0, dt, mu, eta, Jm):
    def step(Cv, F):
        Cv_new = m.viscous_update(F, Cv, dt, mu, eta, Jm)
        return Cv_new, Cv_new

    return jax.lax.scan(step, Cv0, Fs)[1]


_scan_jit = _jit(_scan_updates)


def _scan(Fs, Cv0, dt, mu, eta, Jm):
    return np.asarray(_scan_jit(*_f64(Fs, Cv0, dt, mu, eta, Jm)))


# --------------------------------------------------------------------------------------
# 1. rest state
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("mat", [MAT0, MAT1, MAT4], ids=["0 units", "1 unit", "4 units"])
def test_zero_energy_and_stress_at_rest(mat):
    I = np.eye(3)
    Cv = np.broadcast_to(I, (mat.n_units, 3, 3))
    E0 = np.zeros(3)
    assert abs(float(_psi(I, E0, Cv, mat))) <= 1e-12 * MU_INF
    P = np.asarray(_P(I, E0, Cv, mat))
    assert np.all(np.isfinite(P))
    assert np.max(np.abs(P)) <= 1e-12 * MU_INF, P
    # the rest state is also a fixed point of the viscous update, for any dt
    units = list(zip(np.asarray(mat.mu), np.asarray(mat.eta), np.asarray(mat.Jm)))
    for dt in (1e-4, 1.0) if units else ():
        Cv_new = np.array([np.asarray(_vu(I, I, dt, mu, eta, Jm)) for mu, eta, Jm in units]).reshape(-1, 3, 3)
        assert np.max(np.abs(np.asarray(Cv_new) - I)) <= 1e-14
        # Cv_new = I to round-off, so Je - 1 ~ 1e-16 and K_s (Je - 1) ~ 1e-6 Pa
        assert np.max(np.abs(np.asarray(_P(I, E0, Cv_new, mat)))) <= 1e-9 * MU_INF


# --------------------------------------------------------------------------------------
# 2. objectivity
# --------------------------------------------------------------------------------------
def test_objectivity_energy_stress():
    rng = np.random.default_rng(1)
    mat = MAT2
    F = random_F(rng, 0.15)
    E = rng.standard_normal(3) * 3e7            # referential: unchanged by Q
    Cv = np.stack([random_spd(rng, 0.2), random_spd(rng, 0.2, det=1.3)])  # referential
    psi, P = float(_psi(F, E, Cv, mat)), np.asarray(_P(F, E, Cv, mat))
    # balance of angular momentum: P F^T symmetric
    PFt = P @ F.T
    assert np.linalg.norm(PFt - PFt.T) <= 1e-12 * np.linalg.norm(P)
    for _ in range(3):
        Q = random_rotation(rng)
        assert float(_psi(Q @ F, E, Cv, mat)) == pytest.approx(psi, rel=1e-12)
        assert rel(_P(Q @ F, E, Cv, mat), Q @ P) < 1e-12
    # not vacuous: a stretch (not a rotation) does change psi
    S = np.diag([1.1, 1.0, 1.0])
    assert abs(float(_psi(S @ F, E, Cv, mat)) - psi) > 1e-3 * abs(psi)


def test_objectivity_update_and_tangent():
    rng = np.random.default_rng(2)
    mat = MAT2
    F = random_F(rng, 0.15)
    E = rng.standard_normal(3) * 3e7
    Cv = np.stack([random_spd(rng, 0.2), random_spd(rng, 0.2)])
    P, D, Cv_new = (np.asarray(a) for a in _stu(F, E, Cv, 1e-3, mat))
    Q = random_rotation(rng)
    Pq, Dq, Cvq = (np.asarray(a) for a in _stu(Q @ F, E, Cv, 1e-3, mat))
    assert rel(Cvq, Cv_new) < 1e-13
    assert rel(Pq, Q @ P) < 1e-12
    # P(QF) = Q P(F)  =>  D(QF)_ijkl = Q_ia Q_kb D(F)_ajbl
    assert rel(Dq, np.einsum("ia,kb,ajbl->ijkl", Q, Q, D)) < 1e-12


# --------------------------------------------------------------------------------------
# 3. closed forms
# --------------------------------------------------------------------------------------
def _branches(mat):
    """(mu, Jm) of the equilibrium branch and of each unit (Cv = I: all act like Gent)."""
    return [(MU_INF, JM_INF)] + [(float(a), float(b)) for a, b in zip(np.asarray(mat.mu), np.asarray(mat.Jm))]


@pytest.mark.parametrize("mat", [MAT0, MAT2], ids=["0 units", "2 units"])
@pytest.mark.parametrize("k", [0.3, 1.0, 2.0])
def test_simple_shear_closed_form(mat, k):
    """F = I + k e1 e2 (J = 1): psi = sum -mu Jm/2 ln H, P = sum mu/H (F - I1/3 F^-T),
    H = 1 - k^2/Jm; in particular P12 = sum mu k / H = d psi/dk."""
    F = np.eye(3)
    F[0, 1] = k
    Finv_T = np.eye(3)
    Finv_T[1, 0] = -k
    I1 = 3.0 + k * k
    Cv = np.broadcast_to(np.eye(3), (mat.n_units, 3, 3))
    psi_ref, P_ref, P12 = 0.0, np.zeros((3, 3)), 0.0
    for mu, Jm in _branches(mat):
        H = 1.0 - k * k / Jm
        psi_ref += -0.5 * mu * Jm * np.log(H)
        P_ref += mu / H * (F - I1 / 3.0 * Finv_T)
        P12 += mu * k / H
    assert P_ref[0, 1] == pytest.approx(P12, rel=1e-14)
    assert float(_psi(F, np.zeros(3), Cv, mat)) == pytest.approx(psi_ref, rel=1e-12)
    P = np.asarray(_P(F, np.zeros(3), Cv, mat))
    # J = 1 to round-off; the bulk term K (J-1) ~ K * 1e-16 is negligible against mu
    assert np.max(np.abs(P - P_ref)) <= 1e-9 * np.max(np.abs(P_ref))
    assert P[0, 1] == pytest.approx(P12, rel=1e-9)


@pytest.mark.parametrize("lam", [0.6, 1.5, 2.5, 3.5])
def test_uniaxial_incompressible_cauchy(lam):
    """F = diag(lam, lam^-1/2, lam^-1/2): sigma11 - sigma22 = mu/H (lam^2 - 1/lam),
    H = 1 - (lam^2 + 2/lam - 3)/Jm; sigma22 = sigma33; no shear."""
    F = np.diag([lam, lam ** -0.5, lam ** -0.5])
    P = np.asarray(_P(F, np.zeros(3), np.zeros((0, 3, 3)), MAT0))
    sigma = P @ F.T / np.linalg.det(F)
    H = 1.0 - (lam ** 2 + 2.0 / lam - 3.0) / JM_INF
    ref = MU_INF / H * (lam ** 2 - 1.0 / lam)
    assert sigma[0, 0] - sigma[1, 1] == pytest.approx(ref, rel=1e-9)
    assert abs(sigma[1, 1] - sigma[2, 2]) <= 1e-9 * abs(ref)
    assert np.max(np.abs(sigma - np.diag(np.diag(sigma)))) <= 1e-9 * abs(ref)


@pytest.mark.parametrize("a", [0.99, 1.0, 1.02])
def test_pure_dilatation(a):
    """F = a I, Cv = I: isochoric parts vanish, P = (K_inf + sum K_s)(a^3 - 1) a^2 I."""
    Ktot = K_INF + 2 * K_S
    F = a * np.eye(3)
    Cv = np.broadcast_to(np.eye(3), (2, 3, 3))
    P = np.asarray(_P(F, np.zeros(3), Cv, MAT2))
    ref = Ktot * (a ** 3 - 1.0) * a ** 2 * np.eye(3)
    assert np.max(np.abs(P - ref)) <= 1e-9 * max(np.max(np.abs(ref)), MU_INF)
    psi = float(_psi(F, np.zeros(3), Cv, MAT2))
    assert psi == pytest.approx(0.5 * Ktot * (a ** 3 - 1.0) ** 2, rel=1e-9, abs=1e-12 * MU_INF)


def test_electrostatic_stress_closed_form():
    """psi_e = -eps/2 J E.C^-1 E gives P_e = eps J [e (x) C^-1 E - |e|^2/2 F^-T], e = F^-T E;
    at F = I: P_e = eps (E E^T - |E|^2/2 I); Cauchy sigma_e = eps (e e^T - |e|^2/2 I)."""
    rng = np.random.default_rng(3)
    E = rng.standard_normal(3) * 3e7
    # F = I, Cv = I: only the field stresses (Maxwell-like nominal stress)
    for mat in (MAT0, MAT2):
        Cv = np.broadcast_to(np.eye(3), (mat.n_units, 3, 3))
        P = np.asarray(_P(np.eye(3), E, Cv, mat))
        ref = EPS * (np.outer(E, E) - 0.5 * (E @ E) * np.eye(3))
        assert np.max(np.abs(P - ref)) <= 1e-12 * np.max(np.abs(ref))
        psi = float(_psi(np.eye(3), E, Cv, mat))
        assert psi == pytest.approx(-0.5 * EPS * (E @ E), rel=1e-13)
    # general F: the field part is P(F, E) - P(F, 0)
    F = random_F(rng, 0.1)
    Cv = np.stack([random_spd(rng) for _ in range(2)])
    Pe = np.asarray(_P(F, E, Cv, MAT2)) - np.asarray(_P(F, np.zeros(3), Cv, MAT2))
    J = np.linalg.det(F)
    FiT = np.linalg.inv(F).T
    e = FiT @ E
    ref = EPS * J * (np.outer(e, np.linalg.solve(F.T @ F, E)) - 0.5 * (e @ e) * FiT)
    assert np.max(np.abs(Pe - ref)) <= 1e-7 * np.max(np.abs(ref))  # cancellation vs K(J-1)
    sigma_e = Pe @ F.T / J
    assert np.max(np.abs(sigma_e - EPS * (np.outer(e, e) - 0.5 * (e @ e) * np.eye(3)))) <= 1e-7 * np.max(np.abs(ref))


def test_first_order_electrostriction_closed_form():
    """eps_b: permittivity eps (1 + eps_b (lambda_E - 1)) with lambda_E the stretch along the
    nominal field. F = diag(a, b, c), E along z: psi_e = -eps (1 + eps_b (c - 1))/2 abc E^2/c^2;
    along x the x stretch a enters instead; at E = 0 the energy and its derivative are finite
    and equal to the field-free ones; the change is first order in c - 1 (eps_a's I1bar - 3 is
    second order)."""
    from dejax.material import Material
    from dejax.material import equilibrium_energy as energy

    equilibrium_energy = jax.jit(energy)  # one compiled program, not one per operation
    grad = jax.jit(jax.grad(energy))
    base = dict(mu_inf=60e3, K_inf=1e9, Jm_inf=20.0, eps=4e-11, rho=1e3)
    a, b, c, E0 = 1.3, 0.9, 0.8, 3e7
    F = jnp.diag(jnp.array([a, b, c]))
    for eb in (0.0, 0.3, -0.4):
        mat = Material(**base, eps_b=eb)
        for axis, lam in ((2, c), (0, a)):
            E = jnp.zeros(3).at[axis].set(E0)
            psi_e = float(equilibrium_energy(F, E, mat) - equilibrium_energy(F, jnp.zeros(3), mat))
            ref = -0.5 * 4e-11 * (1 + eb * (lam - 1)) * a * b * c * E0 ** 2 / lam ** 2
            assert psi_e == pytest.approx(ref, rel=1e-12)
        g = grad(F, jnp.zeros(3), mat)
        g0 = grad(F, jnp.zeros(3), Material(**base))
        assert np.all(np.isfinite(np.asarray(g))) and np.allclose(np.asarray(g), np.asarray(g0), rtol=1e-14, atol=0)
    # first vs second order: isochoric stretch along z by 1 + d
    E = jnp.array([0.0, 0.0, E0])
    for name in ("eps_b", "eps_a"):
        mat = Material(**base, **{name: 0.3})
        ref_mat = Material(**base)
        rel = []
        for d in (1e-3, 2e-3):
            Fd = jnp.diag(jnp.array([(1 + d) ** -0.5, (1 + d) ** -0.5, 1 + d]))
            pe = lambda m: float(equilibrium_energy(Fd, E, m) - equilibrium_energy(Fd, jnp.zeros(3), m))
            rel.append(abs(pe(mat) / pe(ref_mat) - 1))
        order = np.log(rel[1] / rel[0]) / np.log(2.0)
        assert order == pytest.approx(1.0 if name == "eps_b" else 2.0, abs=0.05), (name, order)


@pytest.mark.parametrize("lam,xi,E0", [(1.03, 1.01, 2e7), (1.2, 0.95, 5e7), (0.9, 1.1, 0.0)])
def test_equal_biaxial_block_notes(lam, xi, E0):
    """docs/paper-notes.md block: F = diag(lam, lam, lam^-2), Cv = diag(xi^2, xi^2, xi^-4), E along z.
    sigma_xx - sigma_zz = mu_inf lam^4 [ (lam^-2 - lam^-8)/H_inf
        + mu_1/mu_inf (lam^-2 xi^-2 - lam^-8 xi^4)/H_1 - eps/mu_inf E0^2 ]
    (zero at the paper notes' equilibrium), and the flow rule reduces to
    dxi/dt = mu_1/(3 eta_1 H_1) (lam^2 xi^-1 - lam^-4 xi^5)."""
    mu_inf, mu1, K, eta1, eps = 67e3, 67e3, 6.7e9, 3000.0, 4e-11
    mat = Material(mu_inf, K, 15.0, eps, 1100.0, mu=[mu1], K=[K], Jm=[5.0], eta=[eta1])
    F = np.diag([lam, lam, lam ** -2])
    Cv = np.diag([xi ** 2, xi ** 2, xi ** -4])[None]
    E = np.array([0.0, 0.0, E0])
    P = np.asarray(_P(F, E, Cv, mat))
    sigma = P @ F.T / np.linalg.det(F)
    H_inf = 1.0 - (2 * lam ** 2 + lam ** -4 - 3.0) / 15.0
    H_1 = 1.0 - (2 * lam ** 2 * xi ** -2 + lam ** -4 * xi ** 4 - 3.0) / 5.0
    lhs = (lam ** -2 - lam ** -8) / H_inf + mu1 / mu_inf * (lam ** -2 * xi ** -2 - lam ** -8 * xi ** 4) / H_1
    ref = mu_inf * lam ** 4 * (lhs - eps / mu_inf * E0 ** 2)
    scale = mu_inf * abs(lam - 1.0) + eps * E0 ** 2
    assert abs((sigma[0, 0] - sigma[2, 2]) - ref) <= 1e-8 * scale
    assert abs(sigma[0, 0] - sigma[1, 1]) <= 1e-8 * scale
    assert np.max(np.abs(sigma - np.diag(np.diag(sigma)))) <= 1e-8 * scale
    # evolution
    dxi = mu1 / (3 * eta1 * H_1) * (lam ** 2 / xi - lam ** -4 * xi ** 5)
    ref_rate = np.diag([2 * xi * dxi, 2 * xi * dxi, -4 * xi ** -5 * dxi])
    rate = np.asarray(_vrate(F, Cv[0], mu1, eta1, 5.0))
    assert np.max(np.abs(rate - ref_rate)) <= 1e-12 * max(np.max(np.abs(ref_rate)), mu1 / eta1 * 1e-3)
    assert np.max(np.abs(rate - rate_np(F, Cv[0], mu1, eta1, 5.0))) <= 1e-12 * mu1 / eta1


# --------------------------------------------------------------------------------------
# 4. consistent tangent
# --------------------------------------------------------------------------------------
def _tangent_case(mat, seed):
    """Random F near I, nonzero field, Cv_old built by a few viscous updates."""
    rng = np.random.default_rng(seed)
    F0 = random_F(rng, 0.1)
    E = np.array([1e7, -2e7, 3e7])
    Cv = np.array([np.eye(3)] * mat.n_units)
    units = list(zip(np.asarray(mat.mu), np.asarray(mat.eta), np.asarray(mat.Jm)))
    for k in range(1, 4):
        Fk = np.eye(3) + k / 3 * (F0 - np.eye(3))
        Cv = np.array([np.asarray(_vu(Fk, Cv[s], 1e-3, *u)) for s, u in enumerate(units)])
    assert np.max(np.abs(Cv - np.eye(3))) > 1e-3  # Cv_old != I
    F = F0 + 0.02 * rng.standard_normal((3, 3))
    return F, E, Cv


@pytest.mark.parametrize("mat", [MAT2, MAT2_SOFT], ids=["model IV", "soft bulk"])
def test_consistent_tangent_vs_fd(mat):
    """D = dP/dF (viscous update included) vs central differences of P(F) =
    stress_and_update(F, ...)[0]. P is taken from stress_tangent_and_update, which
    returns that same function's output (saves compiling stress_and_update alone)."""
    dt = 1e-3
    F, E, Cv_old = _tangent_case(mat, 4)
    P, D, Cv_new = (np.asarray(a) for a in _stu(F, E, Cv_old, dt, mat))
    D_fd = fd_jacobian(lambda F_: _stu(F_, E, Cv_old, dt, mat)[0], F, 1e-5)
    err = rel(D, D_fd)
    # the part of D coming from dCv_new/dF: D minus the tangent at frozen Cv_new
    # (dt = 0 leaves Cv unchanged and makes dCv/dF = 0: a hyperelastic tangent)
    _, D_frozen, Cv_same = (np.asarray(a) for a in _stu(F, E, Cv_new, 0.0, mat))
    assert rel(Cv_same, Cv_new) < 1e-14
    D_visc = D - D_frozen
    print(f"\n[{'soft' if mat is MAT2_SOFT else 'IV'}] |D - D_fd|/|D| = {err:.2e}; "
          f"|dCv/dF part|/|D| = {np.linalg.norm(D_visc) / np.linalg.norm(D):.2e}; "
          f"|D - D_fd|/|dCv/dF part| = {np.linalg.norm(D - D_fd) / np.linalg.norm(D_visc):.2e}")
    assert err < 1e-6
    # the frozen-Cv tangent is a Hessian of psi: major symmetry, and it matches FD of dpsi/dF
    assert rel(D_frozen, D_frozen.transpose(2, 3, 0, 1)) < 1e-10
    assert rel(D_frozen, fd_jacobian(lambda F_: _P(F_, E, Cv_new, mat), F, 1e-5)) < 1e-6
    # measured (not asserted tight): asymmetry of the full consistent tangent
    asym = np.linalg.norm(D - D.transpose(2, 3, 0, 1))
    print(f"    |D - D^T|/|D| = {asym / np.linalg.norm(D):.2e}, "
          f"|D - D^T|/|dCv/dF part| = {asym / np.linalg.norm(D_visc):.2e}")
    if mat is MAT2_SOFT:
        # K ~ mu: the dCv/dF contribution is O(10 %) of D, and FD resolve it to 1e-6,
        # so the comparison above would catch a missing or wrong implicit derivative
        assert np.linalg.norm(D_visc) > 1e-2 * np.linalg.norm(D)
        assert np.linalg.norm(D - D_fd) < 1e-6 * np.linalg.norm(D_visc)


# --------------------------------------------------------------------------------------
# 5. viscous update
# --------------------------------------------------------------------------------------
MU_U, ETA_U, JM_U = 80e3, 300.0, 5.0   # unit 3 of Model IV, tau = 3.75 ms
TAU_U = ETA_U / MU_U


def test_update_preserves_det_and_spd_random_walk():
    rng = np.random.default_rng(6)
    n = 1000
    Fs = np.empty((n, 3, 3))
    F = np.eye(3)
    for i in range(n):  # mean-reverting random walk, well inside the Gent limit
        F = np.eye(3) + 0.9 * (F - np.eye(3)) + 0.05 * rng.standard_normal((3, 3))
        Fs[i] = F
    assert np.all(np.linalg.det(Fs) > 0)
    Cv0 = random_spd(rng, 0.2, det=1.7)  # det != 1 on purpose: preserved, not normalised
    Cvs = np.asarray(_scan(Fs, Cv0, TAU_U / 4, MU_U, ETA_U, JM_U))
    d = np.linalg.det(Cvs) / np.linalg.det(Cv0) - 1.0
    print(f"\nmax |det Cv / det Cv0 - 1| over {n} steps = {np.max(np.abs(d)):.2e}")
    assert np.max(np.abs(d)) < 1e-12
    asym = np.max(np.abs(Cvs - Cvs.transpose(0, 2, 1)), axis=(1, 2)) / np.max(np.abs(Cvs), axis=(1, 2))
    assert np.max(asym) < 1e-14
    assert np.min(np.linalg.eigvalsh(0.5 * (Cvs + Cvs.transpose(0, 2, 1)))) > 0
    # the walk really moves Cv, and stays inside the Gent limit
    assert np.max(np.abs(Cvs - Cv0)) > 0.1
    H = [1 - (np.linalg.det(F) ** (-2 / 3) * np.sqrt(np.linalg.det(Cv)) ** (2 / 3)
              * np.trace(F.T @ F @ np.linalg.inv(Cv)) - 3) / JM_U for F, Cv in zip(Fs, Cvs)]
    assert min(H) > 0


def _be_literal(F, Cv_old, dt, mu, eta, Jm):
    """Literal backward Euler Cv = Cv_old + dt rate(F, Cv), by fixed-point iteration
    (a contraction for dt << tau; the reference scheme of docs/paper-notes.md)."""
    X = Cv_old.copy()
    for _ in range(100):
        X_new = Cv_old + dt * rate_np(F, X, mu, eta, Jm)
        if np.linalg.norm(X_new - X) <= 1e-16 * np.linalg.norm(X):
            break
        X = X_new
    assert np.linalg.norm(X - Cv_old - dt * rate_np(F, X, mu, eta, Jm)) < 1e-15 * np.linalg.norm(X)
    return X


def test_update_first_order_consistency():
    rng = np.random.default_rng(7)
    F = random_F(rng, 0.15)
    Cv_old = random_spd(rng, 0.2, det=1.2)
    rate = rate_np(F, Cv_old, MU_U, ETA_U, JM_U)
    assert rel(_vrate(F, Cv_old, MU_U, ETA_U, JM_U), rate) < 1e-13
    errs, diffs = [], []
    dts = TAU_U * np.array([1e-2, 1e-3, 1e-4])
    for dt in dts:
        Cv_new = np.asarray(_vu(F, Cv_old, dt, MU_U, ETA_U, JM_U))
        errs.append(np.linalg.norm((Cv_new - Cv_old) / dt - rate) / np.linalg.norm(rate))
        diffs.append(np.linalg.norm(Cv_new - _be_literal(F, Cv_old, dt, MU_U, ETA_U, JM_U)))
    print(f"\nrelative rate error at dt/tau = 1e-2, 1e-3, 1e-4: {np.array(errs)}")
    print(f"|Cv - literal backward Euler| at the same dt: {np.array(diffs)}")
    assert errs[-1] < 1e-3
    for a, b in zip(errs[:-1], errs[1:]):
        assert 7.0 < a / b < 13.0  # first order in dt
    # same first-order scheme as literal backward Euler: they differ by O(dt^2) per step
    assert 70.0 < diffs[0] / diffs[1] < 130.0


def test_relaxation_to_elastic_equilibrium():
    """F held: Cv -> C (det Cv0 / det C)^(1/3); the unit's b_e = F Cv^-1 F^T is then
    spherical (no deviatoric stress)."""
    rng = np.random.default_rng(8)
    F = random_F(rng, 0.2)
    C = F.T @ F
    Cv0 = random_spd(rng, 0.3, det=0.8)
    Cv_inf = C * (np.linalg.det(Cv0) / np.linalg.det(C)) ** (1.0 / 3.0)
    Cvs = np.asarray(_scan(np.broadcast_to(F, (1000, 3, 3)), Cv0, TAU_U / 4, MU_U, ETA_U, JM_U))
    assert rel(Cvs[9], Cv_inf) > 1e-3           # not there after a few steps ...
    assert rel(Cvs[-1], Cv_inf) < 1e-10         # ... but after 250 tau
    b_e = F @ np.linalg.solve(Cvs[-1], F.T)
    assert np.linalg.norm(b_e - np.trace(b_e) / 3 * np.eye(3)) < 1e-10 * np.trace(b_e)
    # one huge step lands there directly (backward Euler is L-stable): the memory of
    # Cv0 left after one step of size dt is O(tau / dt)
    e4, e6 = (rel(_vu(F, Cv0, f * TAU_U, MU_U, ETA_U, JM_U), Cv_inf) for f in (1e4, 1e6))
    assert e6 < 1e-5
    assert 50.0 < e4 / e6 < 200.0


def test_update_derivatives_vs_fd():
    rng = np.random.default_rng(9)
    F = random_F(rng, 0.15)
    Cv_old = random_spd(rng, 0.2, det=1.1)
    dt, mu, eta, Jm = 0.5 * TAU_U, MU_U, ETA_U, JM_U
    args = (F, Cv_old, dt, mu, eta, Jm)
    w = rng.standard_normal((3, 3))

    def fwd_and_rev(*a):
        jac = jax.jacfwd(m.viscous_update, argnums=(0, 1, 2, 3, 4, 5))(*a)
        # reverse mode (as fitting uses it): gradient of w : Cv_new wrt F, mu, eta
        rev = jax.grad(lambda F_, mu_, eta_: jnp.sum(w * m.viscous_update(F_, a[1], a[2], mu_, eta_, a[5])),
                       argnums=(0, 1, 2))(a[0], a[3], a[4])
        return jac, rev

    jac, rev = _jit(fwd_and_rev)(*args)
    steps = (1e-5, 1e-5, 1e-5 * dt, 1e-5 * mu, 1e-5 * eta, 1e-5 * Jm)
    errs = []
    for i, (J_ad, h) in enumerate(zip(jac, steps)):
        def f(x, i=i):
            a = list(args)
            a[i] = x
            return _vu(*a)

        J_fd = fd_jacobian(f, args[i], h)
        errs.append(rel(np.asarray(J_ad), J_fd))
    print("\nrel. error of dCv_new/d(F, Cv_old, dt, mu, eta, Jm) vs FD:", ", ".join(f"{e:.1e}" for e in errs))
    assert max(errs) < 1e-7
    assert rel(rev[0], np.einsum("ij,ijkl->kl", w, jac[0])) < 1e-12
    assert float(rev[1]) == pytest.approx(float(np.sum(w * jac[3])), rel=1e-12)
    assert float(rev[2]) == pytest.approx(float(np.sum(w * jac[4])), rel=1e-12)
    assert abs(float(rev[1])) > 0 and abs(float(rev[2])) > 0


# --------------------------------------------------------------------------------------
# 6. Gent limit
# --------------------------------------------------------------------------------------
def _uniaxial(lam):
    return np.diag([lam, lam ** -0.5, lam ** -0.5])


def _lam_at_margin(h, Jm):
    """Incompressible uniaxial stretch with Gent margin h: lam^2 + 2/lam - 3 = (1 - h) Jm."""
    from scipy.optimize import brentq

    return brentq(lambda l: l * l + 2 / l - 3 - (1 - h) * Jm, 1.0, 10.0)


def test_gent_limit_raises():
    mat = MAT2
    Cv = np.broadcast_to(np.eye(3), (2, 3, 3))
    E = np.array([0.0, 0.0, 1e7])
    # lam = 5: past both the equilibrium (Jm = 15) and the unit (Jm = 5) limits
    for F in (_uniaxial(5.0), _uniaxial(_lam_at_margin(-0.01, JM_S))):  # second: only the units
        with pytest.raises(GentLimitError, match="Gent limit"):
            m.evaluate(F, E, Cv, mat)
        with pytest.raises(GentLimitError, match="Gent limit"):
            m.check_state(F, Cv, mat)
    # the unit at lam = 2.8 is fine once relaxed (Cv ~ C): no error
    F = _uniaxial(2.8)
    Cv_rel = np.broadcast_to(F.T @ F, (2, 3, 3))
    m.check_state(F, Cv_rel, mat)
    # batched: the offending point is named
    Fb = np.broadcast_to(np.eye(3), (2, 3, 3, 3)).copy()
    Fb[1, 2] = _uniaxial(5.0)
    # (numpy >= 2 prints the index as (np.int64(1), np.int64(2)): accept either form)
    with pytest.raises(GentLimitError, match=r"Gent limit.*point \((np\.int64\()?1\)?, (np\.int64\()?2\)?\)"):
        m.check_state(Fb, np.broadcast_to(np.eye(3), (2, 3, 2, 3, 3)), mat)
    # inverted material is reported too
    with pytest.raises(GentLimitError, match="inverted"):
        m.check_state(np.diag([-1.0, 1.0, 1.0]), Cv, mat)


def test_gent_limit_just_inside_and_jitted_placeholder():
    mat = MAT2
    Cv = np.broadcast_to(np.eye(3), (2, 3, 3))
    E = np.array([0.0, 0.0, 1e7])
    lam_in = _lam_at_margin(1e-3, JM_S)
    F_in = _uniaxial(lam_in)
    assert float(_margin(F_in, Cv, mat)) == pytest.approx(1e-3, rel=1e-6)
    m.check_state(F_in, Cv, mat)
    # evaluate() (eager, vmapped over a batch of 6 points, one of them just inside the
    # limit): finite, equal to the jitted point values. (One call: eager evaluation
    # costs seconds of op-by-op compilation per new shape.)
    rng = np.random.default_rng(12)
    Fb = np.stack([F_in, _uniaxial(1.2)] + [random_F(rng, 0.1) for _ in range(4)])
    Eb = np.stack([E] * 6)
    psi_b, P_b = (np.asarray(a) for a in m.evaluate(Fb, Eb, np.stack([Cv] * 6), mat))
    assert psi_b.shape == (6,) and P_b.shape == (6, 3, 3)
    assert np.all(np.isfinite(psi_b)) and np.all(np.isfinite(P_b))
    for i in range(6):
        assert psi_b[i] == pytest.approx(float(_psi(Fb[i], E, Cv, mat)), rel=1e-13)
        assert rel(P_b[i], _P(Fb[i], E, Cv, mat)) < 1e-12
    # the unit stress near the limit is large (~1/H) but finite
    assert np.max(np.abs(P_b[0])) > 100 * np.max(np.abs(P_b[1]))
    for lam in (5.0, _lam_at_margin(-0.01, JM_S), _lam_at_margin(0.0, JM_S) * (1 + 1e-12)):
        F = _uniaxial(lam)
        assert float(_margin(F, Cv, mat)) <= 0.0
        assert np.isfinite(float(_psi(F, E, Cv, mat)))
        assert np.all(np.isfinite(np.asarray(_P(F, E, Cv, mat))))


def test_check_state_rejects_nan_state():
    F = np.eye(3)
    F[0, 0] = np.nan
    with pytest.raises(GentLimitError):
        m.check_state(F, np.broadcast_to(np.eye(3), (2, 3, 3)), MAT2)


# --------------------------------------------------------------------------------------
# 7. Material validation
# --------------------------------------------------------------------------------------
def test_material_validation():
    assert model_iv().validate().n_units == 4
    assert MAT0.validate().n_units == 0
    for bad in (-72e3, 0.0):
        with pytest.raises(ValueError, match="mu_inf"):
            Material(bad, K_INF, JM_INF, EPS, RHO).validate()
    with pytest.raises(ValueError, match="eta"):
        Material(MU_INF, K_INF, JM_INF, EPS, RHO, mu=[1e4], K=[K_S], Jm=[JM_S], eta=[-1.0]).validate()
    with pytest.raises(ValueError, match="Jm_inf"):
        Material(MU_INF, K_INF, 0.0, EPS, RHO).validate()
    with pytest.raises(ValueError, match="eps"):
        Material(MU_INF, K_INF, JM_INF, -EPS, RHO).validate()
    # mismatched numbers of viscous parameters (raised by the constructor)
    with pytest.raises(ValueError, match="'eta'"):
        Material(MU_INF, K_INF, JM_INF, EPS, RHO, mu=MU_S, K=[K_S] * 4, Jm=[JM_S] * 4, eta=ETA_S[:3])
    with pytest.raises(ValueError, match="'K'"):
        Material(MU_INF, K_INF, JM_INF, EPS, RHO, mu=MU_S, K=[K_S] * 3, Jm=[JM_S] * 4, eta=ETA_S)
    with pytest.raises(ValueError, match="'Jm'"):
        Material(MU_INF, K_INF, JM_INF, EPS, RHO, mu=MU_S[:2], K=[K_S] * 2, Jm=[JM_S] * 3, eta=ETA_S[:2])


def test_material_constructible_from_traced_parameters():
    F = np.diag([1.3, 0.9, 0.85])
    Cv = np.diag([1.1, 0.95, 1.0 / (1.1 * 0.95)])[None]

    def psi(mu1):
        mat = Material(MU_INF, K_INF, JM_INF, EPS, RHO, mu=jnp.stack([mu1]), K=(K_S,), Jm=(JM_S,), eta=(400.0,))
        return m.free_energy(F, np.zeros(3), Cv, mat)

    g = float(jax.grad(psi)(1e4))
    fd = (float(psi(1e4 + 1.0)) - float(psi(1e4 - 1.0))) / 2.0
    assert g == pytest.approx(fd, rel=1e-6)


# --------------------------------------------------------------------------------------
# 8. batched use
# --------------------------------------------------------------------------------------
def test_vmap_free_energy_matches_loop():
    rng = np.random.default_rng(11)
    n = 64
    Fs = np.stack([random_F(rng, 0.1) for _ in range(n)])
    Es = rng.standard_normal((n, 3)) * 2e7
    Cvs = np.stack([[random_spd(rng, 0.1) for _ in range(2)] for _ in range(n)])
    batched = np.asarray(_jit(jax.vmap(m.free_energy, in_axes=(0, 0, 0, None)))(Fs, Es, Cvs, MAT2))
    loop = np.array([float(_psi(Fs[i], Es[i], Cvs[i], MAT2)) for i in range(n)])
    assert batched.shape == (n,)
    assert np.max(np.abs(batched - loop)) <= 1e-13 * np.max(np.abs(loop))
    assert np.ptp(loop) > 1e-3 * np.max(np.abs(loop))  # the points really differ


# ----------------------------------------------------------------------------- mixed form


def test_mixed_energy_eliminates_to_the_penalty_energy():
    """The perturbed Lagrangian psi_iso + p (J - 1) - p^2/(2K) is stationary in p at
    p = K (J - 1) (K = K_inf + sum K_s), where it equals the paper's penalty energy and
    has the same stress; with p free its p-derivative is J - 1 - p/K. (Cv with det 1, as
    the isochoric flow keeps it, so Je = J.)"""
    rng = np.random.default_rng(3)
    mat = m.Material(67e3, 6.7e9, 15.0, 4e-11, 1100.0, mu=[20e3, 40e3], K=[1e9, 2e9], Jm=[5.0, 8.0], eta=[1.0, 2.0])
    F = jnp.asarray(np.eye(3) + 0.1 * rng.standard_normal((3, 3)))
    A = 0.2 * rng.standard_normal((2, 3, 3))
    A = A + A.transpose(0, 2, 1)
    A = A - np.trace(A, axis1=1, axis2=2)[:, None, None] / 3 * np.eye(3)
    Cv = jnp.asarray(np.stack([jax.scipy.linalg.expm(a) for a in A]))
    E = jnp.array([1e6, -2e6, 4e6])
    K = 6.7e9 + 1e9 + 2e9
    J = float(np.linalg.det(np.asarray(F)))
    p_star = K * (J - 1.0)
    jit = jax.jit  # one compiled program per function, not one per operation
    psi = float(jit(m.free_energy)(F, E, Cv, mat))
    psi_mixed = float(jit(m.mixed_free_energy)(F, E, Cv, p_star, mat))
    assert psi_mixed == pytest.approx(psi, rel=1e-12)
    P = np.asarray(jit(jax.grad(m.free_energy))(F, E, Cv, mat))
    P_mixed = np.asarray(jit(jax.grad(m.mixed_free_energy))(F, E, Cv, p_star, mat))
    np.testing.assert_allclose(P_mixed, P, rtol=1e-10, atol=1e-10 * np.abs(P).max())
    dp = float(jit(jax.grad(m.mixed_free_energy, argnums=3))(F, E, Cv, 1e5, mat))
    assert dp == pytest.approx(J - 1.0 - 1e5 / K, rel=1e-12)


def test_mixed_energy_incompressible_limit():
    """K = inf: the pressure is the Lagrange multiplier of J = 1 (d psi / d p = J - 1)."""
    mat = m.Material(67e3, np.inf, 15.0, 0.0, 1100.0).validate()
    F = jnp.diag(jnp.array([1.3, 0.9, 0.8]))
    assert float(jax.grad(m.mixed_free_energy, argnums=3)(F, jnp.zeros(3), jnp.zeros((0, 3, 3)), 2e4, mat)) == \
        pytest.approx(1.3 * 0.9 * 0.8 - 1.0, rel=1e-12)
    with pytest.raises(ValueError, match="K = inf"):
        from dejax import mesh, model
        model.build_model(mesh.block_mesh(1e-3), mat, volumetric="displacement")


# ---------------------------------------------------------------------------
# Order of the flow-rule time discretizations (backward Euler, BDF2)
# ---------------------------------------------------------------------------


def _equibiaxial_xi_reference(times, lam_fn, mu, eta, Jm):
    """xi(t) of Cv = diag(xi^2, xi^2, xi^-4) under a prescribed equal-biaxial stretch
    lam(t) (F = diag(lam, lam, lam^-2)): the evolution equation of the reduced block model
    (docs/paper-notes.md), dxi/dt = mu / (3 eta H) (lam^2 / xi - xi^5 / lam^4),
    H = 1 - (2 lam^2 / xi^2 + xi^4 / lam^4 - 3) / Jm, solved by diffrax (Tsit5, rtol 1e-12)."""
    import diffrax

    def rate(t, xi, args):
        lam = lam_fn(t)
        H = 1.0 - (2.0 * lam ** 2 / xi ** 2 + xi ** 4 / lam ** 4 - 3.0) / Jm
        return mu / (3.0 * eta * H) * (lam ** 2 / xi - xi ** 5 / lam ** 4)

    sol = diffrax.diffeqsolve(diffrax.ODETerm(rate), diffrax.Tsit5(), times[0], times[-1], 1e-4, jnp.asarray(1.0),
                              saveat=diffrax.SaveAt(ts=jnp.asarray(times)), max_steps=100_000,
                              stepsize_controller=diffrax.PIDController(rtol=1e-12, atol=1e-14))
    return np.asarray(sol.ys)


@jax.jit
def _march_flow(times, lam, bdf2):
    """Cv_11 = xi^2 of one unit (mu 67 kPa, eta 3000 Pa s, Jm 5) stepped with the given
    flow-step construction under F_k = diag(lam_k, lam_k, lam_k^-2)."""
    mat = m.Material(mu_inf=67e3, K_inf=1e9, Jm_inf=15.0, eps=4e-11, rho=1e3, mu=[67e3], K=[1e9], Jm=[5.0],
                     eta=[3000.0])

    def body(c, x):
        Cv, Cv_prev, h_prev = c
        h, l = x
        F = jnp.diag(jnp.stack([l, l, l ** -2]))
        flow = jnp.where(bdf2, 1.0, 0.0)  # traced switch: one compilation for both
        fb = m.bdf2_flow_step(Cv, Cv_prev, h, h_prev * flow)  # h_prev = 0: backward Euler
        Cv1 = m.update_all_units(F, fb, None, mat)
        return (Cv1, Cv, h), Cv1[0, 0, 0]

    I = jnp.eye(3)[None]
    _, c11 = jax.lax.scan(body, (I, I, jnp.asarray(0.0)), (jnp.diff(times), lam[1:]))
    return c11


def test_flow_update_orders_against_the_reduced_model_ode():
    """Backward Euler converges at first order, BDF2 at second order, both to the diffrax
    solution of the reduced model's evolution equation (an independent derivation):
    halving dt divides the largest error over the second half (periodic regime; the
    first step, backward Euler in both, adds a start-up error of the same order that
    decays) by ~2 and ~4. Relaxation time eta / (2 mu) = 22 ms, 5 Hz stretch
    1 + 0.3 sin(2 pi 5 t) over 0.4 s, dt 2, 1, 0.5 ms."""
    lam_fn = lambda t: 1.0 + 0.3 * jnp.sin(2 * jnp.pi * 5.0 * t)
    errs = {False: [], True: []}
    for dt in (2e-3, 1e-3, 5e-4):
        times = np.arange(0.0, 0.4 + dt / 2, dt)
        ref = _equibiaxial_xi_reference(times, lam_fn, 67e3, 3000.0, 5.0)[1:] ** 2
        for bdf2 in (False, True):
            c11 = np.asarray(_march_flow(jnp.asarray(times), lam_fn(jnp.asarray(times)), bdf2))
            errs[bdf2].append(float(np.max(np.abs(c11 - ref)[times[1:] >= 0.2])))
    be, b2 = np.array(errs[False]), np.array(errs[True])
    print("backward Euler", be, "BDF2", b2)
    assert np.all((be[:-1] / be[1:] > 1.8) & (be[:-1] / be[1:] < 2.2)), be
    assert np.all((b2[:-1] / b2[1:] > 3.7) & (b2[:-1] / b2[1:] < 4.3)), b2
    assert np.all(b2 < 0.3 * be)


def test_bdf2_flow_step_falls_back_to_backward_euler():
    """First step (h_prev = 0), a step over twice the previous one, and a base that the
    extrapolation would make indefinite all give backward Euler's base and step."""
    Cv = jnp.diag(jnp.array([1.2, 1.1, 1 / 1.32]))[None]
    be = m.backward_euler_flow_step(Cv, 1e-3)
    for Cv_prev, h_prev in ((Cv, 0.0), (jnp.eye(3)[None], 4e-4), (jnp.diag(jnp.array([9.0, 1.0, 1 / 9.0]))[None], 1e-3)):
        fb = m.bdf2_flow_step(Cv, Cv_prev, 1e-3, h_prev)
        np.testing.assert_allclose(fb.base, be.base)
        np.testing.assert_allclose(fb.dt, be.dt)
    fb = m.bdf2_flow_step(Cv, jnp.eye(3)[None], 1e-3, 1e-3)  # a regular step: 4/3, -1/3, 2/3 h
    np.testing.assert_allclose(fb.base, 4 / 3 * Cv - 1 / 3 * jnp.eye(3)[None], rtol=1e-14)
    np.testing.assert_allclose(fb.dt, [2e-3 / 3], rtol=1e-14)


# ----------------------------------------------------------------------------- Mullins softening


def _mullins_material(d=0.4, m_=5e3):
    return Material(20e3, 2e8, 100.0, 4e-11, 1000.0, mu=[10e3], K=[1e8], Jm=[50.0], eta=[1e3],
                    mullins_d=d, mullins_m=m_)


def test_mullins_factor_is_one_off_and_on_the_primary_path():
    F = jnp.diag(jnp.array([1.3, 0.9, 1 / (1.3 * 0.9)]))
    W = float(m.equilibrium_gent_energy(F, _mullins_material()))
    eta, wmax = m.mullins_factor(F, 0.5 * W, _mullins_material())  # loading past the history
    assert float(eta) == 1.0 and float(wmax) == W
    eta, wmax = m.mullins_factor(F, W + 3e3, _mullins_material())  # below the largest energy seen
    assert float(eta) == pytest.approx(1 - 0.4 * float(jax.scipy.special.erf(3e3 / 5e3)), rel=1e-14)
    assert float(wmax) == W + 3e3
    assert float(m.mullins_factor(F, W + 3e3, _mullins_material(d=0.0))[0]) == 1.0
    with pytest.raises(ValueError, match="mullins_d"):
        _mullins_material(d=1.0).validate()


def test_mullins_stress_and_consistent_tangent():
    """Below the largest energy seen the stress is eta dW/dF + the other terms at eta held,
    and jacfwd of the stress (d eta/dF included) equals its central differences."""
    mat = _mullins_material()
    F = jnp.array([[1.25, 0.05, 0.0], [0.02, 0.92, 0.03], [0.0, 0.01, 0.88]])
    E = jnp.array([0.0, 0.0, 2e6])
    Cv_old = jnp.broadcast_to(jnp.eye(3), (1, 3, 3))
    stress_and_update = jax.jit(m.stress_and_update)  # compiled once: eager costs ~15 s here
    wmax = float(m.equilibrium_gent_energy(F, mat)) + 2e3
    P, Cv_new = stress_and_update(F, E, Cv_old, 1e-3, mat, wmax)
    eta = float(m.mullins_factor(F, wmax, mat)[0])
    assert 0.6 < eta < 1.0
    ref = jax.jit(jax.grad(m.free_energy), static_argnums=4)(F, E, Cv_new, mat, True, eta)
    np.testing.assert_allclose(np.asarray(P), np.asarray(ref), rtol=1e-12, atol=1e-9)
    D = jax.jit(m.stress_tangent_and_update)(F, E, Cv_old, 1e-3, mat, wmax)[1]
    h = 1e-6
    for i, j in [(0, 0), (0, 1), (2, 2), (1, 0)]:
        dF = jnp.zeros((3, 3)).at[i, j].set(h)
        fd = (stress_and_update(F + dF, E, Cv_old, 1e-3, mat, wmax)[0]
              - stress_and_update(F - dF, E, Cv_old, 1e-3, mat, wmax)[0]) / (2 * h)
        np.testing.assert_allclose(np.asarray(D[:, :, i, j]), np.asarray(fd), rtol=1e-6, atol=1e-6 * float(mat.mu_inf))
