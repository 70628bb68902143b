"""fitting.least_squares: bounded Levenberg-Marquardt against scipy's optimum, with bounds,
failed evaluations and Jacobians by callback (exact or Broyden-updated)."""
import numpy as np
import pytest
from scipy.optimize import least_squares as scipy_ls

from fitting.least_squares import levenberg_marquardt


def test_levenberg_marquardt_on_a_nonlinear_problem_with_bounds_and_failures():
    """fitting.least_squares: the exponential-decay fit of scipy's least_squares reference
    problem, from a far start, reaches scipy's optimum; a bound that cuts off the optimum is
    active at the solution; non-finite trial residuals (a failed simulation) are rejected
    and the solve continues."""
    t = np.linspace(0.0, 4.0, 30)
    y = 2.5 * np.exp(-1.3 * t) + 0.3 + 0.01 * np.sin(7 * t)
    model = lambda x: x[0] * np.exp(-x[1] * t) + x[2]
    jac = lambda x: np.stack([np.exp(-x[1] * t), -x[0] * t * np.exp(-x[1] * t), np.ones_like(t)], 1)
    lo, hi = np.array([0.0, 0.0, -1.0]), np.array([10.0, 10.0, 1.0])
    ref = scipy_ls(lambda x: model(x) - y, [1.0, 0.2, 0.0], jac=jac, bounds=(lo, hi), xtol=1e-14, ftol=1e-14).x
    calls = []

    def fun(x):
        calls.append(x.copy())
        r = model(x) - y
        return (np.full_like(r, np.nan), None) if x[1] > 3.0 else (r, jac(x))  # "failed simulation" region

    res = levenberg_marquardt(fun, [1.0, 0.2, 0.0], lo, hi, max_evals=60, xtol=1e-12, ftol=1e-14)
    assert res.converged, res.message
    np.testing.assert_allclose(res.x, ref, rtol=1e-7)
    bounded = levenberg_marquardt(lambda x: (model(x) - y, jac(x)), [1.0, 0.2, 0.0], lo, [10.0, 1.0, 1.0],
                                  max_evals=60)
    assert bounded.x[1] == 1.0 and bounded.cost > res.cost
    # Jacobian by a callback (finite differences, as the diagnosis), exact or Broyden-updated:
    # the same optimum; Broyden needs fewer Jacobians, the last one exact at the solution
    counted = []

    def fd(x, r, h=1e-7):
        counted.append(1)
        return np.stack([(model(x + h * e) - y - r) / h for e in np.eye(3)], 1)

    n_fd = {}
    for broyden in (False, True):
        counted.clear()
        res_b = levenberg_marquardt(lambda x: model(x) - y, [1.0, 0.2, 0.0], lo, hi, jacobian=fd, max_evals=80,
                                    xtol=1e-12, ftol=1e-14, broyden=broyden)
        assert res_b.converged, res_b.message
        np.testing.assert_allclose(res_b.x, ref, rtol=1e-6)
        np.testing.assert_allclose(res_b.J, jac(res_b.x), rtol=1e-4, atol=1e-6)
        n_fd[broyden] = len(counted)
    assert n_fd[True] < n_fd[False]
    with pytest.raises(FloatingPointError):
        levenberg_marquardt(lambda x: np.full(3, np.inf), [1.0], [0.0], [2.0], jacobian=lambda x, r: np.ones((3, 1)))


def test_a_component_held_at_its_bound_does_not_spoil_the_step_of_the_others():
    # r = (x0 - 2, 10 (x1 - x0)) with x0 <= 1: the minimum is (1, 1) with |r|^2 = 1. A step
    # solved as if x0 could move and then clipped moves x1 towards 2 and is rejected (50
    # evaluations without converging, measured); solved without x0 it lands at once.
    def fun(x):
        return np.array([x[0] - 2.0, 10.0 * (x[1] - x[0])]), np.array([[1.0, 0.0], [-10.0, 10.0]])

    res = levenberg_marquardt(fun, [1.0, 0.0], [-5.0, -5.0], [1.0, 5.0], max_evals=50, ftol=1e-14, xtol=1e-12)
    assert res.converged and res.n_evals <= 6
    np.testing.assert_allclose(res.x, [1.0, 1.0], atol=1e-9)
    assert abs(res.cost - 1.0) < 1e-12


def test_max_step_keeps_a_barely_seen_parameter_from_jumping_to_the_bound():
    # x1 moves r by 1e-7 sin(x1): Marquardt's scaling sends it across the box in one step
    # (to the bound at -20); with steps of at most ln 10 it walks to the minimum at -pi/2.
    def fun(x):
        r = np.array([x[0] - 1.0, 1e-7 * np.sin(x[1]) + 1e-3])
        return r, np.array([[1.0, 0.0], [0.0, 1e-7 * np.cos(x[1])]])

    free = levenberg_marquardt(fun, [0.0, 0.3], [-20.0, -20.0], [20.0, 20.0], max_evals=50, ftol=1e-14, xtol=1e-12)
    assert free.x[1] == -20.0
    capped = levenberg_marquardt(fun, [0.0, 0.3], [-20.0, -20.0], [20.0, 20.0], max_evals=50, ftol=1e-14,
                                 xtol=1e-12, max_step=np.log(10.0))
    assert abs(capped.x[1] + np.pi / 2) < 1e-2 and abs(capped.x[0] - 1.0) < 1e-9
