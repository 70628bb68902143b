'''Experiment files: one TOML file plus CSV traces describe an experiment.

The same file drives ``dejax run`` (simulate the experiment), ``dejax fit``
(identify the free parameters from the ``fit`` traces) and ``dejax diagnose``
(compare with the ``holdout`` traces and try candidate effects). Everything is
SI (m, kg, s, Pa, V, F/m) once loaded; CSV columns may carry other units,
declared per trace and converted on loading. A user's guide with every key, its unit,
its default and the verb that reads it: ``docs/experiment-format.md``.

This module reads the TOML file (``load_experiment`` -> ``Experiment``); the allowed keys
and ``DataError`` are in ``fitting.schema``, units in ``fitting.units``, the CSV traces in
``fitting.traces``.

Example
-------
``tube.toml``::

    [experiment]
    name = "tube-30Hz"
    scenario = "rolled"              # block | rolled | torsional | uniaxial
    description = "rolled DEA, point P on the inner edge of the top face"

    [geometry]                       # SI; keys depend on the scenario (below)
    h = 2e-3                         # wall thickness (m)
    r = 2e-3                         # inner radius (m)
    L = 8e-3                         # length (m)
    mesh = [4, 8, 1]                 # axial x circumferential x radial elements
    probe = "inner"                  # point P (free-form: name or [x, y, z] in m)

    [material]                       # equilibrium network (paper Eqs. 18-20)
    mu_inf = 81e3                    # Pa
    K_inf = 3e9                      # Pa
    Jm_inf = 15.0                    # -
    eps = 3.4e-11                    # F/m
    rho = 1500.0                     # kg/m^3

    [[material.units]]               # viscous unit 1 (parameters mu_1, K_1, Jm_1, eta_1)
    mu = 80e3                        # Pa
    K = 7.5e9                        # Pa
    Jm = 5.0                         # -
    eta = 400.0                      # Pa s

    [fit]
    free = ["mu_inf", "mu_1", "eta_1"]
    scale = "log"                    # log | linear: parametrization of the free parameters
    loss = "trace"                   # free-form string for the fitting module
    max_iter = 200

    [fit.bounds]                     # [lower, upper], lower < upper, initial value inside
    mu_1 = [1e3, 1e6]
    eta_1 = [1.0, 1e5]

    [solver]
    dt = 1e-4                        # s
    rho_inf = 0.8                    # generalized-alpha spectral radius, [0, 1]
    damping = 0.0                    # structural damping c_d (1/s), C_d = c_d M
    gauss_order = 3

    [effects.electrode_stiffness]    # optional candidate effects: name -> parameters
    enabled = false
    thickness = 1e-5

    [[traces]]
    file = "trace_30Hz.csv"          # relative to this TOML file
    role = "fit"                     # fit | holdout
    conditions = { freq = 30.0, phi_max = 25e3 }
    columns = { time = "time_s", displacement = "displacement_mm" }
    units = { displacement = "mm" }  # default: SI
    loading = { kind = "sine", phi_max = 25e3, freq = 30.0 }

    [[traces]]
    file = "trace_10Hz.csv"
    role = "holdout"
    columns = { time = "t_ms", displacement = "x_um", voltage = "U_kV" }
    units = { time = "ms", displacement = "um", voltage = "kV" }

``trace_30Hz.csv`` (comma separated, one header row; lines starting with '#'
and blank lines are ignored; extra columns are ignored)::

    # synthetic trace
    time_s,displacement_mm
    0.0,0.0
    0.0005,0.0012
    ...

``exp = load_experiment("tube.toml")`` then gives ``exp.traces[0].time`` (s),
``exp.traces[0]["displacement"]`` (m), ``exp.parameters()["eta_1"]`` (400.0),
``Material(**exp.material_kwargs())`` (a ``dejax.material.Material``).

Sections and keys
-----------------
Unknown sections or keys are errors (typo protection): the message lists
the allowed ones. The allowed sets are the ``fitting.schema`` constants ``SECTIONS``,
``EXPERIMENT_KEYS``, ``GEOMETRY_KEYS`` (per scenario), ``MATERIAL_KEYS``,
``UNIT_KEYS``, ``FIT_KEYS``, ``FIT_RESULT_KEYS``, ``SOLVER_KEYS``, ``TRACE_KEYS``,
``LOADING_KINDS``; extend them there when a new option is implemented.

``[experiment]`` (required): ``name`` (str, required), ``scenario`` (required,
one of ``SCENARIOS``), ``description`` (str).

``[geometry]`` (required except for ``uniaxial``), SI lengths > 0,
``mesh`` = three element counts >= 1:

* block: ``L`` (cube side) or all of ``lx``, ``ly``, ``lz``; ``mesh``.
* rolled: ``h`` (wall thickness), ``r`` (inner radius, >= 0), ``L`` (length),
  required; ``mesh`` = [n_axial, n_circumferential, n_radial]; ``probe``.
* torsional: ``L``, ``W``, ``h`` required; ``twist`` (turns over the length,
  default 1); ``mesh``.
* uniaxial (material test): optional ``L``, ``W``, ``h`` (specimen, e.g. h
  to turn a voltage into a field), ``mesh``.

``[material]`` (required): ``mu_inf``, ``K_inf``, ``Jm_inf``, ``eps``, ``rho``
(all required, SI) and zero or more ``[[material.units]]`` tables with ``mu``,
``K``, ``Jm``, ``eta`` (all required). mu, Jm, rho, eta > 0; K, eps >= 0.

``[fit]`` (optional): ``free`` (list of parameter names, below), ``bounds``
(table name -> [lower, upper]), ``scale`` ("log" | "linear"), ``loss`` (str),
``features`` (list of str), ``weights`` (table name -> number),
``optimizer`` (str), ``max_iter`` (int > 0), ``tol`` (number > 0),
``learning_rate`` (number > 0), ``result`` (table parameter name -> table of
``FIT_RESULT_KEYS``: what ``dejax fit`` found, written in its ``fitted.toml``; form checked,
kept as ``FitSpec.result``, read by no verb).

Parameter names: ``mu_inf``, ``K_inf``, ``Jm_inf``, ``eps``, ``rho``; per
viscous unit ``mu_i``, ``K_i``, ``Jm_i``, ``eta_i`` with i = 1..N (1-based,
in the order of the ``[[material.units]]`` tables); geometric parameters as
``geometry.<key>`` (e.g. ``geometry.h``); numeric effect parameters as
``effects.<name>.<param>``. Bounds may be given for any of them; the current
(initial) value must lie within them.

``[solver]`` (optional): ``dt``, ``dt_min``, ``t_end`` (s, > 0), ``n_cycles``
(int > 0), ``rho_inf`` ([0, 1]), ``damping`` (>= 0), ``gauss_order`` (int
1..7), ``newton_tol`` (> 0), ``newton_max_iter`` (int > 0), ``save_every``
(int > 0), ``linear_solver`` (str).

``[effects]`` (optional): each key names a candidate effect; its value is a
table of parameters (numbers, strings, booleans or lists) or a boolean
(``true`` = enabled with default parameters). ``enabled = false`` inside a
table switches an effect off without deleting it. Effect names are checked by
the diagnosis module, not here.

``[[traces]]`` (at least one): ``file`` (required; path relative to the TOML
file), ``name`` (default: the file's stem; unique), ``role`` ("fit" default |
"holdout"), ``conditions`` (table of numbers, strings or booleans: the
operating point, e.g. freq in Hz, phi_max in V, temp in K, or any geometry key
overriding ``[geometry]`` for this trace), ``columns`` (table channel ->
CSV header; default: every header that is itself a channel name), ``units``
(table channel -> unit, default SI), ``loading`` (nominal voltage history
when the CSV has no voltage column, see ``LOADING_KINDS``; if both are given
the measured column is what a run uses), ``weight`` (number >= 0, default 1).

Channels (``CHANNELS``) and their SI units: time (s), displacement (m),
velocity (m/s), voltage (V), field (V/m), stretch (-), strain (-), stress
(Pa), force (N), angle (rad), charge (C), current (A), temperature (K).
Required channels: time plus at least one response channel (not voltage)
and a voltage column or a ``loading`` table for block, rolled and torsional
traces; stretch and stress for uniaxial traces (time and voltage optional).
Time, when present, must increase strictly. Accepted units per quantity:
``UNITS`` (e.g. ms, us, mm, um, kV, kPa, MPa, deg, degC).

Loading kinds (all SI): ``sine`` with ``phi_max``, ``freq``, optional
``phase`` (rad, default 1.5 pi) and ``offset`` (V, default 0):
phi = offset + phi_max/2 (1 + sin(2 pi freq t + phase)) (paper Eq. 42);
``ramp_hold`` with ``phi_max``, optional ``t_ramp`` (s, default 1):
phi_max/2 (1 + sin(pi t / t_ramp - pi/2)) up to t_ramp, then phi_max (Eq. 41);
``constant`` with ``phi``; ``piecewise`` with ``times`` (s, increasing) and
``values`` (V): linear interpolation, held constant outside. If both
``conditions`` and ``loading`` give ``freq`` or ``phi_max`` they must agree.

Errors
------
Every problem raises ``DataError`` (a ``ValueError``) whose message starts
with the file it concerns and names the TOML section/key, or the CSV row and
column. CSV rows are counted with the header as row 1 (comment and blank lines
not counted); when comment lines shift them, the physical line number follows
in parentheses. The attributes ``file``, ``row``, ``column`` and ``key`` hold
the same information.
'''
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from dejax import parameters as mp

from .schema import (DYNAMIC_SCENARIOS, EXPERIMENT_KEYS, FIT_KEYS, FIT_RESULT_KEYS, GEOMETRY_ALTERNATIVE, GEOMETRY_KEYS,
                     GEOMETRY_OPTIONAL, GEOMETRY_REQUIRED, MATERIAL_KEYS, MATERIAL_OPTIONAL, MATERIAL_SCALARS,
                     OPTIMIZERS, ROLES, SCENARIOS,
                     SECTIONS, SOLVER_KEYS, STRICTLY_POSITIVE, TRACE_KEYS, TRACE_REQUIRED, UNIT_KEYS, DataError,
                     check_loading, fmt_list, is_number, suggest)
from .traces import Trace, load_trace_csv

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10: the tomli backport (a dependency there)
    import tomli as tomllib

__all__ = ["FitSpec", "Experiment", "load_experiment", "read_document"]


# ---------------------------------------------------------------------------
# experiments
# ---------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class FitSpec:
    """The ``[fit]`` section: free parameter names (in order), their bounds
    (name -> (lower, upper)), the remaining options as given and the ``[fit.result]`` of a
    fitted file (name -> ``FIT_RESULT_KEYS`` as given)."""

    free: tuple[str, ...] = ()
    bounds: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    options: Mapping[str, Any] = field(default_factory=dict)
    result: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)


@dataclass(frozen=True, eq=False)
class Experiment:
    """An experiment file, validated and in SI units (see the module docstring).

    Attributes:
      name, scenario, description: from ``[experiment]``.
      path: the TOML file.
      geometry: ``[geometry]`` as given (floats; ``mesh`` a tuple of 3 ints).
      material: ``mu_inf``, ``K_inf``, ``Jm_inf``, ``eps``, ``rho`` (floats) and
        ``units`` (tuple of dicts with ``mu``, ``K``, ``Jm``, ``eta``).
      fit: ``FitSpec``.
      solver: ``[solver]`` as given.
      effects: enabled effects only, name -> parameter dict.
      traces: tuple of ``Trace`` in file order.
    """

    name: str
    scenario: str
    path: Path
    geometry: Mapping[str, Any]
    material: Mapping[str, Any]
    fit: FitSpec
    solver: Mapping[str, Any]
    effects: Mapping[str, Mapping[str, Any]]
    traces: tuple[Trace, ...]
    description: str = ""

    @property
    def n_units(self) -> int:
        """Number of viscous units."""
        return len(self.material["units"])

    @property
    def fit_traces(self) -> tuple[Trace, ...]:
        return tuple(tr for tr in self.traces if tr.role == "fit")

    @property
    def holdout_traces(self) -> tuple[Trace, ...]:
        return tuple(tr for tr in self.traces if tr.role == "holdout")

    def trace(self, name: str) -> Trace:
        for tr in self.traces:
            if tr.name == name:
                return tr
        raise KeyError(f"{self.path}: no trace named '{name}'; traces: {fmt_list(t.name for t in self.traces)}")

    def parameters(self) -> dict[str, float]:
        """All named parameters and their current values: material (``mu_inf``,
        ..., ``mu_1``, ``eta_1``, ...), ``geometry.<key>`` and
        ``effects.<name>.<param>`` for numeric entries."""
        return _parameters(self.material, self.geometry, self.effects)

    def material_kwargs(self, overrides: Mapping[str, Any] | None = None) -> dict[str, Any]:
        """Keyword arguments for ``dejax.material.Material``, with optional
        overrides by parameter name (values may be jax arrays, e.g. inside a
        fit: ``Material(**exp.material_kwargs({"mu_1": theta[0]}))``)."""
        overrides = dict(overrides or {})
        allowed = mp.names(self.n_units)
        for k in overrides:
            if k not in allowed:
                raise KeyError(f"unknown material parameter '{k}'{suggest(k, allowed)}; known: {fmt_list(allowed)}")
        kw = mp.material_kwargs({**self.parameters(), **overrides}, self.n_units)
        kw.update({k: self.material[k] for k in MATERIAL_OPTIONAL if k in self.material})
        return kw


def _parameters(material, geometry, effects) -> dict[str, float]:
    p = {k: float(material[k]) for k in MATERIAL_SCALARS}
    for i, u in enumerate(material["units"]):
        for k in UNIT_KEYS:
            p[f"{k}_{i + 1}"] = float(u[k])
    for k, v in geometry.items():
        if is_number(v):
            p[f"geometry.{k}"] = float(v)
    for name, params in effects.items():
        for k, v in params.items():
            if is_number(v):
                p[f"effects.{name}.{k}"] = float(v)
    return p


class _Toml:
    """Helpers bound to one TOML file: locate keys for messages, check tables."""

    def __init__(self, path: Path, text: str):
        self.path = path
        self.lines = text.splitlines()

    def line_of(self, key: str) -> int | None:
        """Best-effort line number of a dotted key path (for messages)."""
        parts = key.split(".")
        last = parts[-1]
        section = None
        header_re = re.compile(r"^\s*\[\[?\s*([^\]]+?)\s*\]\]?\s*(#.*)?$")
        key_re = re.compile(rf"(^|[\s{{,]){re.escape(last)}\s*=")
        table = ".".join(parts[:-1])
        fallback = None
        for i, text in enumerate(self.lines, start=1):
            m = header_re.match(text)
            if m:
                section = m.group(1)
                if section == key:
                    return i
                continue
            if key_re.search(text.split("#", 1)[0]):
                if section is not None and (table == section or table.startswith(section + ".")
                                            or section.startswith(table)):
                    return i
                if fallback is None:
                    fallback = i
        return fallback

    def error(self, message: str, key: str | None = None) -> DataError:
        line = self.line_of(key) if key else None
        return DataError(message + (f" (line {line})" if line else ""), file=self.path, key=key)

    def table(self, value, key: str) -> dict:
        if not isinstance(value, dict):
            raise self.error(f"'{key}' must be a table, got {type(value).__name__} {value!r}", key)
        return value

    def array_of_tables(self, value, allowed, key: str, what: str):
        """Yield (i, table) of an array of tables ``[[key]]`` (i from 1), checking each entry is a
        table whose keys are all in ``allowed``; ``what`` names an entry in messages."""
        for i, entry in enumerate(value, start=1):
            if not isinstance(entry, dict):
                raise self.error(f"{what} {i} must be a table", key)
            for k in entry:
                if k not in allowed:
                    raise self.error(f"unknown key '{k}' in {what} {i}{suggest(k, allowed)}; allowed: "
                                     f"{fmt_list(allowed)}", f"{key}.{k}")
            yield i, entry

    def check_keys(self, table: dict, allowed, key: str) -> None:
        for k in table:
            if k not in allowed:
                what = f"key '{k}' in [{key}]" if key else f"section [{k}]"
                raise self.error(
                    f"unknown {what}{suggest(k, allowed)}; allowed: {fmt_list(allowed)}",
                    f"{key}.{k}" if key else k,
                )

    def number(self, table: dict, k: str, key: str, *, lower=None, strict=True, upper=None,
               integer=False):
        v = table[k]
        full = f"{key}.{k}"
        if integer:
            if not isinstance(v, int) or isinstance(v, bool):
                raise self.error(f"'{k}' must be an integer, got {v!r}", full)
        elif not is_number(v) or not math.isfinite(v):
            raise self.error(f"'{k}' must be a finite number, got {v!r}", full)
        if lower is not None and (v <= lower if strict else v < lower):
            raise self.error(f"'{k}' = {v} must be {'>' if strict else '>='} {lower}", full)
        if upper is not None and v > upper:
            raise self.error(f"'{k}' = {v} must be <= {upper}", full)
        return int(v) if integer else float(v)


def read_document(path) -> tuple[str, dict]:
    """The text of a TOML file and its parsed document (not validated); DataError naming
    the file when it is missing, empty or not TOML."""
    path = Path(path)
    if not path.is_file():
        raise DataError("experiment file not found", file=path)
    text = path.read_bytes().decode("utf-8-sig", errors="replace")
    if not text.strip():
        raise DataError("empty experiment file", file=path)
    try:
        return text, tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise DataError(f"invalid TOML: {e}", file=path) from None


def load_experiment(path) -> Experiment:
    """Load and validate an experiment TOML file and its CSV traces.

    Raises ``DataError`` (file, key or row/column named) on any problem; see
    the module docstring for the schema.
    """
    path = Path(path)
    text, doc = read_document(path)
    tf = _Toml(path, text)
    tf.check_keys(doc, SECTIONS, "")
    for sec in ("experiment", "material", "traces"):
        if sec not in doc:
            raise DataError(f"missing required section [{sec}]" + (" (use [[traces]] tables)" if sec == "traces" else ""),
                            file=path)

    # [experiment]
    ex = tf.table(doc["experiment"], "experiment")
    tf.check_keys(ex, EXPERIMENT_KEYS, "experiment")
    for k in ("name", "scenario"):
        if k not in ex:
            raise tf.error(f"missing required key '{k}'", "experiment")
        if not isinstance(ex[k], str) or not ex[k].strip():
            raise tf.error(f"'{k}' must be a non-empty string, got {ex[k]!r}", f"experiment.{k}")
    scenario = ex["scenario"]
    if scenario not in SCENARIOS:
        raise tf.error(f"unknown scenario '{scenario}'{suggest(scenario, SCENARIOS)}; known: {fmt_list(SCENARIOS)}",
                       "experiment.scenario")
    description = ex.get("description", "")
    if not isinstance(description, str):
        raise tf.error("'description' must be a string", "experiment.description")

    geometry = _load_geometry(tf, doc, scenario)
    material = _load_material(tf, doc)
    effects = _load_effects(tf, doc)
    solver = _load_solver(tf, doc)
    params = _parameters(material, geometry, effects)
    fit = _load_fit(tf, doc, params, material)
    traces = _load_traces(tf, doc, scenario)
    return Experiment(
        name=ex["name"], scenario=scenario, path=path, geometry=geometry, material=material, fit=fit,
        solver=solver, effects=effects, traces=traces, description=description,
    )


def _load_geometry(tf: _Toml, doc, scenario) -> dict:
    if "geometry" not in doc:
        if scenario in GEOMETRY_OPTIONAL:
            return {}
        raise DataError(f"missing required section [geometry] for scenario '{scenario}' "
                        f"(keys: {fmt_list(GEOMETRY_KEYS[scenario])})", file=tf.path)
    g = tf.table(doc["geometry"], "geometry")
    allowed = GEOMETRY_KEYS[scenario]
    for k in g:
        if k not in allowed:
            raise tf.error(f"unknown key '{k}' in [geometry] for scenario '{scenario}'{suggest(k, allowed)}; "
                           f"allowed: {fmt_list(allowed)}", f"geometry.{k}")
    required, hint = GEOMETRY_REQUIRED[scenario], ""
    if scenario in GEOMETRY_ALTERNATIVE:
        key, instead, hint = GEOMETRY_ALTERNATIVE[scenario]
        if key not in g:
            required = instead
    for k in required:
        if k not in g:
            raise tf.error(f"missing required key '{k}' for scenario '{scenario}'" + hint, "geometry")
    out = {}
    for k, v in g.items():
        if k == "mesh":
            if not (isinstance(v, list) and len(v) == 3 and all(isinstance(n, int) and not isinstance(n, bool)
                                                               and n >= 1 for n in v)):
                raise tf.error(f"'mesh' must be a list of three integers >= 1, got {v!r}", "geometry.mesh")
            out[k] = tuple(v)
        elif k == "probe":
            ok = isinstance(v, str) or (isinstance(v, list) and len(v) == 3 and all(is_number(x) for x in v))
            if not ok:
                raise tf.error(f"'probe' must be a name or [x, y, z] (m), got {v!r}", "geometry.probe")
            out[k] = v if isinstance(v, str) else tuple(float(x) for x in v)
        elif k == "r":
            out[k] = tf.number(g, k, "geometry", lower=0.0, strict=False)
        elif k == "twist":
            out[k] = tf.number(g, k, "geometry")
        else:
            out[k] = tf.number(g, k, "geometry", lower=0.0)
    return out


def _load_material(tf: _Toml, doc) -> dict:
    m = tf.table(doc["material"], "material")
    tf.check_keys(m, MATERIAL_KEYS, "material")
    out = {}
    for k in MATERIAL_SCALARS:
        if k not in m:
            raise tf.error(f"missing required key '{k}' (required: {fmt_list(MATERIAL_SCALARS)})", "material")
        out[k] = tf.number(m, k, "material", lower=0.0, strict=STRICTLY_POSITIVE[k])
    for k, (lo, strict, hi) in MATERIAL_OPTIONAL.items():
        if k in m:
            out[k] = tf.number(m, k, "material", lower=lo, strict=strict)
            if hi is not None and out[k] >= hi:
                raise tf.error(f"'{k}' = {out[k]} must be < {hi}", f"material.{k}")
    units = m.get("units", [])
    if not isinstance(units, list):
        raise tf.error("'units' must be an array of tables ([[material.units]])", "material.units")
    out_units = []
    for i, u in tf.array_of_tables(units, UNIT_KEYS, "material.units", "viscous unit"):
        key = f"material.units[{i}]"
        for k in UNIT_KEYS:
            if k not in u:
                raise tf.error(f"viscous unit {i} lacks '{k}' (required: {fmt_list(UNIT_KEYS)})", "material.units")
        out_units.append({k: tf.number(u, k, key, lower=0.0, strict=STRICTLY_POSITIVE[k]) for k in UNIT_KEYS})
    out["units"] = tuple(out_units)
    return out


def _load_effects(tf: _Toml, doc) -> dict:
    if "effects" not in doc:
        return {}
    e = tf.table(doc["effects"], "effects")
    out = {}
    for name, spec in e.items():
        key = f"effects.{name}"
        if isinstance(spec, bool):
            if spec:
                out[name] = {}
            continue
        if not isinstance(spec, dict):
            raise tf.error(f"effect '{name}' must be a table of parameters or a boolean, got {spec!r}", key)
        params = {}
        for k, v in spec.items():
            if k == "enabled":
                if not isinstance(v, bool):
                    raise tf.error(f"'enabled' must be true or false, got {v!r}", f"{key}.enabled")
                continue
            if is_number(v):
                if not math.isfinite(v):
                    raise tf.error(f"'{k}' must be finite", f"{key}.{k}")
                params[k] = float(v)
            elif isinstance(v, (str, bool)):
                params[k] = v
            elif isinstance(v, list) and all(is_number(x) or isinstance(x, str) for x in v):
                params[k] = tuple(v)
            else:
                raise tf.error(f"effect parameter '{k}' must be a number, string, boolean or list, got {v!r}",
                               f"{key}.{k}")
        if spec.get("enabled", True):
            out[name] = params
    return out


def _load_solver(tf: _Toml, doc) -> dict:
    if "solver" not in doc:
        return {}
    s = tf.table(doc["solver"], "solver")
    tf.check_keys(s, SOLVER_KEYS, "solver")
    out = {}
    for k in s:
        if k in ("dt", "dt_min", "t_end", "newton_tol"):
            out[k] = tf.number(s, k, "solver", lower=0.0)
        elif k in ("n_cycles", "newton_max_iter", "save_every"):
            out[k] = tf.number(s, k, "solver", lower=0, integer=True)
        elif k == "gauss_order":
            out[k] = tf.number(s, k, "solver", lower=1, strict=False, upper=7, integer=True)
        elif k == "rho_inf":
            out[k] = tf.number(s, k, "solver", lower=0.0, strict=False, upper=1.0)
        elif k == "damping":
            out[k] = tf.number(s, k, "solver", lower=0.0, strict=False)
        elif k == "linear_solver":
            if not isinstance(s[k], str):
                raise tf.error("'linear_solver' must be a string", "solver.linear_solver")
            out[k] = s[k]
    if "dt" in out and "dt_min" in out and out["dt_min"] > out["dt"]:
        raise tf.error(f"dt_min = {out['dt_min']} s exceeds dt = {out['dt']} s", "solver.dt_min")
    return out


def _load_fit(tf: _Toml, doc, params: dict, material) -> FitSpec:
    if "fit" not in doc:
        return FitSpec()
    f = tf.table(doc["fit"], "fit")
    tf.check_keys(f, FIT_KEYS, "fit")
    n_units = len(material["units"])

    def check_name(name, key):
        if not isinstance(name, str):
            raise tf.error(f"parameter names must be strings, got {name!r}", key)
        if name in params:
            return
        hint = suggest(name, params)
        m = re.fullmatch(r"(mu|K|Jm|eta)_(\d+)", name)
        if m:
            i = int(m.group(2))
            if i == 0:
                hint = " (viscous units are numbered from 1)"
            else:
                names = {0: "", 1: f": {m.group(1)}_1"}.get(n_units, f": {m.group(1)}_1..{m.group(1)}_{n_units}")
                hint = f" (the material has {n_units} viscous unit(s){names})"
        raise tf.error(f"unknown parameter '{name}'{hint}; known: {fmt_list(params)}", key)

    free = f.get("free", [])
    if not isinstance(free, list):
        raise tf.error("'free' must be a list of parameter names", "fit.free")
    for name in free:
        check_name(name, "fit.free")
    dup = sorted({n for n in free if free.count(n) > 1})
    if dup:
        raise tf.error(f"duplicate free parameter(s) {fmt_list(dup)}", "fit.free")

    bounds = {}
    for name, b in tf.table(f.get("bounds", {}), "fit.bounds").items():
        key = f"fit.bounds.{name}"
        check_name(name, key)
        if not (isinstance(b, list) and len(b) == 2 and all(is_number(x) for x in b)):
            raise tf.error(f"bounds of '{name}' must be [lower, upper] numbers, got {b!r}", key)
        lo, hi = float(b[0]), float(b[1])
        if math.isnan(lo) or math.isnan(hi) or not lo < hi:
            raise tf.error(f"bounds of '{name}' need lower < upper, got [{lo:g}, {hi:g}]", key)
        v = params[name]
        if not lo <= v <= hi:
            raise tf.error(f"initial value {name} = {v:g} lies outside its bounds [{lo:g}, {hi:g}]", key)
        bounds[name] = (lo, hi)

    result = {}
    for name, entry in tf.table(f.get("result", {}), "fit.result").items():
        key = f"fit.result.{name}"
        check_name(name, key)
        result[name] = _fit_result_entry(tf, tf.table(entry, key), key)

    options = {}
    for k, v in f.items():
        if k in ("free", "bounds", "result"):
            continue
        key = f"fit.{k}"
        if k == "scale":
            if v not in ("log", "linear"):
                raise tf.error(f"'scale' must be \"log\" or \"linear\", got {v!r}", key)
        elif k == "optimizer":
            if v not in OPTIMIZERS:
                raise tf.error(f"'optimizer' must be one of {', '.join(map(repr, OPTIMIZERS))}, got {v!r}", key)
        elif k == "loss":
            if not isinstance(v, str):
                raise tf.error(f"'{k}' must be a string, got {v!r}", key)
        elif k == "features":
            if not (isinstance(v, list) and all(isinstance(x, str) for x in v)):
                raise tf.error("'features' must be a list of strings", key)
            v = tuple(v)
        elif k == "weights":
            w = tf.table(v, key)
            for name, x in w.items():
                if not is_number(x) or x < 0:
                    raise tf.error(f"weight '{name}' must be a number >= 0, got {x!r}", f"{key}.{name}")
            v = {name: float(x) for name, x in w.items()}
        elif k == "max_iter":
            v = tf.number(f, k, "fit", lower=0, integer=True)
        elif k in ("tol", "learning_rate"):
            v = tf.number(f, k, "fit", lower=0.0)
        options[k] = v
    return FitSpec(free=tuple(free), bounds=bounds, options=options, result=result)


def _fit_result_entry(tf: _Toml, entry: dict, key: str) -> dict:
    """One parameter's ``[fit.result]`` table, its keys and types checked (``FIT_RESULT_KEYS``)."""
    tf.check_keys(entry, FIT_RESULT_KEYS, key)
    for k, v in entry.items():
        kind = FIT_RESULT_KEYS[k]
        if (kind == "number" and not is_number(v)) or (kind == "string" and not isinstance(v, str)):
            raise tf.error(f"'{k}' must be a {kind}, got {v!r}", f"{key}.{k}")
    return {k: float(v) if FIT_RESULT_KEYS[k] == "number" else v for k, v in entry.items()}


def _load_traces(tf: _Toml, doc, scenario) -> tuple[Trace, ...]:
    traces_doc = doc["traces"]
    if not isinstance(traces_doc, list) or not traces_doc:
        raise tf.error("'traces' must be one or more [[traces]] tables", "traces")
    traces = []
    names = set()
    for i, t in tf.array_of_tables(traces_doc, TRACE_KEYS, "traces", "[[traces]] table"):
        if "file" not in t:
            raise tf.error(f"[[traces]] #{i} lacks 'file'", "traces")
        if not isinstance(t["file"], str):
            raise tf.error(f"'file' must be a string path, got {t['file']!r}", "traces.file")
        csv_path = (tf.path.parent / t["file"])
        if not csv_path.is_file():
            raise tf.error(f"[[traces]] #{i}: trace file '{t['file']}' not found (looked for {csv_path})",
                           "traces.file")
        role = t.get("role", "fit")
        if role not in ROLES:
            raise tf.error(f"unknown role '{role}'{suggest(role, ROLES)}; known: {fmt_list(ROLES)}", "traces.role")
        name = t.get("name", Path(t["file"]).stem)
        if not isinstance(name, str) or not name:
            raise tf.error("'name' must be a non-empty string", "traces.name")
        if name in names:
            raise tf.error(f"duplicate trace name '{name}' (give each [[traces]] a unique 'name')", "traces.name")
        names.add(name)
        conditions = tf.table(t.get("conditions", {}), "traces.conditions")
        for k, v in conditions.items():
            if not (is_number(v) or isinstance(v, (str, bool))):
                raise tf.error(f"condition '{k}' must be a number, string or boolean, got {v!r}",
                               f"traces.conditions.{k}")
        columns = t.get("columns")
        if columns is not None:
            columns = tf.table(columns, "traces.columns")
        units = tf.table(t.get("units", {}), "traces.units")
        loading = t.get("loading")
        if loading is not None:
            loading = check_loading(dict(tf.table(loading, "traces.loading")), tf.path,
                                     "traces.loading")
            for k in ("freq", "phi_max"):
                if k in loading and k in conditions and is_number(conditions[k]) and not math.isclose(
                        loading[k], conditions[k], rel_tol=1e-12):
                    raise tf.error(f"[[traces]] #{i}: loading {k} = {loading[k]:g} disagrees with "
                                   f"conditions {k} = {conditions[k]:g}", f"traces.loading.{k}")
        weight = t.get("weight", 1.0)
        if not is_number(weight) or weight < 0:
            raise tf.error(f"'weight' must be a number >= 0, got {weight!r}", "traces.weight")
        required = TRACE_REQUIRED[scenario]
        try:
            tr = load_trace_csv(csv_path, columns, units, role=role, conditions=conditions, loading=loading,
                                name=name, weight=weight, required=required)
        except DataError as e:  # name the TOML too: the mapping or the file comes from it
            err = DataError(f"{e} (trace file of [[traces]] #{i} in {tf.path})")
            err.file, err.row, err.column, err.key, err.line = e.file, e.row, e.column, e.key, e.line
            raise err from None
        if scenario in DYNAMIC_SCENARIOS:
            responses = [ch for ch in tr.channels if ch != "voltage"]
            if not responses:
                raise DataError(f"no response channel (e.g. displacement, angle) mapped for scenario "
                                f"'{scenario}'; mapped: {fmt_list(tr.columns)}", file=csv_path)
            if "voltage" not in tr.channels and tr.loading is None:
                raise tf.error(f"[[traces]] #{i} ('{name}'): no voltage column and no 'loading' table; "
                               f"give one of them", "traces")
        traces.append(tr)
    return tuple(traces)
