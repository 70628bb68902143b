"""Instability reporting (dejax.stability): pull-in of the DE block against its closed form."""
import numpy as np
import pytest

from dejax import integrate as it
from dejax import loads, scenarios, stability


def pull_in_field(mu, Jm, eps):
    """Nominal field phi/L (V/m) at the pull-in of a free, incompressible Gent film under
    equibiaxial in-plane stretch lam, thickness stretch lam^-2 (Zhao & Suo 2007 form):
    mu (lam^2 - lam^-4) / (1 - (2 lam^2 + lam^-4 - 3)/Jm) = eps (phi/L)^2 lam^4, i.e.
    (phi/L)^2 = mu (1 - lam^-6) / (eps lam^2 H); pull-in at its first maximum over lam.
    Returns (field, lam at pull-in)."""
    lam = np.linspace(1.0 + 1e-6, 3.0, 2_000_001)
    H = 1.0 - (2 * lam**2 + lam**-4 - 3.0) / Jm
    e2 = mu * (1.0 - lam**-6) / (eps * lam**2 * H)
    k = int(np.flatnonzero(np.diff(e2) < 0)[0])
    return float(np.sqrt(e2[k])), float(lam[k])


def test_pull_in_closed_form_is_the_neo_hookean_limit():
    # independent check of the reference itself: neo-Hooke (Jm -> inf) has lam_c = 4^(1/6),
    # field_c = sqrt(mu/eps) sqrt(3/4) / 4^(1/6)
    e, lam = pull_in_field(1.0, 1e12, 1.0)
    assert lam == pytest.approx(4 ** (1 / 6), rel=1e-5)
    assert e == pytest.approx(np.sqrt(0.75) / 4 ** (1 / 6), rel=1e-9)


def test_block_pull_in_is_reported_as_an_instability_at_the_closed_form_voltage():
    """Voltage ramp on the hyperelastic block (nearly neo-Hookean: Jm = 1e3, so no Gent
    restabilization within reach) to 1.25 x the pull-in voltage, quasi-static: the run
    fails at the pull-in, reported as an instability, with the last converged voltage
    within 0.5 % of the closed form (K/mu = 1e5: compressibility shifts it by ~1e-5)."""
    mat = scenarios.block_material(mu=[], K=[], Jm=[], eta=[], Jm_inf=1e3)
    L = 1e-3
    e_c, lam_c = pull_in_field(mat.mu_inf, mat.Jm_inf, mat.eps)
    phi_c = e_c * L
    voltage = loads.PiecewiseLinear([0.0, 1.0], [0.0, 1.25 * phi_c])
    p = scenarios.block(L=L, material=mat, voltage=voltage)
    sol = p.simulate(1.0, 0.05, quasi_static=True)
    print(f"\npull-in: closed form {phi_c:.6g} V at lam {lam_c:.5f}; status {it.Status(int(sol.status)).name}, "
          f"last converged t = {float(sol.last_converged.t):.6g} s; {sol.detail}")
    assert it.Status(int(sol.status)) == it.Status.INSTABILITY
    phi_last = float(voltage(sol.last_converged.t))
    assert phi_last == pytest.approx(phi_c, rel=5e-3)
    assert phi_last <= phi_c * (1 + 1e-4)  # no equilibrium past the pull-in voltage
    lam_last = float(p.output_fn(p.model, p.loading, sol.last_converged)["lateral_stretch"])
    assert lam_last == pytest.approx(lam_c, rel=2e-2)  # the fold is flat in lam: a looser check
    with pytest.raises(it.SimulationError, match="instability"):
        sol.check()


def test_a_plain_newton_failure_is_not_called_an_instability():
    """Same block, far below pull-in, with a Newton budget too small to converge: the
    static tangent stays positive definite, so the failure stays a Newton failure."""
    mat = scenarios.block_material(mu=[], K=[], Jm=[], eta=[], Jm_inf=1e3)
    p = scenarios.block(material=mat, voltage=loads.PiecewiseLinear([0.0, 1.0], [0.0, 10e3]))
    sol = p.simulate(1.0, 0.5, quasi_static=True, newton=it.NewtonOptions(max_iter=1),
                     control=it.StepControl(dt_min=0.25))
    assert it.Status(int(sol.status)) == it.Status.NEWTON_FAILED
    assert "not an instability" in sol.detail
    ratio = stability.static_eigenvalue(p.model, p.loading, sol.last_converged, 0.25) / \
        stability.reference_eigenvalue(p.model, 0.25)
    assert ratio > 0.5


def test_classification_is_skipped_inside_jax_transformations():
    """Under jit/grad the status is a tracer: the classification must pass the Solution
    through (Problem.simulate is differentiated by users, e.g. the README's jax.grad)."""
    import jax
    import jax.numpy as jnp

    def classify(status):
        sol = it.Solution(jnp.zeros(2), {}, jnp.zeros(1), jnp.zeros(1), status, jnp.asarray(0), None,
                          last_converged=jnp.zeros(1))
        return stability.classify_failure(None, None, sol, 1e-6).status

    assert int(jax.jit(classify)(jnp.asarray(int(it.Status.NEWTON_FAILED)))) == int(it.Status.NEWTON_FAILED)
