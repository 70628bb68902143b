"""The robust nonlinear solve of dejax/integrate.py (issue 9): mixed form, line search,
step cut-back and the quasi-static scheme, on one-element uniaxial tests.

References: the closed-form nominal stress of incompressible Gent uniaxial tension, and
central finite differences for the derivatives through cut-backs. (Split from
test_integrate.py so that the two test workers share the compile-bound load.)
"""
from __future__ import annotations

import numpy as np
import pytest

import dejax  # noqa: F401  (enables float64)
import jax
from dejax import integrate as it
from dejax import loads
from dejax import material as mat_
from dejax import scenarios

MU_U, JM_U = 15e3, 60.0  # the uniaxial test material of the robustness matrix


def _uniaxial(K_ratio, lam_max=3.0, volumetric="mixed", units=None, t_end=40.0):
    mat = mat_.Material(MU_U, K_ratio * MU_U, JM_U, 4e-11, 1000.0, **(units or {}))
    return scenarios.uniaxial(loads.PiecewiseLinear([0.0, t_end], [1.0, lam_max]), mat, volumetric=volumetric)


def _gent_uniaxial_stress(lam):
    """Nominal stress of incompressible Gent uniaxial tension (closed form)."""
    return MU_U * (lam - lam**-2) / (1.0 - (lam**2 + 2.0 / lam - 3.0) / JM_U)


@pytest.mark.parametrize("K_ratio, tol", [(np.inf, 1e-5), (1e4, 1e-3)])
def test_uniaxial_mixed_form_converges_at_large_increments(K_ratio, tol):
    """One element, stretch 1 -> 3 in increments of 0.1 (quasi-static, the scenario's
    default): the mixed form converges in at most 4 full-Newton iterations per step with
    no cut-back, and the stress matches the incompressible Gent closed form (exactly for
    K = inf, within the compressibility effect ~ mu/K for K = 1e4 mu)."""
    p = _uniaxial(K_ratio)
    sol = p.simulate(40.0, 2.0, newton=it.NewtonOptions(reuse=False)).check()
    its = np.asarray(sol.iterations)
    assert sol.n_cutbacks == 0 and its.max() <= 4 and np.median(its) <= 4
    lam = np.asarray(sol.outputs["stretch"])[1:]
    np.testing.assert_allclose(lam[-1], 3.0, rtol=1e-12)
    np.testing.assert_allclose(np.asarray(sol.outputs["stress"])[1:], _gent_uniaxial_stress(lam), rtol=tol)


def test_line_search_globalizes_the_penalty_form():
    """The issue's failing case: the paper's pointwise penalty, K = 1e4 mu, generalized-
    alpha with rho_inf = 0, dt = 1 s (stretch increments 0.05), no cut-back. Its velocity
    predictor overshoots the boundary-driven motion by half an increment (gamma = 1.5),
    and plain Newton steps from there diverge along the ANCF's soft gradient modes; the
    line search on the residual norm converges (and the stress is Gent's)."""
    p = _uniaxial(1e4, lam_max=1.5, volumetric="displacement", t_end=10.0)
    times = it.time_grid(10.0, 1.0)
    run = lambda ls: it.simulate(p.model, p.loading, times, p.output_fn, it.GeneralizedAlpha(0.0),  # noqa: E731
                                 it.NewtonOptions(reuse=False, line_search=ls, max_iter=40), control=None)
    failed = run(False)
    assert not failed.ok and failed.status == it.Status.NEWTON_FAILED
    sol = run(True).check()
    lam = np.asarray(sol.outputs["stretch"])[1:]
    np.testing.assert_allclose(np.asarray(sol.outputs["stress"])[1:], _gent_uniaxial_stress(lam), rtol=5e-3)


def test_cut_back_recovers_and_derivatives_hold_through_it():
    """Newton limited to 3 iterations cannot take the first stretch increment of 0.5: the
    step is cut back and the run completes on the user's grid, at the same equilibrium as
    an uncut run (the same Newton on a grid of increments 0.05; both grids padded to one
    length, so one compiled program serves both and the finite differences); jax.jvp and
    jax.grad of the final stress with respect to mu_inf through the cut-back run agree with
    central finite differences (same schedule at +-h)."""
    times = np.linspace(0.0, 30.0, 4)
    fine = np.linspace(0.0, 30.0, 31)
    newton = it.NewtonOptions(reuse=False, max_iter=3)

    def run(mu, times=times):
        mat = mat_.Material(mu, 1e4 * MU_U, JM_U, 4e-11, 1000.0)
        p = scenarios.uniaxial(loads.PiecewiseLinear([0.0, 30.0], [1.0, 2.5]), mat)
        return it.simulate(p.model, p.loading, times, p.output_fn, it.QuasiStatic(), newton, pad_to=len(fine) - 1)

    sol = run(MU_U).check()
    assert sol.n_cutbacks >= 1 and float(sol.dt_smallest) < 10.0
    ref = run(MU_U, fine).check()
    assert ref.n_cutbacks == 0
    np.testing.assert_allclose(np.asarray(sol.outputs["stress"]), np.asarray(ref.outputs["stress"])[::10], rtol=1e-6,
                               atol=1e-6 * MU_U)
    f = lambda mu: run(mu).outputs["stress"][-1]  # noqa: E731
    # forward mode by linearization, reverse mode by its transpose (what jax.grad does):
    # one forward program serves both
    y, f_lin = jax.linearize(f, MU_U)
    assert float(y) == pytest.approx(float(sol.outputs["stress"][-1]), rel=1e-12)  # the same primal run
    jvp = f_lin(1.0)
    (grad,) = jax.linear_transpose(f_lin, MU_U)(1.0)
    h = 1e-3 * MU_U
    plus, minus = run(MU_U + h), run(MU_U - h)
    assert np.array_equal(np.asarray(plus.cutbacks), np.asarray(sol.cutbacks))
    assert np.array_equal(np.asarray(minus.cutbacks), np.asarray(sol.cutbacks))
    fd = (float(plus.outputs["stress"][-1]) - float(minus.outputs["stress"][-1])) / (2 * h)
    assert float(jvp) == pytest.approx(fd, rel=1e-5)
    assert float(grad) == pytest.approx(float(jvp), rel=1e-10)


@pytest.mark.slow
def test_cut_back_derivatives_viscous():
    """The same with a viscous unit, where the result depends on the sub-step schedule:
    jvp and grad of the final stress with respect to mu_1 against central differences
    (about 4 minutes of compilation: run with --runslow)."""
    times = np.linspace(0.0, 1.0, 4)
    newton = it.NewtonOptions(reuse=False, max_iter=3)

    def run(mu1):
        units = dict(mu=[mu1], K=[0.0], Jm=[JM_U], eta=[2.5e3])
        mat = mat_.Material(MU_U, 1e4 * MU_U, JM_U, 4e-11, 1000.0, **units)
        p = scenarios.uniaxial(loads.PiecewiseLinear([0.0, 1.0], [1.0, 2.5]), mat)
        return it.simulate(p.model, p.loading, times, p.output_fn, it.QuasiStatic(), newton)

    sol = run(25e3).check()
    assert sol.n_cutbacks >= 1
    f = lambda mu1: run(mu1).outputs["stress"][-1]  # noqa: E731
    _, jvp = jax.jvp(f, (25e3,), (1.0,))
    grad = jax.grad(f)(25e3)
    h = 25.0
    plus, minus = run(25e3 + h), run(25e3 - h)
    assert plus.n_cutbacks == minus.n_cutbacks == sol.n_cutbacks
    fd = (float(plus.outputs["stress"][-1]) - float(minus.outputs["stress"][-1])) / (2 * h)
    assert float(jvp) == pytest.approx(fd, rel=1e-5)
    assert float(grad) == pytest.approx(float(jvp), rel=1e-10)
