"""Bounded Levenberg-Marquardt for the fits of ``fitting.fit`` and ``fitting.effect_fit``.

``levenberg_marquardt(fun, x0, lower, upper, jacobian=None, ...) -> LeastSquaresResult``
minimizes ``|r(x)|^2`` over the box ``lower <= x <= upper``.

* ``fun(x)`` returns the residuals ``r`` (m,), or ``(r, J)`` with their Jacobian
  (m, k) when it comes with them (a forward-mode program gives both in one pass);
  otherwise ``jacobian(x, r) -> J`` is called, only at accepted points. A non-finite
  ``r`` (a failed simulation) is a rejected trial: the damping grows and the step
  shortens.
* A step solves ``(J^T J + lam D) dx = -J^T r``, ``D = diag(J^T J)`` (Marquardt's
  scaling, floored), again without the components that push against an active bound
  (held there), and is projected onto the box; ``lam`` follows Nielsen's rule
  (``lam *= max(1/3, 1 - (2 rho - 1)^3)`` on success, doubling growth on failure) with
  ``rho`` the actual over the predicted reduction of the projected step.
* ``max_step`` bounds every component of a step (a box trust region around x; ``fit``
  passes ln 10 for its log parameters: at most a factor of ten per step). Without it a
  parameter the residuals barely see (a viscous unit relaxed within the first step: its
  column of J near zero, Marquardt's scaling floored) takes a step as large as the box
  and lands at the opposite bound, in another model.
* Stops when the relative reduction of ``|r|^2`` of an accepted step, or the one the
  linear model predicts for the next step, is below ``ftol``, the step is below ``xtol``
  (inf-norm), the projected gradient is below ``gtol``, or after ``max_evals``
  evaluations of ``fun``.
* ``broyden=True`` (with ``jacobian``): the Jacobian is computed at the start and at the
  solution (for the covariance), between them updated by Broyden's rank-one rule after
  every accepted step and recomputed after a rejected one, so that a finite-difference
  Jacobian costs k evaluations at a few points rather than at every accepted step.

Why a host loop rather than ``optimistix.LevenbergMarquardt``: the simulations behind
``fun`` are compiled once per trace and run one after another (a jitted least-squares
solve would put every trace in one program, compiling the forward model once per
trace), a failed simulation must shorten the step rather than end the solve, and the
Jacobian comes with the residuals from one forward-mode pass.
"""
from __future__ import annotations

import dataclasses
from typing import Callable

import numpy as np

__all__ = ["LeastSquaresResult", "levenberg_marquardt"]


@dataclasses.dataclass
class LeastSquaresResult:
    """x: (k,) solution; r: (m,) residuals and J: (m, k) Jacobian there; cost = |r|^2;
    cost0: at x0; n_evals: evaluations of ``fun``; n_jac: Jacobians computed (by
    ``jacobian`` or with the residuals); history: [(evaluation, cost, lam, accepted)];
    message: why it stopped; converged: a tolerance was met (not the evaluation budget)."""

    x: np.ndarray
    r: np.ndarray
    J: np.ndarray
    cost: float
    cost0: float
    n_evals: int
    n_jac: int
    history: list
    message: str
    converged: bool


def _split(out):
    if isinstance(out, tuple):
        r, J = out
        return np.asarray(r, dtype=float), np.asarray(J, dtype=float)
    return np.asarray(out, dtype=float), None


def _damped_step(A, g, damping, x, lo, hi):
    """The damped Gauss-Newton step -(A + diag(damping))^-1 g with the components that
    push against an active bound held at zero (solved again without them), so that the
    box does not clip a step computed as if they could move."""
    dx = -np.linalg.solve(A + np.diag(damping), g)
    held = ((x <= lo) & (dx < 0)) | ((x >= hi) & (dx > 0))
    if held.any() and not held.all():
        free = ~held
        dx = np.zeros_like(dx)
        dx[free] = -np.linalg.solve(A[np.ix_(free, free)] + np.diag(damping[free]), g[free])
    return dx


def levenberg_marquardt(
    fun: Callable,
    x0,
    lower,
    upper,
    jacobian: Callable | None = None,
    max_evals: int = 30,
    ftol: float = 1e-10,
    xtol: float = 1e-8,
    gtol: float = 1e-12,
    lam0: float = 1e-3,
    callback: Callable | None = None,
    broyden: bool = False,
    max_step: float = np.inf,
) -> LeastSquaresResult:
    """Minimize |fun(x)|^2 over lower <= x <= upper (see the module docstring).

    ``callback(n_evals, x, cost, accepted)`` is called after every evaluation."""
    lo, hi = np.asarray(lower, dtype=float), np.asarray(upper, dtype=float)
    x = np.clip(np.asarray(x0, dtype=float), lo, hi)
    r, J = _split(fun(x))
    n_evals, n_jac = 1, int(J is not None)
    if not np.all(np.isfinite(r)):
        raise FloatingPointError("levenberg_marquardt: the residuals are not finite at the starting point")
    if J is None:
        J, n_jac = np.asarray(jacobian(x, r), dtype=float), n_jac + 1
    cost = cost0 = float(r @ r)
    history = [(n_evals, cost, np.nan, True)]
    if callback is not None:
        callback(n_evals, x, cost, True)
    lam, nu = None, 2.0
    fresh = True  # J is the true Jacobian at x (not a Broyden update)
    message, converged = "evaluation budget exhausted", False
    while True:
        g = J.T @ r
        A = J.T @ J
        # projected gradient: components pushing against an active bound do not count
        pg = np.where(((x <= lo) & (g > 0)) | ((x >= hi) & (g < 0)), 0.0, g)
        if np.max(np.abs(pg)) <= gtol * max(cost, 1e-300):
            message, converged = "projected gradient below gtol", True
            break
        if n_evals >= max_evals:
            break
        d = np.maximum(np.diag(A), 1e-12 * max(np.max(np.diag(A)), 1e-300))
        if lam is None:
            lam = lam0
        dx = _damped_step(A, g, lam * d, x, lo, hi)
        dx = np.clip(dx, -max_step, max_step)
        x_new = np.clip(x + dx, lo, hi)
        step = x_new - x
        if np.max(np.abs(step)) <= xtol * (1.0 + np.max(np.abs(x))):
            message, converged = "step below xtol", True
            break
        predicted = -(2.0 * g @ step + step @ A @ step)
        if 0 <= predicted <= ftol * cost:
            message, converged = "predicted reduction below ftol", True
            break
        r_new, J_new = _split(fun(x_new))
        n_evals += 1
        cost_new = float(r_new @ r_new) if np.all(np.isfinite(r_new)) else np.inf
        rho = (cost - cost_new) / predicted if predicted > 0 else -1.0
        accepted = bool(np.isfinite(cost_new) and cost_new < cost and rho > 0)
        history.append((n_evals, cost_new, lam, accepted))
        if callback is not None:
            callback(n_evals, x_new, cost_new, accepted)
        if broyden and J_new is None and accepted:
            J = J + np.outer(r_new - r - J @ step, step) / float(step @ step)  # rank-one secant update
            fresh = False
        if broyden and not accepted and not fresh:  # a failed step with an updated Jacobian: recompute it
            J, n_jac, fresh = np.asarray(jacobian(x, r), dtype=float), n_jac + 1, True
        if accepted:
            reduction = (cost - cost_new) / max(cost, 1e-300)
            x, r, cost = x_new, r_new, cost_new
            if J_new is None and not broyden:
                J_new, n_jac = np.asarray(jacobian(x, r), dtype=float), n_jac + 1
            elif J_new is not None:
                n_jac += 1
            J = J if J_new is None else J_new
            lam *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
            nu = 2.0
            if reduction <= ftol:
                message, converged = "relative reduction below ftol", True
                break
        else:
            lam *= nu
            nu *= 2.0
    if broyden and not fresh:  # the covariance needs the true Jacobian
        J, n_jac = np.asarray(jacobian(x, r), dtype=float), n_jac + 1
    return LeastSquaresResult(x, r, J, cost, cost0, n_evals, n_jac, history, message, converged)
