"""The experiment-file schema: sections, keys, roles, loading tables, and the error type.

The allowed sets are the module constants ``SECTIONS``, ``EXPERIMENT_KEYS``,
``GEOMETRY_KEYS`` (per scenario), ``MATERIAL_KEYS``, ``UNIT_KEYS``, ``FIT_KEYS``,
``FIT_RESULT_KEYS``, ``SOLVER_KEYS``, ``TRACE_KEYS``, ``LOADING_KINDS``; extend them there
when a new option is implemented. ``DataError`` locates every problem (file, TOML key, CSV row and column);
``check_loading`` validates a loading table and ``loading_voltage`` evaluates one. The file
format itself: ``fitting.data`` and ``docs/experiment-format.md``.
"""
from __future__ import annotations

import difflib
import math
from typing import Any, Mapping

import numpy as np

from dejax import parameters as mp
from dejax import scenarios

__all__ = ["DataError", "SCENARIOS", "LOADING_KINDS", "check_loading", "loading_voltage", "suggest", "fmt_list",
           "is_number"]

SCENARIOS = scenarios.NAMES  # ("block", "rolled", "torsional", "uniaxial"): the registry's
DYNAMIC_SCENARIOS = ("block", "rolled", "torsional")
ROLES = ("fit", "holdout")

SECTIONS = ("experiment", "geometry", "material", "fit", "solver", "effects", "traces")
EXPERIMENT_KEYS = ("name", "scenario", "description")
GEOMETRY_KEYS = {
    "block": ("L", "lx", "ly", "lz", "mesh"),
    "rolled": ("h", "r", "L", "mesh", "probe"),
    "torsional": ("L", "W", "h", "twist", "mesh"),
    "uniaxial": ("L", "W", "h", "mesh"),
}
GEOMETRY_REQUIRED = {
    "block": (),  # L or lx, ly, lz: GEOMETRY_ALTERNATIVE
    "rolled": ("h", "r", "L"),
    "torsional": ("L", "W", "h"),
    "uniaxial": (),
}
GEOMETRY_ALTERNATIVE = {"block": ("L", ("lx", "ly", "lz"), " (give L, or all of lx, ly, lz)")}
"""scenario -> (key, the keys required without it, the hint of the message)."""
GEOMETRY_OPTIONAL = ("uniaxial",)
"""Scenarios whose [geometry] section may be left out."""
TRACE_REQUIRED = {"block": ("time",), "rolled": ("time",), "torsional": ("time",), "uniaxial": ("stretch", "stress")}
"""scenario -> the channels every trace must map."""
MATERIAL_KEYS = ("mu_inf", "K_inf", "Jm_inf", "eps", "rho", "units", "mullins_d", "mullins_m")
MATERIAL_SCALARS = mp.SCALARS  # the TOML keys are the parameter names (dejax.parameters)
MATERIAL_OPTIONAL = {"mullins_d": (0.0, False, 1.0), "mullins_m": (0.0, True, None)}
"""Optional [material] keys beyond the paper's model: (lower bound, whether it is strict, exclusive
upper bound or None). Mullins softening; absent keys take ``dejax.material.Material``'s defaults (off)."""
UNIT_KEYS = mp.UNIT_KEYS
# lower bound and whether it is strict, for the material parameters
STRICTLY_POSITIVE = {"mu_inf": True, "K_inf": False, "Jm_inf": True, "eps": False, "rho": True,
             "mu": True, "K": False, "Jm": True, "eta": True}
FIT_KEYS = ("free", "bounds", "scale", "loss", "features", "weights", "optimizer", "max_iter",
            "tol", "learning_rate", "result")
FIT_RESULT_KEYS = {"value": "number", "unit": "string", "stderr": "number", "rel_stderr": "number",
                   "initial": "number"}
"""``[fit.result]``: parameter name -> these keys (all optional), as ``dejax fit`` writes them in
``fitted.toml`` (value, standard error and initial value in the parameter's unit, the relative
standard error in 1). Validated for form only; no verb reads them."""
OPTIMIZERS = ("lm", "adam-lbfgs")
"""``[fit] optimizer`` values (``fitting.fit.METHODS``): Levenberg-Marquardt, optax Adam then L-BFGS."""
SOLVER_KEYS = ("dt", "dt_min", "t_end", "n_cycles", "rho_inf", "damping", "gauss_order",
               "newton_tol", "newton_max_iter", "save_every", "linear_solver")
TRACE_KEYS = ("file", "name", "role", "conditions", "columns", "units", "loading", "weight")
LOADING_KINDS = {
    # kind: (required keys, optional keys with defaults)
    "sine": (("phi_max", "freq"), {"phase": 1.5 * math.pi, "offset": 0.0}),
    "ramp_hold": (("phi_max",), {"t_ramp": 1.0}),
    "constant": (("phi",), {}),
    "piecewise": (("times", "values"), {}),
}


# ---------------------------------------------------------------------------
# errors
# ---------------------------------------------------------------------------


class DataError(ValueError):
    """A problem with an experiment file or a trace, located as precisely as possible.

    Attributes: ``file`` (path), ``row`` (CSV row, header = 1), ``column``
    (CSV header), ``key`` (TOML key path such as ``fit.bounds.mu_1``).
    """

    def __init__(self, message: str, *, file=None, row=None, column=None, key=None, line=None):
        self.file = None if file is None else str(file)
        self.row = row
        self.column = column
        self.key = key
        self.line = line
        where = []
        if row is not None:
            where.append(f"row {row}" + (f" (line {line})" if line is not None and line != row else ""))
        elif line is not None:
            where.append(f"line {line}")
        if column is not None:
            where.append(f"column '{column}'")
        if key is not None:
            where.append(f"[{key}]" if "." not in key else key)
        prefix = (self.file + ": " if self.file else "") + (", ".join(where) + ": " if where else "")
        super().__init__(prefix + message)


def suggest(word: str, options) -> str:
    options = [str(o) for o in options]
    same_case = [o for o in options if o.lower() == str(word).lower()]
    if same_case:
        return f" (did you mean '{same_case[0]}'?)"
    close = difflib.get_close_matches(str(word), options, n=1, cutoff=0.6)
    return f" (did you mean '{close[0]}'?)" if close else ""


def fmt_list(options) -> str:
    return ", ".join(str(o) for o in options) if options else "(none)"


# ---------------------------------------------------------------------------
# loading tables
# ---------------------------------------------------------------------------


def is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def check_loading(spec: dict, file, key: str) -> dict:
    kind = spec.get("kind")
    if kind is None:
        raise DataError(f"missing 'kind'; one of {fmt_list(LOADING_KINDS)}", file=file, key=key)
    if kind not in LOADING_KINDS:
        raise DataError(f"unknown loading kind '{kind}'{suggest(kind, LOADING_KINDS)}; known: "
                        f"{fmt_list(LOADING_KINDS)}", file=file, key=f"{key}.kind")
    req, opt = LOADING_KINDS[kind]
    allowed = ("kind",) + tuple(req) + tuple(opt)
    for k in spec:
        if k not in allowed:
            raise DataError(f"unknown key '{k}' for loading kind '{kind}'{suggest(k, allowed)}; "
                            f"allowed: {fmt_list(allowed)}", file=file, key=f"{key}.{k}")
    for k in req:
        if k not in spec:
            raise DataError(f"loading kind '{kind}' needs '{k}' (required: {fmt_list(req)})",
                            file=file, key=key)
    out = {"kind": kind}
    for k in tuple(req) + tuple(opt):
        v = spec.get(k, opt.get(k))
        if kind == "piecewise":
            if not (isinstance(v, list) and v and all(is_number(x) for x in v)):
                raise DataError(f"'{k}' must be a non-empty list of numbers", file=file, key=f"{key}.{k}")
            v = [float(x) for x in v]
        else:
            if not is_number(v) or not math.isfinite(v):
                raise DataError(f"'{k}' must be a finite number, got {v!r}", file=file, key=f"{key}.{k}")
            v = float(v)
        out[k] = v
    if kind == "sine" and out["freq"] <= 0:
        raise DataError(f"freq = {out['freq']} Hz must be > 0", file=file, key=f"{key}.freq")
    if kind == "ramp_hold" and out["t_ramp"] <= 0:
        raise DataError(f"t_ramp = {out['t_ramp']} s must be > 0", file=file, key=f"{key}.t_ramp")
    if kind == "piecewise":
        if len(out["times"]) != len(out["values"]):
            raise DataError(f"'times' ({len(out['times'])}) and 'values' ({len(out['values'])}) "
                            "must have equal lengths", file=file, key=key)
        if np.any(np.diff(out["times"]) <= 0):
            raise DataError("'times' must increase strictly", file=file, key=f"{key}.times")
    return out


def loading_voltage(spec: Mapping[str, Any], t):
    """Nominal voltage (V) of a loading table at times ``t`` (s): ``dejax.loads.from_spec(spec)(t)``.

    Written with jax.numpy: differentiable in ``t`` and in the numeric entries of
    ``spec`` (those of piecewise tables excepted). See ``LOADING_KINDS`` and the module
    docstring for the forms.
    """
    import jax.numpy as jnp

    from dejax import loads

    return loads.from_spec(spec)(jnp.asarray(t, dtype=float))
