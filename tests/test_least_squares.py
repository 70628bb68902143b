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
