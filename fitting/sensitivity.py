"""Forward-mode sensitivities of the rolled tube's outputs to geometry and material.

``Setup`` (hashable) fixes everything that is not differentiated: mesh shape,
Table 2 model, voltage (sine, ``freq`` Hz, ``phi_max`` V), time grid and Newton
options. ``outputs(p, names, setup)`` maps a parameter vector ``p`` (values of
``names``: any of h, L, r and the material parameters mu_inf, K_inf, Jm_inf, eps,
rho, mu_i, K_i, Jm_i, eta_i, c_d) to a dict of arrays:

* ``x_P`` (n+1,): axial displacement of point P (m) at every grid time,
* per whole cycle of the excitation: ``x_max``, ``x_min``, ``mean`` (m),
  ``k_c`` (-, when >= 2 cycles) and ``loop_area`` (x_P against voltage, V m),
  from ``dejax.cycles``.

``sensitivity(params, names, setup)`` returns the values and the Jacobians
d output / d p (``jax.jacfwd``: k forward tangents pushed through mesh generation
(``dejax.scenarios.rolled`` builds its mesh differentiably in h, L, r) and the
time stepping, whose per-step derivatives are implicit), plus timings of one
simulation and of the Jacobian (both after compilation).

The ``sensitivity`` verb is in ``fitting.cli``.
"""
from __future__ import annotations

import dataclasses
import time as _time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from dejax import integrate as it
from dejax import cycles as feat
from dejax import linsolve, parameters, scenarios

from .fit import apply_params

__all__ = ["Setup", "outputs", "sensitivity", "reverse_check", "finite_differences", "default_params", "check_names",
           "relative_error", "check_rows"]

GEOMETRY = ("h", "L", "r")


@dataclasses.dataclass(frozen=True)
class Setup:
    """Static part of a sensitivity run (hashable)."""

    shape: tuple = (1, 4, 1)
    model: str = "I"
    freq: float = 100.0
    phi_max: float = 25e3
    t_end: float = 0.03
    dt: float = 5e-4
    rho_inf: float = 0.8
    tol: float = 1e-11
    max_iter: int = 50
    features: bool = True
    field: float | None = None  # V/m: when set, phi_max = field * h (a fixed nominal field, paper Fig. 20)
    solver: str = "auto"  # dejax.linsolve.choose_solver: dense LU up to 2,500 unknowns, SuperLU above

    @property
    def times(self) -> np.ndarray:
        return it.time_grid(self.t_end, self.dt)


def default_params(setup: Setup) -> dict:
    """h = r = 2 mm, L = 8 mm and the material of ``setup.model`` (c_d = 0)."""
    p = dict(h=2e-3, L=8e-3, r=2e-3)
    p.update(parameters.flat(scenarios.rolled_material(setup.model), damping=0.0))
    return p


def check_names(names, params):
    """KeyError naming the first of ``names`` that is no parameter or has no value in ``params``."""
    for k in names:
        if k not in GEOMETRY and not parameters.PATTERN.match(k):
            raise KeyError(f"unknown parameter {k!r}: geometry h, L, r or a material parameter "
                           "(mu_inf, K_inf, Jm_inf, eps, rho, mu_i, K_i, Jm_i, eta_i, c_d)")
        if k not in params:
            raise KeyError(f"parameter {k!r} has no value (known: {', '.join(params)})")


def outputs(p, names: tuple, base: dict, setup: Setup, control: it.StepControl | None = it.StepControl()) -> dict:
    """Outputs (see the module docstring) for parameter vector ``p`` (values of ``names``),
    other parameters from ``base``. ``control``: step cut-back (``integrate.simulate``; None:
    the user's grid only, whose derivative is one pass over it)."""
    return _outputs_and_cutbacks(p, names, base, setup, control)[0]


def _outputs_and_cutbacks(p, names, base, setup, control):
    vals = parameters.from_vector(p, names, base)
    phi_max = setup.phi_max if setup.field is None else setup.field * vals["h"]
    prob = scenarios.rolled(setup.model, freq=setup.freq, phi_max=phi_max, h=vals["h"], r=vals["r"], L=vals["L"],
                            shape=setup.shape)
    mat_p = {k: v for k, v in vals.items() if k not in GEOMETRY}
    model = apply_params(prob.model, mat_p)
    if "c_d" in vals:
        model = eqx.tree_at(lambda m: m.damping, model, jnp.asarray(vals.get("c_d", 0.0), dtype=float))
    t = setup.times
    sol = it.simulate(model, prob.loading, t, prob.output_fn, it.GeneralizedAlpha(setup.rho_inf),
                      it.NewtonOptions(tol=setup.tol, max_iter=setup.max_iter),
                      linsolve.choose_solver(prob.model.structure, setup.solver), control=control)
    x = sol.outputs["x_P"]
    out = {"x_P": jnp.where(sol.status == 0, x, jnp.nan)}
    if setup.features:
        c = feat.cycles(t, setup.freq)
        if c.n >= 1:
            v = sol.outputs["voltage"]
            out["x_max"] = feat.x_max(t, x, setup.freq)
            out["x_min"] = feat.x_min(t, x, setup.freq)
            out["mean"] = feat.mean(t, x, setup.freq)
            out["loop_area"] = feat.loop_area(x, v, t, setup.freq)
            if c.n >= 2:
                out["k_c"] = feat.k_c(t, x, setup.freq)
    return out, jnp.sum(sol.cutbacks)


_JIT: dict = {}


def _compiled(names: tuple, setup: Setup, kind: str):
    """The jitted functions of (p, base): "value", the outputs of a run with step cut-back
    plus "n_cutbacks" (steps of the run cut back); "jac", jacfwd of the outputs on the user's
    grid (one pass: the derivative of that run when it took no cut-back); "jac_replay", with
    cut-back (the run, then a replay of its accepted sub-steps differentiated)."""
    key = (names, setup, kind)
    if key not in _JIT:
        if kind == "value":
            def value(p, base):
                out, n_cut = _outputs_and_cutbacks(p, names, base, setup, it.StepControl())
                return {**out, "n_cutbacks": n_cut}

            _JIT[key] = jax.jit(value)
        else:
            control = None if kind == "jac" else it.StepControl()
            _JIT[key] = jax.jit(jax.jacfwd(lambda p, base: outputs(p, names, base, setup, control)))
    return _JIT[key]


def _block(tree):
    return jax.tree_util.tree_map(lambda a: np.asarray(jax.block_until_ready(a)), tree)


def sensitivity(params: dict, names, setup: Setup = Setup(), timing: bool = True) -> dict:
    """Values, forward-mode Jacobians and timings.

    The run takes step cut-backs where Newton needs them; when it took none (the usual
    case) its Jacobian is one forward-mode pass over the user's grid, else the accepted
    sub-steps are replayed (``integrate.simulate``; twice the work).

    Returns dict(values: name -> (..,) array, jacobian: name -> (.., k) array,
    names, p, n_cutbacks, seconds_simulation, seconds_jacobian, ratio, compile_seconds).
    Timings are of the compiled functions (best of 2 runs each when ``timing``).
    """
    names = tuple(names)
    check_names(names, params)
    base = {k: float(v) for k, v in params.items()}
    p = parameters.to_vector(base, names)
    fv = _compiled(names, setup, "value")
    tic = _time.perf_counter()
    vals = _block(fv(p, base))
    c1 = _time.perf_counter() - tic
    n_cut = int(vals.pop("n_cutbacks"))
    fj = _compiled(names, setup, "jac" if n_cut == 0 else "jac_replay")  # one pass unless the run cut back
    tic = _time.perf_counter()
    jac = _block(fj(p, base))
    c2 = _time.perf_counter() - tic
    res = dict(values=vals, jacobian=jac, names=list(names), p=np.asarray(p), n_cutbacks=n_cut,
               first_call_seconds=(c1, c2))
    if timing:
        ts, tj = [], []
        for _ in range(2):
            tic = _time.perf_counter()
            _block(fv(p, base))
            ts.append(_time.perf_counter() - tic)
            tic = _time.perf_counter()
            _block(fj(p, base))
            tj.append(_time.perf_counter() - tic)
        res.update(seconds_simulation=min(ts), seconds_jacobian=min(tj), ratio=min(tj) / min(ts))
    return res


def reverse_check(params: dict, names, setup: Setup = Setup(), jacobian: dict | None = None, seed: int = 0) -> dict:
    """Reverse mode against forward mode: for each output, w^T J (k,) by one reverse pass
    (``jax.vjp`` through the whole run: the steps' implicit derivative rule transposed) with
    random weights w, against w^T J from ``jacobian`` (the jacfwd result; computed if None).

    Returns dict(rows: name -> dict(reverse (k,), forward (k,), rel_error), seconds_reverse
    (s, one reverse pass after compilation), compile_seconds)."""
    names = tuple(names)
    check_names(names, params)
    base = {k: float(v) for k, v in params.items()}
    p = parameters.to_vector(base, names)
    if jacobian is None:
        jacobian = sensitivity(params, names, setup, timing=False)["jacobian"]
    key = (names, setup, "vjp")
    if key not in _JIT:
        _JIT[key] = jax.jit(lambda p, base, ct: jax.vjp(lambda q: outputs(q, names, base, setup), p)[1](ct)[0])
    vjp = _JIT[key]
    rng = np.random.default_rng(seed)
    zeros = {k: np.zeros(np.shape(v)[:-1]) for k, v in jacobian.items()}
    rows, secs = {}, []
    for k, J in jacobian.items():
        w = rng.standard_normal(zeros[k].shape)
        ct = {**zeros, k: w}
        tic = _time.perf_counter()
        r = np.asarray(jax.block_until_ready(vjp(p, base, ct)))
        secs.append(_time.perf_counter() - tic)  # the first includes compilation
        f = np.tensordot(w, np.asarray(J), axes=w.ndim) if w.ndim else w * np.asarray(J)
        den = np.max(np.abs(f)) or 1.0
        rows[k] = dict(reverse=r, forward=f, rel_error=float(np.max(np.abs(r - f)) / den))
    return dict(rows=rows, seconds_reverse=min(secs[1:] or secs), compile_seconds=secs[0])


def finite_differences(params: dict, names, setup: Setup = Setup(), rel_step: float = 1e-4) -> dict:
    """Central differences of ``outputs`` (same compiled forward function): name -> (.., k)."""
    names = tuple(names)
    base = {k: float(v) for k, v in params.items()}
    p = np.asarray(parameters.to_vector(base, names))
    fv = _compiled(names, setup, "value")
    cols = []
    for i in range(len(names)):
        h = rel_step * abs(p[i])
        pp, pm = p.copy(), p.copy()
        pp[i] += h
        pm[i] -= h
        a, b = _block(fv(jnp.asarray(pp), base)), _block(fv(jnp.asarray(pm), base))
        cols.append({k: (a[k] - b[k]) / (2 * h) for k in a if k != "n_cutbacks"})
    return {k: np.stack([c[k] for c in cols], axis=-1) for k in cols[0]}


def relative_error(J, J_ref) -> float:
    """max |J - J_ref| / max |J_ref|, per column, maximum over columns."""
    J, J_ref = np.asarray(J), np.asarray(J_ref)
    J2, R2 = J.reshape(-1, J.shape[-1]), J_ref.reshape(-1, J_ref.shape[-1])
    den = np.max(np.abs(R2), axis=0)
    den = np.where(den > 0, den, 1.0)
    return float(np.max(np.max(np.abs(J2 - R2), axis=0) / den))


def check_rows(res: dict, fd: dict, rev: dict | None = None, tiny: float = 1e-3) -> list[dict]:
    """Per output of ``sensitivity`` (``res``): the check against central differences ``fd``
    (and reverse mode ``rev``, from ``reverse_check``).

    An entry dy/dp_j counts as tiny when its relative sensitivity |p_j dy/dp_j| / max|y| is
    below ``tiny`` (a 100 % change of p_j moves y by less than 0.1 %): differences of it
    measure the solver's round-off, not the derivative, so it is reported but not judged.
    Returns dicts(output, row (the row judged: the largest relative sensitivity), value,
    rel_sens (p_j/y dy/dp_j there), param, fd_error (relative_error over the judged
    columns, None if every column is tiny), rev_error, tiny (names of the unjudged
    columns))."""
    names, p = res["names"], np.asarray(res["p"])
    out = []
    for k, J in res["jacobian"].items():
        J = np.asarray(J).reshape(-1, len(names))
        F = np.asarray(fd[k]).reshape(-1, len(names))
        y = np.asarray(res["values"][k]).reshape(-1)
        ymax = np.max(np.abs(y)) or 1.0
        rel = F * p / ymax  # (rows, k) relative sensitivities (from the differences)
        judged = np.max(np.abs(rel), axis=0) >= tiny
        i, j = np.unravel_index(int(np.argmax(np.abs(rel))), rel.shape)
        err = relative_error(J[:, judged], F[:, judged]) if judged.any() else None
        out.append(dict(output=k, row=int(i), value=float(y[i]), rel_sens=float(rel[i, j]), param=names[j],
                        fd_error=err, rev_error=None if rev is None else rev["rows"][k]["rel_error"],
                        tiny=[n for n, m in zip(names, judged) if not m]))
    return out
