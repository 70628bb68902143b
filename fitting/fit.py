"""Parameter identification by autodiff through dejax simulations.

API
---
``fit(forward, params0, free, bounds, targets, holdout=(), ...) -> FitResult``

* ``forward(params, data) -> prediction``: ``params`` is a dict name -> jax
  scalar (every parameter of ``params0``, the free ones traced), ``data`` a
  pytree of arrays describing one trace (its loading, time grid, ...: the
  trace's ``data``); returns an array shaped like the trace's ``y``. It must be jax-traceable
  (it is jitted, differentiated by ``jax.grad`` and ``jax.jacfwd``). Keep it a
  module-level function or a hashable object: compiled code is cached per
  ``(forward, free, fixed names)`` and reused across targets whose ``data``
  have equal shapes (give every trace the same number of steps).
* ``targets`` / ``holdout``: sequences of ``fitting.traces.Trace`` with a ``response``
  channel (``y``) and ``data`` (``fitting.experiment`` builds them from experiment files;
  ``Target(name, y, data, t=None, x=None, weight=1, scale=None)`` from samples).
* free parameters are mapped to an unbounded variable ``theta`` by
  ``p = exp(log lo + (log hi - log lo) sigmoid(theta))`` (box bounds in log
  space); missing bounds default to ``[p0 / 100, p0 * 100]``.
* loss = sum over targets of ``weight * mean(((pred - y) / scale)^2)``,
  ``scale`` = the trace's ``norm`` (its ``scale``, else the amplitude of y).
* optimizer (``method``): "lm" (default), Levenberg-Marquardt in log p within the
  bounds (``fitting.least_squares``, at most ``max_evals`` evaluations), each evaluation
  one forward-mode program per target giving its residuals and their Jacobian; or
  "adam-lbfgs", optax Adam (``adam_steps``) then L-BFGS (``optax.scale_by_lbfgs``
  directions with a backtracking Armijo line search, ``lbfgs_steps``) in theta, every
  loss evaluation one simulation per target plus its gradient (forward mode up to
  ``FORWARD_MODE_MAX_FREE`` free parameters, reverse mode above).
* at the optimum: residual Jacobian by ``jax.jacfwd`` w.r.t. log p (forward
  mode, k tangents; "lm" has it from its last evaluation), Gauss-Newton covariance ``s^2 (J^T J)^-1`` with
  ``s^2 = RSS / (m - k)``, standard errors ``SE(p) = p SE(log p)`` and the
  correlation matrix; RMS errors on training and held-out targets.

``FitResult.save(out_dir)`` writes ``fit.json`` and PNG plots (trace overlays
with residuals; y against ``x`` loops where a target has ``x``, e.g. stress
against stretch or displacement against voltage).

``apply_params(model, params)`` replaces material leaves (mu_inf, K_inf,
Jm_inf, eps, rho, mu_i, K_i, Jm_i, eta_i) and the damping c_d of a
``dejax.model.Model`` by name, keeping its structure (compiled code reuse).
"""
from __future__ import annotations

import dataclasses
import json
import math
import re
import time as _time
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax

from dejax import parameters

from .schema import OPTIMIZERS
from .toml_writer import write_atomic
from .traces import Trace, from_samples

__all__ = ["Target", "FitResult", "fit", "apply_params", "LogBox"]


# ----------------------------------------------------------------------------- parameters

def apply_params(model, params: Mapping[str, Any]):
    """``model`` with material parameters and damping ``c_d`` replaced (same structure)."""
    model = eqx.tree_at(lambda m: m.material, model, parameters.replace(model.material, params))
    if "c_d" in params:
        model = eqx.tree_at(lambda m: m.damping, model, jnp.asarray(params["c_d"], dtype=float))
    return model


@dataclasses.dataclass(frozen=True)
class LogBox:
    """p = exp(a + (b - a) sigmoid(theta)), a = log lo, b = log hi."""

    lo: np.ndarray
    hi: np.ndarray

    def to_p(self, theta):
        a, b = jnp.log(self.lo), jnp.log(self.hi)
        return jnp.exp(a + (b - a) * jax.nn.sigmoid(theta))

    def to_theta(self, p):
        a, b = np.log(self.lo), np.log(self.hi)
        s = (np.log(np.asarray(p, dtype=float)) - a) / (b - a)
        s = np.clip(s, 1e-6, 1 - 1e-6)
        return np.log(s / (1 - s))


# ----------------------------------------------------------------------------- targets

Target = from_samples
"""A fit target known by its samples alone: ``Target(name, y, data, t=None, x=None, weight=1,
scale=None, ylabel="y", xlabel="x", unit="")`` -> ``fitting.traces.Trace``."""


# ----------------------------------------------------------------------------- compiled pieces

_CACHE: dict = {}


def explain_nonfinite(forward, params: Mapping[str, float], target: Trace) -> str:
    """Why ``forward`` predicts ``target`` as non-finite at ``params``: when the forward can
    simulate (``forward.simulate(params, data)`` -> dejax Solution), the time (s) and cause
    of the failed simulation; otherwise only the trace."""
    sim = getattr(forward, "simulate", None)
    if sim is None:
        return f"trace {target.name!r}: the prediction is not finite"
    from dejax.integrate import SimulationError, Status

    sol = sim({k: jnp.asarray(v, dtype=float) for k, v in params.items()}, target.data)
    if int(sol.status) != 0:
        status = Status(int(sol.status))
        err = SimulationError(status, sol.fail_time, int(sol.fail_step) + 1)
        hint = ("; fits take their time steps without cut-back: try more steps (--steps, [solver] dt) or other "
                "initial parameters" if status == Status.NEWTON_FAILED else "")
        return f"trace {target.name!r}: {err}{hint}"
    return f"trace {target.name!r}: the simulation completed but its prediction is not finite (check the data)"


FORWARD_MODE_MAX_FREE = 4  # up to this many free parameters the fit differentiates in forward mode
METHODS = OPTIMIZERS
"""Optimizers of ``fit``: Levenberg-Marquardt (``fitting.least_squares``) or optax Adam then L-BFGS."""
LM_MAX_STEP = math.log(10.0)  # Levenberg-Marquardt: at most a factor of ten per parameter and step


def _common_shapes(targets) -> dict:
    """name -> (data, y, mask) with the same array shapes for every trace, so that one
    compilation of the loss, its gradient and the Jacobian serves them all.

    Every array of ``data`` (time grids, interpolation tables, observation times) and ``y``
    is padded along its first axis to the longest by repeating its last entry: a time grid
    then ends in zero-length steps, which ``integrate.simulate`` skips; a table continues
    constant; ``mask`` (1 real, 0 padded) removes the padded observations from the loss.
    Traces whose data differ in structure are left as they are."""
    out = {t.name: (t.data, jnp.asarray(t.y), jnp.ones(t.y.size)) for t in targets}
    if len(targets) < 2:
        return out
    structs = {jax.tree_util.tree_structure(t.data) for t in targets}
    if len(structs) != 1:
        return out
    leaves = [jax.tree_util.tree_leaves(t.data) for t in targets]
    if any(np.ndim(a) != np.ndim(b) or np.shape(a)[1:] != np.shape(b)[1:] for ls in leaves for a, b in zip(ls, leaves[0])):
        return out
    lengths = [max(np.shape(ls[i])[0] if np.ndim(ls[i]) else 0 for ls in leaves) for i in range(len(leaves[0]))]
    n_obs = max(t.y.size for t in targets)

    def pad(a, n):
        a = np.asarray(a)
        if a.ndim == 0 or a.shape[0] == n:
            return jnp.asarray(a)
        return jnp.asarray(np.concatenate([a, np.repeat(a[-1:], n - a.shape[0], axis=0)]))

    treedef = structs.pop()
    for t, ls in zip(targets, leaves):
        data = jax.tree_util.tree_unflatten(treedef, [pad(a, n) for a, n in zip(ls, lengths)])
        mask = jnp.asarray(np.arange(n_obs) < t.y.size, dtype=float)
        out[t.name] = (data, pad(t.y, n_obs), mask)
    return out


def _fns(forward, free: tuple, fixed: tuple):
    """Jitted (value_and_grad in theta, residual in log p, jacfwd in log p, (residual,
    jacfwd) in log p) for one forward."""
    key = (forward, free, fixed)
    if key in _CACHE:
        return _CACHE[key]

    def params_of(p_free, fixed_vals):
        d = {k: fixed_vals[i] for i, k in enumerate(fixed)}
        d.update({k: p_free[i] for i, k in enumerate(free)})
        return d

    def residual_logp(logp, fixed_vals, data, y, c):
        pred = forward(params_of(jnp.exp(logp), fixed_vals), data)
        return (pred - y) * c

    def loss_theta(theta, lo, hi, fixed_vals, data, y, c):
        logp = jnp.log(lo) + (jnp.log(hi) - jnp.log(lo)) * jax.nn.sigmoid(theta)
        r = residual_logp(logp, fixed_vals, data, y, c)
        return jnp.sum(r * r)

    def residual_and_jacobian(logp, fixed_vals, data, y, c):
        J, r = jax.jacfwd(lambda lp: (residual_logp(lp, fixed_vals, data, y, c),) * 2, has_aux=True)(logp)
        return r, J

    fns = (
        jax.jit(jax.value_and_grad(loss_theta)),
        jax.jit(residual_logp),
        jax.jit(jax.jacfwd(residual_logp)),
        jax.jit(residual_and_jacobian),
    )
    _CACHE[key] = fns
    return fns


def _exported(resid_jac, forward, free, params0, args):
    """``resid_jac`` loaded from / saved to the exported-program cache (``dejax.compile_cache.
    exported_call``) when the compilation cache is on: a second identical fit skips tracing."""
    import dejax
    import fitting
    from dejax import compile_cache

    if not args or not compile_cache.enabled() or not isinstance(forward, eqx.Module):
        return resid_jac  # (a plain function's identity is no key across processes)
    fixed = tuple(k for k in params0 if k not in free)
    key = (f"fit.residual_and_jacobian|{compile_cache.content_digest(forward)}|{free}|{fixed}|"
           f"{compile_cache.source_digest(dejax, fitting)}")
    return compile_cache.exported_call(resid_jac, args, key)


# ----------------------------------------------------------------------------- result

PARAMETER_UNIT = "units[name]"
KEY_UNITS = {
    "params": PARAMETER_UNIT, "initial": PARAMETER_UNIT, "bounds": PARAMETER_UNIT, "stderr": PARAMETER_UNIT,
    "rel_stderr": "1", "correlation": "1", "cov_log": "1 (of log p)", "loss": "1", "loss0": "1",
    "history": "[iteration, stage, loss (1)]", "rms": "rms: rms[trace].unit; rel_rms: 1; n: samples",
    "n_evals": "1", "seconds": "s",
}
"""fit.json's ``key_units``: the unit of every numeric entry of ``FitResult.to_dict()`` ("1" =
dimensionless; ``units[name]``: each parameter's unit in ``units``)."""


@dataclasses.dataclass
class FitResult:
    """Outcome of ``fit``.

    params: all parameters (free at their optimum); free: names; p0: initial free
    values; stderr / rel_stderr: standard errors (absolute, relative) of the free
    parameters; corr: (k, k) correlation matrix; cov_log: covariance of log p;
    loss, loss0: final and initial loss; history: [(iteration, stage, loss)];
    rms: name -> dict(role, rms, rel_rms (RMS / scale), n); predictions: name -> (n,)
    array; n_evals: loss+gradient evaluations; seconds: wall time.
    """

    params: dict
    free: list
    p0: dict
    bounds: dict
    stderr: dict
    rel_stderr: dict
    corr: np.ndarray
    cov_log: np.ndarray
    loss: float
    loss0: float
    history: list
    rms: dict
    predictions: dict
    targets: list
    holdout: list
    n_evals: int
    seconds: float
    at_bound: list

    def table(self) -> str:
        lines = [f"{'parameter':>10} {'initial':>12} {'fitted':>12} {'std.err':>11} {'rel.err':>8}  unit"]
        for k in self.free:
            lines.append(f"{k:>10} {self.p0[k]:12.5g} {self.params[k]:12.5g} {self.stderr[k]:11.3g} "
                         f"{100 * self.rel_stderr[k]:7.2f}%  {parameters.unit(k)}"
                         + ("  (at bound)" if k in self.at_bound else ""))
        lines.append(f"loss {self.loss0:.4g} -> {self.loss:.4g} in {self.n_evals} evaluations, {self.seconds:.1f} s")
        lines.append(f"{'trace':>24} {'role':>8} {'RMS':>12} {'RMS/amp':>8}  unit")
        for name, r in self.rms.items():
            lines.append(f"{name:>24} {r['role']:>8} {r['rms']:12.4g} {100 * r['rel_rms']:7.3f}%  "
                         f"{r.get('unit') or '?'}")
        if len(self.free) > 1:
            lines.append("correlation matrix:")
            lines.append(" " * 10 + " ".join(f"{k:>8}" for k in self.free))
            for i, k in enumerate(self.free):
                lines.append(f"{k:>10}" + " ".join(f"{c:8.3f}" for c in self.corr[i]))
        return "\n".join(lines)

    def to_dict(self) -> dict:
        return dict(
            params=self.params, free=self.free, initial=self.p0, bounds={k: list(v) for k, v in self.bounds.items()},
            stderr=self.stderr, rel_stderr=self.rel_stderr, correlation=np.asarray(self.corr).tolist(),
            cov_log=np.asarray(self.cov_log).tolist(), loss=self.loss, loss0=self.loss0,
            history=[list(h) for h in self.history], rms=self.rms, n_evals=self.n_evals, seconds=self.seconds,
            at_bound=self.at_bound, units={k: parameters.unit(k) for k in self.params}, key_units=KEY_UNITS,
        )

    def save(self, out_dir, plots: bool = True) -> list[Path]:
        """Write fit.json (and PNG plots); return the written paths."""
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        paths = [write_atomic(out / "fit.json", json.dumps(_jsonable(self.to_dict()), indent=2))]
        if plots:
            paths += self.plot(out)
        return paths

    def plot(self, out_dir) -> list[Path]:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        out = Path(out_dir)
        paths = []
        for tg in list(self.targets) + list(self.holdout):
            role = "fit" if any(tg is t for t in self.targets) else "holdout"
            pred = self.predictions[tg.name]
            tt = np.arange(tg.y.size) if tg.time is None else np.asarray(tg.time)
            fig, ax = plt.subplots(2, 1, figsize=(7, 5), sharex=True, gridspec_kw=dict(height_ratios=[3, 1]))
            ax[0].plot(tt, tg.y, ".", ms=3, label="data")
            ax[0].plot(tt, pred, "-", label="model")
            ax[0].set_ylabel(tg.label(tg.response))
            ax[0].set_title(f"{tg.name} ({role}) RMS/amp = {100 * self.rms[tg.name]['rel_rms']:.2f} %")
            ax[0].legend()
            ax[1].plot(tt, pred - tg.y, "-")
            ax[1].set_ylabel("residual")
            ax[1].set_xlabel("time (s)" if tg.time is not None else "sample")
            fig.tight_layout()
            p = out / f"trace_{_safe(tg.name)}.png"
            fig.savefig(p, dpi=90)
            plt.close(fig)
            paths.append(p)
            if tg.x is not None:
                fig, ax = plt.subplots(figsize=(5, 4))
                ax.plot(tg.x, tg.y, ".", ms=3, label="data")
                ax.plot(tg.x, pred, "-", label="model")
                ax.set_xlabel(tg.label(tg.against))
                ax.set_ylabel(tg.label(tg.response))
                ax.set_title(f"{tg.name} ({role})")
                ax.legend()
                fig.tight_layout()
                p = out / f"loop_{_safe(tg.name)}.png"
                fig.savefig(p, dpi=90)
                plt.close(fig)
                paths.append(p)
        return paths


def _safe(s: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", s)


def _jsonable(o):
    if isinstance(o, dict):
        return {str(k): _jsonable(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_jsonable(v) for v in o]
    if isinstance(o, (np.ndarray, jax.Array)):
        return _jsonable(np.asarray(o).tolist())
    if isinstance(o, (np.floating, float)):
        v = float(o)
        return v if math.isfinite(v) else str(v)
    if isinstance(o, np.integer):
        return int(o)
    return o


# ----------------------------------------------------------------------------- fit


def fit(
    forward: Callable,
    params0: Mapping[str, float],
    free: Sequence[str],
    bounds: Mapping[str, Sequence[float]] | None,
    targets: Sequence[Trace],
    holdout: Sequence[Trace] = (),
    adam_steps: int = 30,
    adam_lr: float = 0.1,
    lbfgs_steps: int = 30,
    tol: float = 1e-10,
    verbose: bool = True,
    print_fn: Callable = print,
    covariance: bool = True,
    method: str = "lm",
    max_evals: int = 30,
) -> FitResult:
    """Fit ``free`` parameters of ``params0`` to ``targets`` (see the module docstring).

    ``method``: "lm" (Levenberg-Marquardt in log p on the forward-mode Jacobian, at most
    ``max_evals`` evaluations) or "adam-lbfgs" (``adam_steps`` + ``lbfgs_steps``)."""
    if method not in METHODS:
        raise ValueError(f"fit: method must be one of {', '.join(METHODS)}, got {method!r}")
    tic = _time.perf_counter()
    free = tuple(free)
    if not free:
        raise ValueError("fit: no free parameters")
    for k in free:
        if k not in params0:
            raise KeyError(f"fit: free parameter {k!r} is not in params0 ({', '.join(params0)})")
    fixed = tuple(k for k in params0 if k not in free)
    bounds = dict(bounds or {})
    p0 = np.array([float(params0[k]) for k in free])
    if np.any(p0 <= 0):
        raise ValueError("fit: free parameters must be > 0 (log parametrization)")
    lo = np.array([float(bounds.get(k, (v / 100, v * 100))[0]) for k, v in zip(free, p0)])
    hi = np.array([float(bounds.get(k, (v / 100, v * 100))[1]) for k, v in zip(free, p0)])
    if np.any(lo <= 0) or np.any(hi <= lo) or np.any(p0 < lo) or np.any(p0 > hi):
        raise ValueError(f"fit: need 0 < lower <= p0 <= upper for every free parameter; got {list(zip(free, lo, p0, hi))}")
    box = LogBox(lo, hi)
    fixed_vals = jnp.asarray([float(params0[k]) for k in fixed]) if fixed else jnp.zeros(0)
    vg, resid, jac, resid_jac = _fns(forward, free, fixed)
    # few free parameters: forward mode gives the residuals and their Jacobian in one program
    # that serves the loss, its gradient, the covariance and the predictions (one compilation)
    forward_mode = len(free) <= FORWARD_MODE_MAX_FREE
    log_lo, log_span = np.log(lo), np.log(hi) - np.log(lo)
    targets = list(targets)
    holdout = list(holdout)
    coef = [math.sqrt(t.weight / t.y.size) / t.norm for t in targets]
    padded = _common_shapes(targets + holdout)  # name -> (data, y, mask): one compilation for all
    lo_j, hi_j = jnp.asarray(lo), jnp.asarray(hi)

    def say(msg):
        if verbose:
            print_fn(msg)

    n_evals = [0]
    failing = []  # names of the traces whose loss was not finite at the last evaluation

    def value_and_grad(theta):
        val, g = 0.0, np.zeros_like(theta)
        failing.clear()
        sig = 1.0 / (1.0 + np.exp(-np.asarray(theta)))
        logp = jnp.asarray(log_lo + log_span * sig)
        for t, c in zip(targets, coef):
            data, y, mask = padded[t.name]
            if forward_mode:
                r, J = (np.asarray(a) for a in resid_jac(logp, fixed_vals, data, y, c * mask))
                v, gi = float(r @ r), 2.0 * (J.T @ r) * log_span * sig * (1.0 - sig)
            else:
                v, gi = vg(jnp.asarray(theta), lo_j, hi_j, fixed_vals, data, y, c * mask)
            val += float(v)
            g += np.asarray(gi)
            if not np.isfinite(float(v)):
                failing.append(t.name)
        n_evals[0] += 1
        if not np.isfinite(val):
            return np.inf, np.zeros_like(theta)
        return val, g

    if method == "lm":
        return _fit_lm(forward, resid_jac, free, params0, p0, lo, hi, fixed_vals, targets, holdout, coef, padded,
                       max_evals, tol, covariance, say, tic)
    theta = box.to_theta(p0)
    say(f"[fit] compiling the forward model and its gradient, first evaluation on {len(targets)} trace(s) ...")
    f, g = value_and_grad(theta)
    loss0 = f
    if not np.isfinite(f):
        p_init = {k: float(params0[k]) for k in params0}
        why = "; ".join(explain_nonfinite(forward, p_init, t) for t in targets if t.name in failing)
        raise FloatingPointError(f"fit: the loss is not finite at the initial parameters: {why or 'no trace failed'}")
    say(f"[fit] first evaluation done in {_time.perf_counter() - tic:.1f} s")
    history = [(0, "init", f)]
    say(f"[fit] {len(free)} free parameter(s), {len(targets)} target(s); initial loss {f:.6g}")
    best = (f, theta.copy())
    # --- Adam
    opt = optax.adam(adam_lr)
    st = opt.init(jnp.asarray(theta))
    adam_update = jax.jit(opt.update)  # one compiled program, not one per operation
    for i in range(adam_steps):
        u, st = adam_update(jnp.asarray(g), st)
        for j in range(6):  # a failed simulation (inf loss): shorten the step
            cand = theta + 0.5 ** j * np.asarray(u)
            fc, gc = value_and_grad(cand)
            if np.isfinite(fc):
                break
        if not np.isfinite(fc):
            say(f"[fit] adam {i + 1:4d}: simulation failed along the step (trace {', '.join(failing)}), stopping Adam")
            break
        theta, f, g = cand, fc, gc
        if f < best[0]:
            best = (f, theta.copy())
        history.append((i + 1, "adam", f))
        say(f"[fit] adam {i + 1:4d}/{adam_steps} loss {f:.6g}  " + _pstr(free, box.to_p(jnp.asarray(theta)))
            + f"  ({_time.perf_counter() - tic:.0f} s)")
    theta, f = best[1], best[0]
    f, g = value_and_grad(theta)
    # --- L-BFGS (optax direction + backtracking Armijo line search)
    lb = optax.scale_by_lbfgs()
    ls = lb.init(jnp.asarray(theta))
    lbfgs_update = jax.jit(lb.update)
    for i in range(lbfgs_steps):
        d, ls = lbfgs_update(jnp.asarray(g), ls, jnp.asarray(theta))
        d = -np.asarray(d)
        slope = float(np.dot(g, d))
        if slope >= 0:  # not a descent direction: restart with steepest descent
            ls = lb.init(jnp.asarray(theta))
            d = -g
            slope = -float(np.dot(g, g))
        alpha, accepted = 1.0, False
        for _ in range(10):
            cand = theta + alpha * d
            fc, gc = value_and_grad(cand)
            if np.isfinite(fc) and fc <= f + 1e-4 * alpha * slope:
                accepted = True
                break
            alpha *= 0.5
        if not accepted:
            say(f"[fit] lbfgs {i + 1:4d}: line search failed, stopping")
            break
        df = f - fc
        theta, f, g = cand, fc, gc
        history.append((i + 1, "lbfgs", f))
        say(f"[fit] lbfgs {i + 1:4d}/{lbfgs_steps} loss {f:.6g} step {alpha:g}  "
            + _pstr(free, box.to_p(jnp.asarray(theta))) + f"  ({_time.perf_counter() - tic:.0f} s)")
        if df <= tol * max(1.0, abs(f)) or np.max(np.abs(g)) < 1e-12:
            say("[fit] converged")
            break
    p_opt = np.asarray(box.to_p(jnp.asarray(theta)))
    logp = jnp.log(jnp.asarray(p_opt))
    r = J = None
    if covariance:
        say("[fit] standard errors: compiling the Jacobian of the residuals ...")
        Js, rs = [], []
        for t, c in zip(targets, coef):
            data, y, mask = padded[t.name]
            if forward_mode:
                r_, J_ = resid_jac(logp, fixed_vals, data, y, c * mask)
            else:
                r_, J_ = resid(logp, fixed_vals, data, y, c * mask), jac(logp, fixed_vals, data, y, c * mask)
            Js.append(np.asarray(J_)[: t.y.size])
            rs.append(np.asarray(r_)[: t.y.size])
        J, r = np.concatenate(Js), np.concatenate(rs)

    def predict(t, logp):
        data, y, mask = padded[t.name]
        # the residual function with y = 0, c = 1 is the prediction (no extra compilation)
        pr = (resid_jac(logp, fixed_vals, data, jnp.zeros_like(y), mask)[0] if forward_mode
              else resid(logp, fixed_vals, data, jnp.zeros_like(y), mask))
        return np.asarray(pr)[: t.y.size]

    return _result(free, params0, p0, lo, hi, p_opt, r, J, float(f), float(loss0), history, targets, holdout,
                   predict, {}, n_evals[0], tic, say)


def _result(free, params0, p0, lo, hi, p_opt, r, J, loss, loss0, history, targets, holdout, predict, known,
            n_evals, tic, say) -> FitResult:
    """FitResult at the optimum ``p_opt``: Gauss-Newton covariance of log p from the scaled
    residuals ``r`` (m,) and their Jacobian ``J`` (m, k) in log p (None: no covariance),
    predictions ``known`` (name -> (n,)) or ``predict(target, log p)``, RMS per trace."""
    k = len(free)
    if J is not None:
        s2 = float(r @ r) / max(r.size - k, 1)
        cov = s2 * np.linalg.pinv(J.T @ J)
    else:
        cov = np.full((k, k), np.nan)
    se_log = np.sqrt(np.clip(np.diag(cov), 0, None))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(se_log, se_log)
    params = {k_: float(params0[k_]) for k_ in params0}
    params.update({k_: float(v) for k_, v in zip(free, p_opt)})
    stderr = {k_: float(v * s) for k_, v, s in zip(free, p_opt, se_log)}
    rel = {k_: float(s) for k_, s in zip(free, se_log)}
    at_bound = [k_ for k_, v, a, b in zip(free, p_opt, lo, hi) if v < a * 1.001 or v > b / 1.001]
    say(f"[fit] predicting {len(targets) + len(holdout)} trace(s) ({len(holdout)} held out) ...")
    logp = jnp.log(jnp.asarray(p_opt))
    preds, rms = {}, {}
    for role, group in (("fit", targets), ("holdout", holdout)):
        for t in group:
            pr = known[t.name] if t.name in known else predict(t, logp)
            preds[t.name] = pr
            e = float(np.sqrt(np.mean((pr - t.y) ** 2)))
            rms[t.name] = dict(role=role, rms=e, rel_rms=e / t.norm, n=int(t.y.size), unit=t.unit)
    res = FitResult(params, list(free), {k_: float(v) for k_, v in zip(free, p0)},
                    {k_: (float(a), float(b)) for k_, a, b in zip(free, lo, hi)}, stderr, rel, corr, cov,
                    float(loss), float(loss0), history, rms, preds, list(targets), list(holdout), n_evals,
                    _time.perf_counter() - tic, at_bound)
    say(res.table())
    return res


def _fit_lm(forward, resid_jac, free, params0, p0, lo, hi, fixed_vals, targets, holdout, coef, padded, max_evals,
            tol, covariance, say, tic) -> FitResult:
    """``fit`` by Levenberg-Marquardt in log p: every evaluation runs each trace's one
    forward-mode program (residuals and their Jacobian together)."""
    from .least_squares import levenberg_marquardt

    failing = []
    last = {}  # the evaluation at the last point: name -> residuals (unpadded)
    resid_jac = _exported(resid_jac, forward, free, params0, (jnp.log(jnp.asarray(p0)), fixed_vals)
                          + padded[targets[0].name] if targets else ())

    def fun(logp):
        rs, Js = [], []
        failing.clear()
        for t, c in zip(targets, coef):
            data, y, mask = padded[t.name]
            r, J = resid_jac(jnp.asarray(logp), fixed_vals, data, y, c * mask)
            r, J = np.asarray(r)[: t.y.size], np.asarray(J)[: t.y.size]
            if not np.all(np.isfinite(r)):
                failing.append(t.name)
            rs.append(r)
            Js.append(J)
        last.clear()
        last.update({t.name: r for t, r in zip(targets, rs)})
        return np.concatenate(rs), np.concatenate(Js)

    def progress(n, logp, cost, accepted):
        if n == 1:
            say(f"[fit] first evaluation done in {_time.perf_counter() - tic:.1f} s")
            say(f"[fit] {len(free)} free parameter(s), {len(targets)} target(s); initial loss {cost:.6g}")
            return
        mark = "" if accepted else "  (rejected" + (f": trace {', '.join(failing)} failed)" if failing else ")")
        say(f"[fit] lm {n:4d}/{max_evals} loss {cost:.6g}  " + _pstr(free, np.exp(logp))
            + f"  ({_time.perf_counter() - tic:.0f} s){mark}")

    say(f"[fit] compiling the forward model and its Jacobian, first evaluation on {len(targets)} trace(s) ...")
    try:
        res = levenberg_marquardt(fun, np.log(p0), np.log(lo), np.log(hi), max_evals=max_evals,
                                  ftol=max(tol, 1e-12), xtol=1e-6, callback=progress, max_step=LM_MAX_STEP)
    except FloatingPointError:
        p_init = {k: float(params0[k]) for k in params0}
        why = "; ".join(explain_nonfinite(forward, p_init, t) for t in targets if t.name in failing)
        raise FloatingPointError(f"fit: the loss is not finite at the initial parameters: {why or 'no trace failed'}")
    say(f"[fit] {res.message}")
    history = [(n, "lm", c) for n, c, _, ok in res.history if ok]
    # the fit traces' predictions follow from the residuals at the optimum: r = c (pred - y)
    known = {}
    offsets = np.cumsum([0] + [t.y.size for t in targets])
    for t, c, a, b in zip(targets, coef, offsets[:-1], offsets[1:]):
        if c > 0:
            known[t.name] = res.r[a:b] / c + t.y
    p_opt = np.exp(res.x)

    def predict(t, logp):
        data, y, mask = padded[t.name]
        return np.asarray(resid_jac(logp, fixed_vals, data, jnp.zeros_like(y), mask)[0])[: t.y.size]

    J = res.J if covariance else None
    return _result(free, params0, p0, lo, hi, p_opt, res.r, J, res.cost, res.cost0, history, targets, holdout,
                   predict, known, res.n_evals, tic, say)


def _pstr(free, p) -> str:
    return " ".join(f"{k}={float(v):.4g}" for k, v in zip(free, np.asarray(p)))
