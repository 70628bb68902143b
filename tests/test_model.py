"""Tests of the discrete model (dejax/model.py): the iteration matrix and the mixed form.

References: central finite differences of the residual (with the element pressures
eliminated exactly, p = K int (J - 1) dV / V_e), the symmetry the linear solvers rely
on (``SparseSolver.solve`` declares it to ``lax.custom_linear_solve``), and the closed
form of a slender cantilever under its own weight (Euler-Bernoulli plus Timoshenko
shear), which shows whether the nearly incompressible element locks. (Measured on the
same 10 x 1 x 1 mesh, for the record: the paper's pointwise penalty gives 0.93 of the
beam value in its linear response; a constant pressure per element gives a near
zero-energy bending mode, ~2000 times too soft, which is why the default pressure is
linear per element.)
"""
from __future__ import annotations

import numpy as np
import pytest

import dejax  # noqa: F401  (float64)
import equinox as eqx
import jax
import jax.numpy as jnp
from dejax import constraints as cs
from dejax import integrate as it
from dejax import mesh
from dejax import model as mdl
from dejax.material import Material

L = 1e-3


def _block_model(volumetric, viscous, K_ratio):
    m = mesh.block_mesh(L, shape=(1, 1, 1))
    c = cs.Constraints(m.n_dofs)
    for name, ax in (("x0", 0), ("y0", 1), ("z0", 2)):
        c = c.fix(cs.face_dofs(m.nodes(name), ax, [ax]))
    units = dict(mu=[30e3, 60e3], K=[0.0, 0.0], Jm=[5.0, 8.0], eta=[40.0, 3.0]) if viscous else {}
    mat = Material(67e3, K_ratio * 67e3, 15.0, 4e-11, 1100.0, **units)
    return mdl.build_model(m, mat, c, gauss_order=3, volumetric=volumetric)


def _deformed_inputs(model, seed=0):
    """A generic state: perturbed coordinates, det-1 viscous tensors away from I, a field."""
    rng = np.random.default_rng(seed)
    s = model.structure
    z = np.asarray(model.q0)[s.free] + 0.03 * np.asarray(mdl.dof_scale(model)) * rng.standard_normal(s.n_free)
    n_el, n_gp = model.dV.shape
    nu = model.material.n_units
    A = 0.1 * rng.standard_normal((n_el, n_gp, nu, 3, 3))
    A = A + np.swapaxes(A, -1, -2)
    A = A - np.trace(A, axis1=-2, axis2=-1)[..., None, None] / 3 * np.eye(3)
    Cv = jnp.asarray(jax.vmap(jax.scipy.linalg.expm)(A.reshape(-1, 3, 3)).reshape(A.shape))
    E = mdl.nominal_field(model, jnp.array([5e3]))
    return jnp.asarray(z), Cv, E


OPTIONS = [
    ("displacement", False, 10.0),
    ("displacement", True, 10.0),
    ("mixed", False, 10.0),
    ("mixed", True, 10.0),
    ("mixed-constant", True, 10.0),
    ("mixed", True, np.inf),
]


@pytest.mark.parametrize("volumetric, viscous, K_ratio", OPTIONS)
def test_iteration_matrix_symmetric_and_consistent(volumetric, viscous, K_ratio):
    """The assembled consistent tangent (viscous dCv/dF and, in the mixed form, the
    condensed element pressures included) is symmetric, for every material option, and
    for finite K it is the derivative of the residual with the pressures eliminated.
    A soft bulk (K = 10 mu) keeps the shear and viscous parts visible in the comparison."""
    model = _block_model(volumetric, viscous, K_ratio)
    z, Cv, E = _deformed_inputs(model)
    dt = 2e-2
    u = jnp.zeros(0)

    def eliminated_pressure(q):
        """p solving g(p) = int N (J - 1) dV - int N N^T dV p / K = 0 exactly (finite K)."""
        _, g0, _ = mdl.element_forces(model, q, E, Cv, dt, None)
        return K_ratio * 67e3 * jnp.linalg.solve(mdl.pressure_mass(model), g0[..., None])[..., 0]

    @jax.jit
    def tangent(z):
        q = mdl.full_coordinates(model, z, u)
        p = None
        if model.structure.mixed:
            p = eliminated_pressure(q) if np.isfinite(K_ratio) else jnp.full((1, model.structure.n_pressure), 3e3)
        _, Ke, _ = mdl.element_tangents(model, q, E, Cv, dt, p)
        return mdl.assemble_dense(model, Ke)

    K = np.asarray(tangent(z))
    scale = np.abs(K).max()
    assert np.abs(K - K.T).max() <= 1e-13 * scale
    if not np.isfinite(K_ratio):
        return

    @jax.jit
    def residual(z):
        q = mdl.full_coordinates(model, z, u)
        p = eliminated_pressure(q) if model.structure.mixed else None
        return mdl.reduce(model, mdl.internal_force(model, q, E, Cv, dt, p)[0])

    s = model.structure
    fd = np.zeros_like(K)
    for j, h in enumerate(1e-6 * np.asarray(mdl.dof_scale(model))):
        e = jnp.zeros(s.n_free).at[j].set(h)
        fd[:, j] = (np.asarray(residual(z + e)) - np.asarray(residual(z - e))) / (2 * h)
    assert np.abs(fd - K).max() <= 1e-6 * scale


# ----------------------------------------------------------------------------- locking


def _tip_deflection(model, loading, st):
    n = jnp.asarray(model.structure.node_sets["x1"])
    q, q0 = st.q.reshape(-1, 4, 3), model.q0.reshape(-1, 4, 3)
    return {"tip": jnp.mean(q[n, 0, 2] - q0[n, 0, 2])}


def _cantilever(n_thick, volumetric, n_long=10):
    """20 x 1 x 1 mm cantilever, clamped at x = 0, under gravity g = 0.025 m/s^2 (tip
    deflection ~ 1e-3 of its length: linear regime), mu = 100 kPa, K = 1e4 mu."""
    length, t, g, mu, K, rho = 20e-3, 1e-3, 0.025, 1e5, 1e9, 1000.0
    msh = mesh.block_mesh(length, t, t, shape=(n_long, 1, n_thick))
    c = cs.Constraints(msh.n_dofs).fix(cs.face_dofs(msh.nodes("x0"), 0, [0, 1, 2]))
    model = mdl.build_model(msh, Material(mu, K, 1e3, 0.0, rho), c, gravity=(0.0, 0.0, -g), volumetric=volumetric)
    sol = it.simulate(model, it.Loading(), np.array([0.0, 1.0]), _tip_deflection, it.QuasiStatic()).check()
    return -float(sol.outputs["tip"][-1]), _cantilever_reference()[1]


def _cantilever_reference(length=20e-3, t=1e-3, g=0.025, mu=1e5, K=1e9, rho=1000.0):
    """Tip deflection (m) of the cantilever under its weight: Euler-Bernoulli q L^4/(8 E I)
    plus Timoshenko shear q L^2/(2 kappa G A), kappa = 5/6, E = 9 K mu / (3 K + mu)."""
    E = 9 * K * mu / (3 * K + mu)
    q = rho * g * t * t
    return None, q * length**4 / (8 * E * t**4 / 12) + q * length**2 / (2 * (5 / 6) * mu * t * t)


@pytest.mark.parametrize("n_thick", [1, pytest.param(2, marks=pytest.mark.slow), pytest.param(4, marks=pytest.mark.slow)])
def test_cantilever_does_not_lock(n_thick):
    """Mixed form: the tip deflection of the nearly incompressible cantilever matches the
    beam closed form at 1, 2 and 4 elements through the thickness (2 and 4: slow tier,
    measured 0.972 and 0.976 of the beam value)."""
    tip, ref = _cantilever(n_thick, "mixed")
    print(f"\nmixed, {n_thick} through the thickness: tip {tip:.4e} m, beam theory {ref:.4e} m, ratio {tip / ref:.4f}")
    assert tip == pytest.approx(ref, rel=0.03)


def test_dead_face_traction_gives_the_energy_stationary_stretch():
    """A 2 x 2 x 2 hyperelastic block pulled by a dead nominal traction s on its free faces
    x = L and y = L (model.dead_load from face_traction_load, no voltage): the quasi-static
    lateral stretch equals the stationary point of Gent energy - 2 s (lam - 1) per volume
    with lam_z = lam^-2 (nearly incompressible: K/mu = 1e5), found by scipy."""
    from scipy import optimize

    from dejax import integrate as it
    from dejax import loads
    from dejax import scenarios as sc

    s = 20e3
    mat = sc.block_material(mu=[], K=[], Jm=[], eta=[])
    prob = sc.block(shape=(2, 2, 2), material=mat, voltage=loads.Constant(0.0))
    mesh = prob.extras["mesh"]
    load = mdl.face_traction_load(mesh, "x1", (s, 0.0, 0.0)) + mdl.face_traction_load(mesh, "y1", (0.0, s, 0.0))
    model = eqx.tree_at(lambda m: m.dead_load, prob.model, load)
    sol = it.simulate(model, prob.loading, np.linspace(0.0, 1.0, 6), prob.output_fn, it.QuasiStatic()).check()
    lam = float(sol.outputs["lateral_stretch"][-1])
    mu, Jm = 67e3, 15.0
    d_pot = lambda l: (-0.5 * mu * Jm * np.log(1 - (2 * (l + 1e-7) ** 2 + (l + 1e-7) ** -4 - 3) / Jm) - 2 * s * (l + 1e-7)
                       + 0.5 * mu * Jm * np.log(1 - (2 * (l - 1e-7) ** 2 + (l - 1e-7) ** -4 - 3) / Jm) + 2 * s * (l - 1e-7)) / 2e-7
    ref = optimize.brentq(d_pot, 1.0, 1.5, xtol=1e-14)
    assert lam == pytest.approx(ref, rel=1e-5) and lam > 1.05


def test_dof_scale_of_a_traced_mesh_is_the_element_size():
    """Norms weight positions by the element size; a mesh built from traced geometry (h, L,
    r under jax.jit / jacfwd) must get the same scale as a concrete one, or Newton's
    relative tolerance means something else in a differentiated run (it once fell back to
    1 m, and the 4x8x1 tube's first step failed only when h was traced)."""
    from dejax import scenarios as sc

    def scale(h):
        return mdl.dof_scale(sc.rolled("IV", shape=(1, 4, 1), h=h).model)

    eager, traced = np.asarray(scale(2e-3)), np.asarray(jax.jit(scale)(2e-3))
    m = sc.rolled("IV", shape=(1, 4, 1), h=2e-3).model
    ell = np.cbrt(np.sum(np.asarray(m.dV)) / m.dV.shape[0])  # m: one element's volume, cube root
    pos = np.asarray(m.structure.is_position)
    assert 1e-4 < ell < 1e-2
    np.testing.assert_allclose(eager[pos], ell, rtol=1e-14)
    np.testing.assert_allclose(eager[~pos], 1.0)
    np.testing.assert_allclose(traced, eager, rtol=1e-14)


def test_over_points_equals_the_nested_vmap():
    """One vmap over the merged (element, Gauss point) axes gives what vmap(vmap) gives,
    for pytree arguments, shared arguments and an empty unit axis (n_units = 0)."""
    rng = np.random.default_rng(0)
    F = jnp.asarray(rng.standard_normal((3, 4, 3, 3)))
    units = dict(a=jnp.asarray(rng.standard_normal((3, 4, 2, 3, 3))), empty=jnp.zeros((3, 4, 0, 3, 3)))
    scale = 1.7

    def point(F, units, s):
        return dict(P=s * F @ F.T + jnp.sum(units["a"], axis=0), n=units["empty"].shape[0] + jnp.trace(F))

    nested = jax.vmap(jax.vmap(point, in_axes=(0, 0, None)), in_axes=(0, 0, None))(F, units, scale)
    merged = mdl.over_points(point, (0, 0, None))(F, units, scale)
    assert merged["P"].shape == (3, 4, 3, 3) and merged["n"].shape == (3, 4)
    np.testing.assert_array_equal(np.asarray(merged["P"]), np.asarray(nested["P"]))
    np.testing.assert_array_equal(np.asarray(merged["n"]), np.asarray(nested["n"]))


def test_gathered_assembly_equals_the_scatter_loop():
    """T^T K T, T^T r and the slot sums are gathers of precomputed entries (``mdl.assembly``);
    on the torsional strip (clamped end: dropped coordinates; the far face's common axial
    position: tied ones, summed) they equal numpy's unbuffered scatter-add over the elements, and the sparse values
    (CSC order) are the dense matrix's entries at the pattern, those of its upper triangle
    alone (``mdl.assemble_upper``) as well. The tied face's entries sum
    more contributions than one gather row holds (``mdl.GATHER_WIDTH``): their surplus is
    scattered, and checked here as well."""
    from dejax import scenarios as sc

    m = sc.torsional(0.5, 1.0, shape=(1, 2, 2)).model
    s = m.structure
    rng = np.random.default_rng(0)
    n_el, n = s.edofs.shape[0], s.n_free
    Ke = rng.standard_normal((n_el, 96, 96))
    r = rng.standard_normal(s.n_dofs)
    fe = rng.standard_normal((n_el, 32, 3))
    assert np.any(np.bincount(s.col[s.col >= 0]) > 1) and np.any(s.col < 0)  # ties and constraints both present

    ref = np.zeros((n + 1, n + 1))
    idx = np.where(s.col >= 0, s.col, n)[s.edofs]
    for e in range(n_el):
        np.add.at(ref, (idx[e][:, None], idx[e][None, :]), Ke[e])
    ref = ref[:n, :n]
    np.testing.assert_allclose(np.asarray(mdl.assemble_dense(m, jnp.asarray(Ke))), ref, rtol=1e-13, atol=1e-13)
    a = mdl.assembly(s)
    values = np.asarray(mdl.assemble_values(m, jnp.asarray(Ke)))
    np.testing.assert_allclose(values, ref[a.rows, a.cols], rtol=1e-13, atol=1e-13)
    assert np.count_nonzero(ref) == a.nnz and np.all(np.diff(a.cols.astype(np.int64) * n + a.rows) > 0)
    # the tied coordinates have more contributions than one gather row holds: the surplus path ran
    assert a.entries.extra_source.size > 0 and a.reduce_entries.extra_source.size > 0
    # the upper triangle alone (what Pardiso's Cholesky reads), surplus entries included
    upper = np.asarray(mdl.assemble_upper(m, jnp.asarray(Ke)))
    rows, cols = a.rows[a.upper], a.cols[a.upper]
    assert np.all(rows >= cols) and a.upper.size == np.count_nonzero(a.rows >= a.cols)
    np.testing.assert_allclose(upper, ref[rows, cols], rtol=1e-13, atol=1e-13)
    assert a.upper_entries.extra_source.size > 0

    red = np.zeros(n + 1)
    np.add.at(red, np.where(s.col >= 0, s.col, n), r)
    np.testing.assert_allclose(np.asarray(mdl.reduce(m, jnp.asarray(r))), red[:n], rtol=1e-13, atol=1e-13)
    slots = np.zeros((s.n_dofs // 3, 3))
    np.add.at(slots, s.slots, fe)
    np.testing.assert_allclose(np.asarray(mdl.scatter_slots(m, jnp.asarray(fe))), slots.reshape(-1), rtol=1e-13,
                               atol=1e-13)


@pytest.mark.parametrize("volumetric, chunk", [("mixed", 3), ("displacement", 3), ("mixed", None)])
def test_element_chunks_equal_the_whole_mesh(monkeypatch, volumetric, chunk):
    """Large meshes evaluate the element system and forces a chunk of elements at a time
    (``mdl.over_element_chunks``); with chunks forced on a 16-element tube (5 chunks of 3
    and a remainder of 1; or the divisor nearest 3: 8 chunks of 2) they equal the
    whole-mesh evaluation, forces' jvp and the condensed matrices included (condensed after
    the element system, and chunk by chunk as ``mdl.condensed_system`` does), and the mass
    coefficient adds c M_e to every element matrix."""
    from dejax import scenarios as sc

    m = sc.rolled("IV", 30.0, 50e3, shape=(4, 4, 1), volumetric=volumetric).model
    z, Cv, _ = _deformed_inputs(m)
    q = mdl.full_coordinates(m, z, jnp.zeros(m.prescribed_dirs.shape[0]))
    E = mdl.nominal_field(m, jnp.array([3e4]))
    from dejax import material as mat

    flow = jax.vmap(jax.vmap(lambda C: mat.backward_euler_flow_step(C, 1e-3)))(Cv)
    p = 1e3 * jnp.ones_like(mdl.initial_pressure(m)) if m.structure.mixed else None
    dq = jnp.asarray(np.random.default_rng(3).standard_normal(q.shape)) * 1e-6

    def evaluate():
        sys = jax.jit(lambda q: mdl.element_system(m, q, E, flow, 1e-3, p, None, mass_coefficient=2e5))(q)
        plain = jax.jit(lambda q: mdl.element_system(m, q, E, flow, 1e-3, p, None))(q)
        forces = jax.jit(lambda q, dq: jax.jvp(lambda q: mdl.element_forces(m, q, E, flow, 1e-3, p, None), (q,), (dq,)))(q, dq)
        condensed = jax.jit(mdl.condense)(sys.Ke, sys.kup, sys.kpp) if m.structure.mixed else None
        if m.structure.mixed:  # condensed chunk by chunk as made: the same matrices
            fused = jax.jit(lambda q: mdl.condensed_system(m, q, E, flow, 1e-3, p, None, mass_coefficient=2e5))(q)
            np.testing.assert_allclose(np.asarray(fused.Kc), np.asarray(condensed), rtol=0,
                                       atol=1e-13 * float(jnp.max(jnp.abs(condensed))))
            np.testing.assert_array_equal(np.asarray(fused.kup), np.asarray(sys.kup))
            np.testing.assert_array_equal(np.asarray(fused.kpp), np.asarray(sys.kpp))
            for name in ("fe", "g", "Cv_new"):  # the element equations it was made with (another program)
                a, b = np.asarray(getattr(fused, name)), np.asarray(getattr(sys, name))
                np.testing.assert_allclose(a, b, rtol=0, atol=1e-13 * float(np.max(np.abs(b))))
        return sys, plain, forces, condensed

    whole = evaluate()
    np.testing.assert_allclose(np.asarray(whole[0].Ke), np.asarray(whole[1].Ke + 2e5 * mdl.mass_elements(m)),
                               rtol=1e-13, atol=1e-13 * float(jnp.max(jnp.abs(whole[0].Ke))))
    monkeypatch.setattr(mdl, "CHUNK_FROM", 1)
    monkeypatch.setattr(mdl, "CHUNK_ELEMENTS", 3)
    if chunk is not None:
        monkeypatch.setattr(mdl, "_chunk_size", lambda n_el, target: chunk)
    else:
        assert mdl._chunk_size(16, 3) == 2 and mdl._chunk_size(960, 16) == 16 and mdl._chunk_size(13, 4) == 4
    chunked = evaluate()
    for a, b in zip(jax.tree_util.tree_leaves(whole), jax.tree_util.tree_leaves(chunked)):
        assert a.shape == b.shape
        np.testing.assert_allclose(np.asarray(b), np.asarray(a), rtol=0, atol=1e-12 * float(jnp.max(jnp.abs(a))) + 1e-300)
