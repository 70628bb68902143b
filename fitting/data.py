'''Experiment files: one TOML file plus CSV traces describe an experiment.

The same file drives ``dejax run`` (simulate the experiment), ``dejax fit``
(identify the free parameters from the ``fit`` traces) and ``dejax diagnose``
(compare with the ``holdout`` traces and try candidate effects). Everything is
SI (m, kg, s, Pa, V, F/m) once loaded; CSV columns may carry other units,
declared per trace and converted on loading. A user's guide with every key, its unit,
its default and the verb that reads it: ``docs/experiment-format.md``.

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
the allowed ones. The allowed sets are the module constants ``SECTIONS``,
``EXPERIMENT_KEYS``, ``GEOMETRY_KEYS`` (per scenario), ``MATERIAL_KEYS``,
``UNIT_KEYS``, ``FIT_KEYS``, ``SOLVER_KEYS``, ``TRACE_KEYS``, ``LOADING_KINDS``;
extend them there when a new option is implemented.

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
``learning_rate`` (number > 0).

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

import csv
import difflib
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from dejax import parameters as mp

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10: the tomli backport (a dependency there)
    import tomli as tomllib

__all__ = [
    "DataError",
    "Trace",
    "FitSpec",
    "Experiment",
    "load_experiment",
    "load_trace_csv",
    "loading_voltage",
    "to_si",
    "SCENARIOS",
    "CHANNELS",
    "UNITS",
    "LOADING_KINDS",
]


# ---------------------------------------------------------------------------
# schema constants
# ---------------------------------------------------------------------------

SCENARIOS = ("block", "rolled", "torsional", "uniaxial")
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
    "block": (),  # L or lx, ly, lz: checked separately
    "rolled": ("h", "r", "L"),
    "torsional": ("L", "W", "h"),
    "uniaxial": (),
}
MATERIAL_KEYS = ("mu_inf", "K_inf", "Jm_inf", "eps", "rho", "units")
MATERIAL_SCALARS = mp.SCALARS  # the TOML keys are the parameter names (dejax.parameters)
UNIT_KEYS = mp.UNIT_KEYS
# lower bound and whether it is strict, for the material parameters
_POSITIVE = {"mu_inf": True, "K_inf": False, "Jm_inf": True, "eps": False, "rho": True,
             "mu": True, "K": False, "Jm": True, "eta": True}
FIT_KEYS = ("free", "bounds", "scale", "loss", "features", "weights", "optimizer", "max_iter",
            "tol", "learning_rate")
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

# channel -> physical quantity
CHANNELS = {
    "time": "time",
    "displacement": "length",
    "velocity": "velocity",
    "voltage": "voltage",
    "field": "field",
    "stretch": "dimensionless",
    "strain": "dimensionless",
    "stress": "pressure",
    "force": "force",
    "angle": "angle",
    "charge": "charge",
    "current": "current",
    "temperature": "temperature",
}
SI_UNIT = {
    "time": "s", "length": "m", "velocity": "m/s", "voltage": "V", "field": "V/m",
    "dimensionless": "-", "pressure": "Pa", "force": "N", "angle": "rad", "charge": "C",
    "current": "A", "temperature": "K",
}
# quantity -> unit -> (scale, offset): SI value = scale * value + offset
UNITS: dict[str, dict[str, tuple[float, float]]] = {
    "time": {"s": (1.0, 0.0), "ms": (1e-3, 0.0), "us": (1e-6, 0.0), "µs": (1e-6, 0.0),
             "min": (60.0, 0.0), "h": (3600.0, 0.0)},
    "length": {"m": (1.0, 0.0), "cm": (1e-2, 0.0), "mm": (1e-3, 0.0), "um": (1e-6, 0.0),
               "µm": (1e-6, 0.0), "nm": (1e-9, 0.0)},
    "velocity": {"m/s": (1.0, 0.0), "cm/s": (1e-2, 0.0), "mm/s": (1e-3, 0.0), "um/s": (1e-6, 0.0)},
    "voltage": {"V": (1.0, 0.0), "mV": (1e-3, 0.0), "kV": (1e3, 0.0), "MV": (1e6, 0.0)},
    "field": {"V/m": (1.0, 0.0), "kV/m": (1e3, 0.0), "V/mm": (1e3, 0.0), "MV/m": (1e6, 0.0),
              "kV/mm": (1e6, 0.0), "V/um": (1e6, 0.0)},
    "dimensionless": {"-": (1.0, 0.0), "1": (1.0, 0.0), "%": (1e-2, 0.0)},
    "pressure": {"Pa": (1.0, 0.0), "kPa": (1e3, 0.0), "MPa": (1e6, 0.0), "GPa": (1e9, 0.0),
                 "N/mm^2": (1e6, 0.0), "N/mm2": (1e6, 0.0)},
    "force": {"N": (1.0, 0.0), "mN": (1e-3, 0.0), "kN": (1e3, 0.0)},
    "angle": {"rad": (1.0, 0.0), "mrad": (1e-3, 0.0), "deg": (math.pi / 180.0, 0.0)},
    "charge": {"C": (1.0, 0.0), "mC": (1e-3, 0.0), "uC": (1e-6, 0.0), "nC": (1e-9, 0.0)},
    "current": {"A": (1.0, 0.0), "mA": (1e-3, 0.0), "uA": (1e-6, 0.0)},
    "temperature": {"K": (1.0, 0.0), "degC": (1.0, 273.15), "°C": (1.0, 273.15)},
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


def _suggest(word: str, options) -> str:
    options = [str(o) for o in options]
    same_case = [o for o in options if o.lower() == str(word).lower()]
    if same_case:
        return f" (did you mean '{same_case[0]}'?)"
    close = difflib.get_close_matches(str(word), options, n=1, cutoff=0.6)
    return f" (did you mean '{close[0]}'?)" if close else ""


def _fmt_list(options) -> str:
    return ", ".join(str(o) for o in options) if options else "(none)"


# ---------------------------------------------------------------------------
# units
# ---------------------------------------------------------------------------


def to_si(values, unit: str, channel: str, *, file=None):
    """Convert ``values`` of ``channel`` given in ``unit`` to SI (numpy array)."""
    quantity = CHANNELS[channel]
    table = UNITS[quantity]
    if unit not in table:
        raise DataError(
            f"unknown unit '{unit}' for channel '{channel}' ({quantity}){_suggest(unit, table)}; "
            f"known units: {_fmt_list(table)}",
            file=file, key=f"units.{channel}",
        )
    scale, offset = table[unit]
    return np.asarray(values, dtype=float) * scale + offset


# ---------------------------------------------------------------------------
# traces
# ---------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Trace:
    """One measured (or simulated) record, in SI units.

    Attributes:
      time: (n,) time in s, strictly increasing, or None (material tests
        without a time column).
      channels: channel name -> (n,) SI array (time excluded), e.g.
        ``displacement`` (m), ``voltage`` (V), ``stretch`` (-), ``stress`` (Pa).
      role: "fit" or "holdout".
      conditions: operating point (freq Hz, phi_max V, temp K, geometry
        overrides, ...), as given.
      source: the CSV file.
      name: unique name within the experiment (default the file's stem).
      loading: nominal voltage history (see ``LOADING_KINDS``) or None.
      weight: relative weight in a fit.
      columns, units: the CSV headers and units the channels came from.

    ``trace["displacement"]`` returns a channel (``trace["time"]`` the time).
    """

    time: np.ndarray | None
    channels: Mapping[str, np.ndarray]
    role: str = "fit"
    conditions: Mapping[str, Any] = field(default_factory=dict)
    source: Path | None = None
    name: str = ""
    loading: Mapping[str, Any] | None = None
    weight: float = 1.0
    columns: Mapping[str, str] = field(default_factory=dict)
    units: Mapping[str, str] = field(default_factory=dict)

    def __getitem__(self, channel: str) -> np.ndarray:
        if channel == "time" and self.time is not None:
            return self.time
        try:
            return self.channels[channel]
        except KeyError:
            have = (["time"] if self.time is not None else []) + list(self.channels)
            raise KeyError(f"trace '{self.name}' has no channel '{channel}'; it has {_fmt_list(have)}") from None

    def __contains__(self, channel: str) -> bool:
        return (channel == "time" and self.time is not None) or channel in self.channels

    def __len__(self) -> int:
        if self.time is not None:
            return int(self.time.shape[0])
        return int(next(iter(self.channels.values())).shape[0]) if self.channels else 0

    @property
    def frequency(self) -> float | None:
        """Excitation frequency (Hz) from ``loading`` or ``conditions``, if any."""
        if self.loading is not None and "freq" in self.loading:
            return float(self.loading["freq"])
        f = self.conditions.get("freq")
        return None if f is None else float(f)

    @property
    def dt(self) -> float | None:
        """Sample spacing (s) if time is uniformly sampled (to 0.1 % of the mean spacing), else None."""
        if self.time is None or self.time.size < 2:
            return None
        d = np.diff(self.time)
        return float(np.mean(d)) if np.ptp(d) <= 1e-3 * np.mean(d) else None

    def voltage(self, t=None):
        """Voltage (V) at ``t`` (default: the trace's time): the measured
        channel if present (interpolated when ``t`` is given), else the nominal
        ``loading``; None if neither exists."""
        if "voltage" in self.channels:
            v = self.channels["voltage"]
            if t is None:
                return v
            if self.time is None:
                raise ValueError(f"trace '{self.name}': no time column to interpolate the voltage on")
            return np.interp(np.asarray(t, dtype=float), self.time, v)
        if self.loading is not None:
            tt = self.time if t is None else t
            if tt is None:
                raise ValueError(f"trace '{self.name}': no time column to evaluate the loading on")
            return loading_voltage(self.loading, tt)
        return None


def _read_lines(path: Path) -> list[str]:
    raw = path.read_bytes()
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        text = raw.decode("latin-1")
    return text.splitlines()


def _parse_cell(text: str, path, row, line, column) -> float:
    s = text.strip()
    if s == "":
        raise DataError("empty cell; expected a number", file=path, row=row, line=line, column=column)
    try:
        val = float(s)
    except ValueError:
        hint = " (decimal comma? use '.' as decimal separator)" if re.fullmatch(r"[-+]?\d+,\d+", s) else ""
        raise DataError(f"cannot parse '{s}' as a number{hint}", file=path, row=row, line=line,
                        column=column) from None
    if not math.isfinite(val):
        raise DataError(f"non-finite value '{s}' (NaN and inf are not allowed)", file=path, row=row,
                        line=line, column=column)
    return val


def load_trace_csv(
    path,
    columns: Mapping[str, str] | None = None,
    units: Mapping[str, str] | None = None,
    *,
    role: str = "fit",
    conditions: Mapping[str, Any] | None = None,
    loading: Mapping[str, Any] | None = None,
    name: str | None = None,
    weight: float = 1.0,
    required: tuple[str, ...] = (),
) -> Trace:
    """Read a comma-separated trace file into a ``Trace`` (SI units).

    Args:
      path: CSV file with one header row; '#' comment lines and blank lines
        are skipped; extra columns are ignored.
      columns: channel -> header (see ``CHANNELS``); default: every header that
        is itself a channel name.
      units: channel -> unit (see ``UNITS``); channels not listed are SI.
      role, conditions, loading, name, weight: stored on the trace (``loading``
        is validated, see ``LOADING_KINDS``).
      required: channels that must be present.

    Raises ``DataError`` naming the file, row (header = 1) and column.
    """
    path = Path(path)
    if not path.is_file():
        raise DataError("file not found" + (" (it is a directory)" if path.is_dir() else ""), file=path)
    lines = _read_lines(path)
    # (row, line, cells) for header and data, skipping comments and blanks
    records = []
    row = 0
    for i, text in enumerate(lines, start=1):
        s = text.strip()
        if not s or s.startswith("#"):
            continue
        row += 1
        cells = next(csv.reader([text], skipinitialspace=True))
        records.append((row, i, [c.strip() for c in cells]))
    if not records:
        raise DataError("empty file: no header row and no data (comment and blank lines only)", file=path)
    _, hline, header = records[0]
    if len(header) == 1 and ";" in header[0]:
        raise DataError(f"header '{header[0]}' looks semicolon-separated; trace files must be "
                        "comma-separated", file=path, row=1, line=hline)
    for j, h in enumerate(header):
        if h == "":
            raise DataError(f"empty header cell (column {j + 1})", file=path, row=1, line=hline)
    dup = sorted({h for h in header if header.count(h) > 1})
    if dup:
        raise DataError(f"duplicate header(s) {_fmt_list(dup)}", file=path, row=1, line=hline)
    if len(records) < 2:
        raise DataError(f"no data rows after the header ({_fmt_list(header)})", file=path, row=1, line=hline)

    if columns is None:
        columns = {h: h for h in header if h in CHANNELS}
        if not columns:
            raise DataError(
                f"no column mapping given and no header is a channel name; present columns: "
                f"{_fmt_list(header)}; channels: {_fmt_list(CHANNELS)}", file=path, row=1, line=hline)
    columns = dict(columns)
    units = dict(units or {})
    for ch in columns:
        if ch not in CHANNELS:
            raise DataError(f"unknown channel '{ch}'{_suggest(ch, CHANNELS)}; known channels: "
                            f"{_fmt_list(CHANNELS)}", file=path, key=f"columns.{ch}")
        if not isinstance(columns[ch], str):
            raise DataError(f"column name for channel '{ch}' must be a string, got {columns[ch]!r}",
                            file=path, key=f"columns.{ch}")
    for ch in units:
        if ch not in columns:
            raise DataError(f"unit given for channel '{ch}', which is not among the mapped columns "
                            f"({_fmt_list(columns)})", file=path, key=f"units.{ch}")
        if not isinstance(units[ch], str):
            raise DataError(f"unit for channel '{ch}' must be a string, got {units[ch]!r}",
                            file=path, key=f"units.{ch}")
        to_si([], units[ch], ch, file=path)  # validates the unit
    missing_ch = [ch for ch in required if ch not in columns]
    if missing_ch:
        raise DataError(f"required channel(s) {_fmt_list(missing_ch)} not mapped; mapped: "
                        f"{_fmt_list(columns)}; present columns: {_fmt_list(header)}", file=path)
    index = {}
    for ch, col in columns.items():
        if col not in header:
            raise DataError(f"column '{col}' (channel '{ch}') not found{_suggest(col, header)}; "
                            f"present columns: {_fmt_list(header)}", file=path, row=1, line=hline,
                            column=col)
        index[ch] = header.index(col)

    data = {ch: np.empty(len(records) - 1) for ch in columns}
    for k, (r, ln, cells) in enumerate(records[1:]):
        if len(cells) != len(header):
            raise DataError(f"expected {len(header)} cells like the header, found {len(cells)}",
                            file=path, row=r, line=ln)
        for ch, j in index.items():
            data[ch][k] = _parse_cell(cells[j], path, r, ln, header[j])

    if "time" in data:  # checked in the file's units (conversion is increasing)
        bad = np.nonzero(np.diff(data["time"]) <= 0)[0]
        if bad.size:
            k = int(bad[0]) + 1
            r, ln, cells = records[1 + k]
            rp, _, cells_p = records[k]
            j = index["time"]
            raise DataError(
                f"time must increase strictly: '{cells[j]}' is not after '{cells_p[j]}' (row {rp})",
                file=path, row=r, line=ln, column=columns["time"])
    out = {}
    for ch, vals in data.items():
        arr = to_si(vals, units[ch], ch, file=path) if ch in units else np.asarray(vals, dtype=float)
        arr.setflags(write=False)
        out[ch] = arr
    time = out.pop("time", None)
    if loading is not None:
        loading = _check_loading(dict(loading), path, "loading")
    return Trace(
        time=time,
        channels=out,
        role=role,
        conditions=dict(conditions or {}),
        source=path,
        name=path.stem if name is None else name,
        loading=loading,
        weight=float(weight),
        columns=columns,
        units={ch: units.get(ch, SI_UNIT[CHANNELS[ch]]) for ch in columns},
    )


# ---------------------------------------------------------------------------
# loading
# ---------------------------------------------------------------------------


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _check_loading(spec: dict, file, key: str) -> dict:
    kind = spec.get("kind")
    if kind is None:
        raise DataError(f"missing 'kind'; one of {_fmt_list(LOADING_KINDS)}", file=file, key=key)
    if kind not in LOADING_KINDS:
        raise DataError(f"unknown loading kind '{kind}'{_suggest(kind, LOADING_KINDS)}; known: "
                        f"{_fmt_list(LOADING_KINDS)}", file=file, key=f"{key}.kind")
    req, opt = LOADING_KINDS[kind]
    allowed = ("kind",) + tuple(req) + tuple(opt)
    for k in spec:
        if k not in allowed:
            raise DataError(f"unknown key '{k}' for loading kind '{kind}'{_suggest(k, allowed)}; "
                            f"allowed: {_fmt_list(allowed)}", file=file, key=f"{key}.{k}")
    for k in req:
        if k not in spec:
            raise DataError(f"loading kind '{kind}' needs '{k}' (required: {_fmt_list(req)})",
                            file=file, key=key)
    out = {"kind": kind}
    for k in tuple(req) + tuple(opt):
        v = spec.get(k, opt.get(k))
        if kind == "piecewise":
            if not (isinstance(v, list) and v and all(_is_number(x) for x in v)):
                raise DataError(f"'{k}' must be a non-empty list of numbers", file=file, key=f"{key}.{k}")
            v = [float(x) for x in v]
        else:
            if not _is_number(v) or not math.isfinite(v):
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


# ---------------------------------------------------------------------------
# experiments
# ---------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class FitSpec:
    """The ``[fit]`` section: free parameter names (in order), their bounds
    (name -> (lower, upper)) and the remaining options as given."""

    free: tuple[str, ...] = ()
    bounds: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    options: Mapping[str, Any] = field(default_factory=dict)


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
        raise KeyError(f"{self.path}: no trace named '{name}'; traces: {_fmt_list(t.name for t in self.traces)}")

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
                raise KeyError(f"unknown material parameter '{k}'{_suggest(k, allowed)}; known: {_fmt_list(allowed)}")
        return mp.material_kwargs({**self.parameters(), **overrides}, self.n_units)


def _parameters(material, geometry, effects) -> dict[str, float]:
    p = {k: float(material[k]) for k in MATERIAL_SCALARS}
    for i, u in enumerate(material["units"]):
        for k in UNIT_KEYS:
            p[f"{k}_{i + 1}"] = float(u[k])
    for k, v in geometry.items():
        if _is_number(v):
            p[f"geometry.{k}"] = float(v)
    for name, params in effects.items():
        for k, v in params.items():
            if _is_number(v):
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

    def check_keys(self, table: dict, allowed, key: str) -> None:
        for k in table:
            if k not in allowed:
                what = f"key '{k}' in [{key}]" if key else f"section [{k}]"
                raise self.error(
                    f"unknown {what}{_suggest(k, allowed)}; allowed: {_fmt_list(allowed)}",
                    f"{key}.{k}" if key else k,
                )

    def number(self, table: dict, k: str, key: str, *, lower=None, strict=True, upper=None,
               integer=False):
        v = table[k]
        full = f"{key}.{k}"
        if integer:
            if not isinstance(v, int) or isinstance(v, bool):
                raise self.error(f"'{k}' must be an integer, got {v!r}", full)
        elif not _is_number(v) or not math.isfinite(v):
            raise self.error(f"'{k}' must be a finite number, got {v!r}", full)
        if lower is not None and (v <= lower if strict else v < lower):
            raise self.error(f"'{k}' = {v} must be {'>' if strict else '>='} {lower}", full)
        if upper is not None and v > upper:
            raise self.error(f"'{k}' = {v} must be <= {upper}", full)
        return int(v) if integer else float(v)


def load_experiment(path) -> Experiment:
    """Load and validate an experiment TOML file and its CSV traces.

    Raises ``DataError`` (file, key or row/column named) on any problem; see
    the module docstring for the schema.
    """
    path = Path(path)
    if not path.is_file():
        raise DataError("experiment file not found", file=path)
    text = path.read_bytes().decode("utf-8-sig", errors="replace")
    if not text.strip():
        raise DataError("empty experiment file", file=path)
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise DataError(f"invalid TOML: {e}", file=path) from None
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
        raise tf.error(f"unknown scenario '{scenario}'{_suggest(scenario, SCENARIOS)}; known: {_fmt_list(SCENARIOS)}",
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
        if scenario == "uniaxial":
            return {}
        raise DataError(f"missing required section [geometry] for scenario '{scenario}' "
                        f"(keys: {_fmt_list(GEOMETRY_KEYS[scenario])})", file=tf.path)
    g = tf.table(doc["geometry"], "geometry")
    allowed = GEOMETRY_KEYS[scenario]
    for k in g:
        if k not in allowed:
            raise tf.error(f"unknown key '{k}' in [geometry] for scenario '{scenario}'{_suggest(k, allowed)}; "
                           f"allowed: {_fmt_list(allowed)}", f"geometry.{k}")
    required = GEOMETRY_REQUIRED[scenario]
    if scenario == "block" and "L" not in g:
        required = ("lx", "ly", "lz")
    for k in required:
        if k not in g:
            raise tf.error(f"missing required key '{k}' for scenario '{scenario}'"
                           + (" (give L, or all of lx, ly, lz)" if scenario == "block" else ""), "geometry")
    out = {}
    for k, v in g.items():
        if k == "mesh":
            if not (isinstance(v, list) and len(v) == 3 and all(isinstance(n, int) and not isinstance(n, bool)
                                                               and n >= 1 for n in v)):
                raise tf.error(f"'mesh' must be a list of three integers >= 1, got {v!r}", "geometry.mesh")
            out[k] = tuple(v)
        elif k == "probe":
            ok = isinstance(v, str) or (isinstance(v, list) and len(v) == 3 and all(_is_number(x) for x in v))
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
            raise tf.error(f"missing required key '{k}' (required: {_fmt_list(MATERIAL_SCALARS)})", "material")
        out[k] = tf.number(m, k, "material", lower=0.0, strict=_POSITIVE[k])
    units = m.get("units", [])
    if not isinstance(units, list):
        raise tf.error("'units' must be an array of tables ([[material.units]])", "material.units")
    out_units = []
    for i, u in enumerate(units):
        key = f"material.units[{i + 1}]"
        if not isinstance(u, dict):
            raise tf.error(f"viscous unit {i + 1} must be a table", "material.units")
        for k in u:
            if k not in UNIT_KEYS:
                raise tf.error(f"unknown key '{k}' in viscous unit {i + 1}{_suggest(k, UNIT_KEYS)}; allowed: "
                               f"{_fmt_list(UNIT_KEYS)}", f"material.units.{k}")
        for k in UNIT_KEYS:
            if k not in u:
                raise tf.error(f"viscous unit {i + 1} lacks '{k}' (required: {_fmt_list(UNIT_KEYS)})",
                               "material.units")
        out_units.append({k: tf.number(u, k, key, lower=0.0, strict=_POSITIVE[k]) for k in UNIT_KEYS})
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
            if _is_number(v):
                if not math.isfinite(v):
                    raise tf.error(f"'{k}' must be finite", f"{key}.{k}")
                params[k] = float(v)
            elif isinstance(v, (str, bool)):
                params[k] = v
            elif isinstance(v, list) and all(_is_number(x) or isinstance(x, str) for x in v):
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
        hint = _suggest(name, params)
        m = re.fullmatch(r"(mu|K|Jm|eta)_(\d+)", name)
        if m:
            i = int(m.group(2))
            if i == 0:
                hint = " (viscous units are numbered from 1)"
            else:
                names = {0: "", 1: f": {m.group(1)}_1"}.get(n_units, f": {m.group(1)}_1..{m.group(1)}_{n_units}")
                hint = f" (the material has {n_units} viscous unit(s){names})"
        raise tf.error(f"unknown parameter '{name}'{hint}; known: {_fmt_list(params)}", key)

    free = f.get("free", [])
    if not isinstance(free, list):
        raise tf.error("'free' must be a list of parameter names", "fit.free")
    for name in free:
        check_name(name, "fit.free")
    dup = sorted({n for n in free if free.count(n) > 1})
    if dup:
        raise tf.error(f"duplicate free parameter(s) {_fmt_list(dup)}", "fit.free")

    bounds = {}
    for name, b in tf.table(f.get("bounds", {}), "fit.bounds").items():
        key = f"fit.bounds.{name}"
        check_name(name, key)
        if not (isinstance(b, list) and len(b) == 2 and all(_is_number(x) for x in b)):
            raise tf.error(f"bounds of '{name}' must be [lower, upper] numbers, got {b!r}", key)
        lo, hi = float(b[0]), float(b[1])
        if math.isnan(lo) or math.isnan(hi) or not lo < hi:
            raise tf.error(f"bounds of '{name}' need lower < upper, got [{lo:g}, {hi:g}]", key)
        v = params[name]
        if not lo <= v <= hi:
            raise tf.error(f"initial value {name} = {v:g} lies outside its bounds [{lo:g}, {hi:g}]", key)
        bounds[name] = (lo, hi)

    options = {}
    for k, v in f.items():
        if k in ("free", "bounds"):
            continue
        key = f"fit.{k}"
        if k == "scale":
            if v not in ("log", "linear"):
                raise tf.error(f"'scale' must be \"log\" or \"linear\", got {v!r}", key)
        elif k in ("loss", "optimizer"):
            if not isinstance(v, str):
                raise tf.error(f"'{k}' must be a string, got {v!r}", key)
        elif k == "features":
            if not (isinstance(v, list) and all(isinstance(x, str) for x in v)):
                raise tf.error("'features' must be a list of strings", key)
            v = tuple(v)
        elif k == "weights":
            w = tf.table(v, key)
            for name, x in w.items():
                if not _is_number(x) or x < 0:
                    raise tf.error(f"weight '{name}' must be a number >= 0, got {x!r}", f"{key}.{name}")
            v = {name: float(x) for name, x in w.items()}
        elif k == "max_iter":
            v = tf.number(f, k, "fit", lower=0, integer=True)
        elif k in ("tol", "learning_rate"):
            v = tf.number(f, k, "fit", lower=0.0)
        options[k] = v
    return FitSpec(free=tuple(free), bounds=bounds, options=options)


def _load_traces(tf: _Toml, doc, scenario) -> tuple[Trace, ...]:
    traces_doc = doc["traces"]
    if not isinstance(traces_doc, list) or not traces_doc:
        raise tf.error("'traces' must be one or more [[traces]] tables", "traces")
    traces = []
    names = set()
    for i, t in enumerate(traces_doc):
        key = f"traces[{i + 1}]"
        if not isinstance(t, dict):
            raise tf.error(f"trace {i + 1} must be a table", "traces")
        for k in t:
            if k not in TRACE_KEYS:
                raise tf.error(f"unknown key '{k}' in [[traces]] #{i + 1}{_suggest(k, TRACE_KEYS)}; allowed: "
                               f"{_fmt_list(TRACE_KEYS)}", f"traces.{k}")
        if "file" not in t:
            raise tf.error(f"[[traces]] #{i + 1} lacks 'file'", "traces")
        if not isinstance(t["file"], str):
            raise tf.error(f"'file' must be a string path, got {t['file']!r}", "traces.file")
        csv_path = (tf.path.parent / t["file"])
        if not csv_path.is_file():
            raise tf.error(f"[[traces]] #{i + 1}: trace file '{t['file']}' not found (looked for {csv_path})",
                           "traces.file")
        role = t.get("role", "fit")
        if role not in ROLES:
            raise tf.error(f"unknown role '{role}'{_suggest(role, ROLES)}; known: {_fmt_list(ROLES)}", "traces.role")
        name = t.get("name", Path(t["file"]).stem)
        if not isinstance(name, str) or not name:
            raise tf.error("'name' must be a non-empty string", "traces.name")
        if name in names:
            raise tf.error(f"duplicate trace name '{name}' (give each [[traces]] a unique 'name')", "traces.name")
        names.add(name)
        conditions = tf.table(t.get("conditions", {}), f"traces.conditions")
        for k, v in conditions.items():
            if not (_is_number(v) or isinstance(v, (str, bool))):
                raise tf.error(f"condition '{k}' must be a number, string or boolean, got {v!r}",
                               f"traces.conditions.{k}")
        columns = t.get("columns")
        if columns is not None:
            columns = tf.table(columns, "traces.columns")
        units = tf.table(t.get("units", {}), "traces.units")
        loading = t.get("loading")
        if loading is not None:
            loading = _check_loading(dict(tf.table(loading, "traces.loading")), tf.path,
                                     f"traces.loading")
            for k in ("freq", "phi_max"):
                if k in loading and k in conditions and _is_number(conditions[k]) and not math.isclose(
                        loading[k], conditions[k], rel_tol=1e-12):
                    raise tf.error(f"[[traces]] #{i + 1}: loading {k} = {loading[k]:g} disagrees with "
                                   f"conditions {k} = {conditions[k]:g}", f"traces.loading.{k}")
        weight = t.get("weight", 1.0)
        if not _is_number(weight) or weight < 0:
            raise tf.error(f"'weight' must be a number >= 0, got {weight!r}", "traces.weight")
        required = ("stretch", "stress") if scenario == "uniaxial" else ("time",)
        try:
            tr = load_trace_csv(csv_path, columns, units, role=role, conditions=conditions, loading=loading,
                                name=name, weight=weight, required=required)
        except DataError as e:  # name the TOML too: the mapping or the file comes from it
            err = DataError(f"{e} (trace file of [[traces]] #{i + 1} in {tf.path})")
            err.file, err.row, err.column, err.key, err.line = e.file, e.row, e.column, e.key, e.line
            raise err from None
        if scenario in DYNAMIC_SCENARIOS:
            responses = [ch for ch in tr.channels if ch != "voltage"]
            if not responses:
                raise DataError(f"no response channel (e.g. displacement, angle) mapped for scenario "
                                f"'{scenario}'; mapped: {_fmt_list(tr.columns)}", file=csv_path)
            if "voltage" not in tr.channels and tr.loading is None:
                raise tf.error(f"[[traces]] #{i + 1} ('{name}'): no voltage column and no 'loading' table; "
                               f"give one of them", "traces")
        traces.append(tr)
    return tuple(traces)
