"""Independent checks of the paper scenarios (rolled tube, torsional strip).

Each check compares the discrete model with something it must satisfy for reasons
outside the code: frame indifference, equilibrium of the reference state, the
closed-form equal-biaxial Gent membrane (a thin free tube under a radial field),
mesh convergence, and the physics of viscous stiffening.

Cost: every distinct mesh compiles its time stepper once (~15-40 s on 2 CPU cores),
so the default set compiles twice (test b and the torsional strip against FElupe on a
24 x 4 x 2 mesh); the thin-tube membrane check, the convergence study and the torsional
strip on the paper's mesh are marked ``slow`` (``pytest --runslow``).
"""
import json
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from dejax import constraints as cs
from dejax import integrate as it
from dejax import linsolve, loads
from dejax import model as mdl
from dejax import scenarios
from dejax.mesh import rolled_tube_mesh
from dejax.verification import models as ref


def _rotation(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def _rigid(q, R, c=np.zeros(3)):
    """Apply x -> R x + c to the positions and R to the gradient coordinates."""
    q = np.asarray(q).reshape(-1, 4, 3)
    out = q @ R.T
    out[:, 0, :] += c
    return out.reshape(-1)


def _stretched(q0, lam):
    """Homogeneous deformation diag(lam) applied to reference coordinates."""
    q = np.asarray(q0).reshape(-1, 4, 3) * np.asarray(lam)
    return q.reshape(-1)


# ----------------------------------------------------------------------------- (a) objectivity


def test_rigid_rotation_changes_no_energy_and_gives_no_force():
    p = scenarios.rolled("IV", shape=(2, 6, 1), h=2e-3, r=2e-3, L=8e-3)
    m = p.model
    Cv = mdl.initial_viscous_state(m)
    E0 = mdl.nominal_field(m, jnp.zeros(1))
    E1 = mdl.nominal_field(m, jnp.array([20e3]))
    R = _rotation([0.3, -1.0, 0.7], 0.9)
    c = np.array([1e-3, -2e-3, 5e-4])
    q0 = np.asarray(m.q0)
    energy = jax.jit(mdl.free_energy_total)
    force = jax.jit(mdl.internal_force_at)

    # reference scales: a 1 % uniaxial-ish stretch of the same tube
    q1 = _stretched(q0, [1.01, 0.995, 0.995])
    W_ref = float(energy(m, jnp.asarray(q1), E0, Cv))
    f_ref = float(jnp.max(jnp.abs(force(m, jnp.asarray(q1), E0, Cv))))
    assert W_ref > 0 and f_ref > 0

    # rigid motion of the reference state: no energy, no force
    qr = jnp.asarray(_rigid(q0, R, c))
    assert abs(float(energy(m, qr, E0, Cv))) <= 1e-9 * W_ref
    assert float(jnp.max(jnp.abs(force(m, qr, E0, Cv)))) <= 1e-7 * f_ref

    # rigid motion superposed on a deformed state, with a field (nominal, i.e. material):
    # energy unchanged, force rotated with the body (f_pos -> R f_pos, f_grad -> R f_grad)
    for E in (E0, E1):
        W1 = float(energy(m, jnp.asarray(q1), E, Cv))
        W2 = float(energy(m, jnp.asarray(_rigid(q1, R, c)), E, Cv))
        assert abs(W2 - W1) <= 1e-9 * max(abs(W1), W_ref)
        f1 = np.asarray(force(m, jnp.asarray(q1), E, Cv))
        f2 = np.asarray(force(m, jnp.asarray(_rigid(q1, R, c)), E, Cv))
        assert np.max(np.abs(f2 - _rigid(f1, R))) <= 1e-7 * f_ref


# ----------------------------------------------------------------------------- (b) rest


def test_zero_voltage_tube_stays_at_rest():
    p = scenarios.rolled("IV", shape=(1, 4, 1), freq=30.0, phi_max=0.0)
    sol = p.simulate(0.01, 1e-3).check()
    x = np.asarray(sol.outputs["x_P"])
    assert np.all(np.isfinite(x))
    assert np.max(np.abs(x)) <= 1e-12 * 8e-3
    d = (np.asarray(sol.final.q) - np.asarray(p.model.q0)).reshape(-1, 4, 3)
    assert np.max(np.abs(d[:, 0])) <= 1e-12 * 8e-3  # positions (m)
    assert np.max(np.abs(d[:, 1:])) <= 1e-11  # gradient coordinates (-): Newton round-off


# ----------------------------------------------------------------------------- (c) thin tube


class _VoltageOnly(eqx.Module):

    def __call__(self, model, loading, state):
        return {"voltage": loading.phi(state.t)[0]}


def free_thin_tube(h, r, L, shape):
    """Tube with u1 = 0 on the bottom face and only rigid motions removed: nodes of the
    bottom face at angles 0 and pi keep z, at pi/2 and 3 pi/2 keep y (radial motion free)."""
    mesh = rolled_tube_mesh(h, r, L, shape=shape)
    X = np.asarray(mesh.X)
    bottom = mesh.nodes("bottom")
    tol = 1e-9 * r
    on_y = bottom[np.abs(X[bottom, 2]) < tol]  # angle 0, pi
    on_z = bottom[np.abs(X[bottom, 1]) < tol]  # angle pi/2, 3 pi/2
    assert len(on_y) >= 2 and len(on_z) >= 2
    c = cs.Constraints(mesh.n_dofs)
    c = c.fix(cs.face_dofs(bottom, 0, [0]))
    c = c.fix(cs.dof_index(on_y, 0, 2))
    c = c.fix(cs.dof_index(on_z, 0, 1))
    return mesh, c


@pytest.mark.slow  # ~40 s compile + 80 full-Newton steps: over the default budget with (a) and (b)
def test_thin_free_tube_reaches_equibiaxial_gent_stretch():
    r, L = 2e-3, 2e-3
    h = r / 20
    mat = scenarios.rolled_material("hyperelastic")
    mesh, c = free_thin_tube(h, r, L, (1, 8, 1))
    m = mdl.build_model(mesh, mat, c, damping=200.0)
    lam_target = 1.1
    phi = float(ref.gent_equibiaxial_voltage(lam_target, h, mat.mu_inf, mat.Jm_inf, mat.eps))
    lam_exact = ref.gent_equibiaxial_stretch(phi, h, mat.mu_inf, mat.Jm_inf, mat.eps)
    assert abs(lam_exact - lam_target) < 1e-9
    loading = it.Loading(voltages=(loads.RampHold(phi, 0.03),))
    # full Newton: the default modified Newton (reuse=True) stalls mid-ramp on this
    # thin-walled free tube (step 16 at dt = 1e-3 s: NEWTON_FAILED)
    newton = it.NewtonOptions(reuse=False, max_iter=40)
    sol = it.simulate(m, loading, it.time_grid(0.08, 1e-3), _VoltageOnly(), it.GeneralizedAlpha(0.0), newton).check()
    q = np.asarray(sol.final.q).reshape(-1, 4, 3)
    X = np.asarray(mesh.X)
    top, bottom = mesh.nodes("top"), mesh.nodes("bottom")
    lam_axial = (q[top, 0, 0].mean() - q[bottom, 0, 0].mean()) / L
    rho = np.hypot(q[:, 0, 1], q[:, 0, 2])
    inner, outer = mesh.nodes("inner"), mesh.nodes("outer")
    lam_circ = 0.5 * (rho[inner].mean() + rho[outer].mean()) / (r + 0.5 * h)
    lam_thick = (rho[outer].mean() - rho[inner].mean()) / h
    assert abs(lam_axial / lam_exact - 1) < 0.01, (lam_axial, lam_exact)
    assert abs(lam_circ / lam_exact - 1) < 0.01, (lam_circ, lam_exact)
    # incompressible: thickness stretch 1/lam^2
    assert abs(lam_thick * lam_exact**2 - 1) < 0.02, lam_thick
    # static: the velocity has died out
    assert np.max(np.abs(np.asarray(sol.final.v))) * 1e-3 < 1e-3 * (lam_exact - 1) * L


# ----------------------------------------------------------------------------- (d) convergence


def mesh_convergence(shapes, t_end=0.01, dt=1e-3, phi_max=50e3):
    """x_P(t_end) for each mesh shape (rolled Model IV tube, Eq. 42 sine at 30 Hz)."""
    out = []
    for shape in shapes:
        p = scenarios.rolled("IV", shape=shape, phi_max=phi_max)
        sol = p.simulate(t_end, dt).check()
        out.append(float(np.asarray(sol.outputs["x_P"])[-1]))
    return np.array(out)


def observed_rate(values, ratio):
    """Richardson observed order from three solutions on meshes refined by ``ratio``."""
    d1 = values[0] - values[1]
    d2 = values[1] - values[2]
    return float(np.log(abs(d1 / d2)) / np.log(ratio))


@pytest.mark.slow
def test_mesh_refinement_of_x_P_converges():
    # refine the circumferential direction (the one the paper says governs convergence)
    x = mesh_convergence([(1, 4, 1), (1, 8, 1), (1, 16, 1)])
    print("x_P(t=0.01 s) on n_s = 4, 8, 16:", x, "observed rate", observed_rate(x, 2.0))
    assert np.all(x > 0)
    assert abs(x[2] - x[1]) < abs(x[1] - x[0])  # differences shrink
    assert observed_rate(x, 2.0) > 1.0


# ----------------------------------------------------------------------------- (e) torsional


REFERENCE = Path(__file__).resolve().parent.parent / "data" / "reference"


def _felupe(shape):
    """FElupe 11.3 twist angles of the same strip (27-node hexahedra, (u, p, J) form),
    recorded by bench/felupe_torsional.py (phibar 0 -> 0.5 in 10 increments)."""
    path = REFERENCE / f"torsional_felupe_{'x'.join(map(str, shape))}.json"
    with open(path) as f:
        return json.load(f)


def _twist(shape, viscous=False, t_ramp=1.0, n_inc=10, phibar=0.5, solver=None):
    p = scenarios.torsional(phibar, t_ramp, viscous=viscous, shape=shape)
    solver = solver or linsolve.choose_solver(p.model.structure)
    sol = p.simulate(t_ramp, t_ramp / n_inc, quasi_static=True, solver=solver)
    sol.check()
    return np.asarray(sol.outputs["twist_angle"]), sol


def test_torsional_twist_matches_an_independent_fe_code():
    """Paper Sec. 5 strip, hyperelastic, quasi-static, phibar 0 -> 0.5 in 10 increments, on
    12 x 4 x 2 ANCF elements (2,340 unknowns, the sparse solver), against FElupe on 48 x 8
    x 2 tri-quadratic hexahedra (36,836 unknowns, its own mixed form, supports and Newton
    loop). FElupe's own mesh error is about 1e-3 (its 24 x 4 x 2 mesh differs from its 48 x
    8 x 2 one by at most 1.0e-3 relative); the ANCF 12 x 4 x 2, 24 x 4 x 2 and 48 x 8 x 2
    meshes measured within 6.5e-4, 1.1e-3 and 1.2e-3 of FElupe's finest (12 x 2 x 2 and
    24 x 2 x 2: 3.1e-2: two elements across the width are too few). 5e-3 bounds both
    errors."""
    ang, sol = _twist((12, 4, 2), solver=linsolve.SparseSolver())
    ref = _felupe((48, 8, 2))
    np.testing.assert_allclose(ref["phibar"], np.linspace(0.0, 0.5, 11), atol=1e-12)
    print("\ntwist (rad) dejax / FElupe:", [f"{a:.5f}/{r:.5f}" for a, r in zip(ang, ref["twist_angle"])])
    np.testing.assert_allclose(ang[1:], ref["twist_angle"][1:], rtol=5e-3)
    assert ang[-1] > 0.6  # a large twist: the strip untwists by 37 degrees at phibar 0.5
    assert np.max(np.asarray(sol.iterations)) <= 12 and sol.n_cutbacks == 0


@pytest.mark.slow
def test_torsional_paper_mesh_matches_felupe_and_viscous_unit_stiffens():
    """The paper's 48 x 8 x 2 = 768 elements against FElupe's 48 x 8 x 2 hex27 (measured
    1.1e-3, asserted 2e-3); with the viscous unit (relaxation time eta_1/(2 mu_1) = 2.5 ms)
    on 24 x 4 x 2: the 1 s ramp gives a smaller twist than the hyperelastic strip (the
    paper's Fig. 9(b) observation; measured 0.917x on 48 x 8 x 2), a 2.5 ms ramp a far
    smaller one (unrelaxed unit, mu_inf + mu_1 = 7.7 mu_inf; measured 0.11x)."""
    ang, _ = _twist((48, 8, 2))
    np.testing.assert_allclose(ang[1:], _felupe((48, 8, 2))["twist_angle"][1:], rtol=2e-3)
    hyper, _ = _twist((24, 4, 2))
    slow, _ = _twist((24, 4, 2), viscous=True)
    fast, _ = _twist((24, 4, 2), viscous=True, t_ramp=2.5e-3)
    print(f"\ntwist at 0.5: hyperelastic {hyper[-1]:.5f}, viscous 1 s ramp {slow[-1]:.5f}, 2.5 ms ramp {fast[-1]:.5f}")
    assert 0.8 * hyper[-1] < slow[-1] < 0.99 * hyper[-1]
    assert np.all(np.diff(slow) > 0) and np.all(np.diff(fast) > 0)
    assert 0 < fast[-1] < 0.3 * hyper[-1]


# ----------------------------------------------------------------------------- registry


def test_registry_builds_every_scenario_and_rebuilds_its_mesh_from_the_parameters():
    assert scenarios.NAMES == ("block", "rolled", "torsional", "uniaxial")
    kwargs = {"block": {}, "rolled": dict(shape=(1, 4, 1)), "torsional": dict(shape=(4, 2, 2)),
              "uniaxial": dict(stretch=loads.Constant(1.0), material=scenarios.block_material())}
    for name in scenarios.NAMES:
        entry = scenarios.get(name)
        p = entry.build(**kwargs[name])
        assert p.name == name == p.params["scenario"]
        # equal outputs of rebuilt problems compare and hash equal (one compiled stepper)
        q = entry.build(**kwargs[name])
        assert p.output_fn == q.output_fn and hash(p.output_fn) == hash(q.output_fn)
        if entry.mesh is not None:
            np.testing.assert_array_equal(np.asarray(entry.mesh(p.params).X), np.asarray(p.extras["mesh"].X))
    with pytest.raises(ValueError, match="unknown scenario 'tube'; known: block, rolled, torsional, uniaxial"):
        scenarios.get("tube")
