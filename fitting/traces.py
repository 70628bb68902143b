"""Measured traces: the ``Trace`` record (SI units), the CSV reader ``load_trace_csv`` and
``from_samples`` (a trace known by its samples alone).

One record serves every consumer: an experiment file's traces (``fitting.data``), the
traces a fit compares with its forward model (``fitting.fit``, built by
``fitting.experiment``: the response at the observation times and the forward's
``data``) and the traces of a gap diagnosis (``fitting.diagnose``: the response channel
and the commanded voltage history)."""
from __future__ import annotations

import csv
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from .schema import DataError, check_loading, fmt_list, loading_voltage, suggest
from .units import CHANNELS, SI_UNIT, to_si

__all__ = ["Trace", "load_trace_csv", "from_samples"]


@dataclass(frozen=True, eq=False)
class Trace:
    """One measured (or simulated) trace, in SI units.

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
      columns, units: the CSV headers and units the channels came from (for a channel
        that is not one of ``CHANNELS``: the unit of its values).
      response: the channel a model is compared with (``y``), or None.
      against: the channel ``y`` is plotted against in loop plots (``x``), or None.
      data: the pytree a fit's forward model simulates the trace from (time grid,
        histories, observation times), or None.
      scale: a fit's normalization of the residual; None: the amplitude of ``y`` (see ``norm``).
      labels: channel -> axis label of plots (default: the channel's name).

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
    response: str | None = None
    against: str | None = None
    data: Any = None
    scale: float | None = None
    labels: Mapping[str, str] = field(default_factory=dict)

    def __getitem__(self, channel: str) -> np.ndarray:
        if channel == "time" and self.time is not None:
            return self.time
        try:
            return self.channels[channel]
        except KeyError:
            have = (["time"] if self.time is not None else []) + list(self.channels)
            raise KeyError(f"trace '{self.name}' has no channel '{channel}'; it has {fmt_list(have)}") from None

    def __contains__(self, channel: str) -> bool:
        return (channel == "time" and self.time is not None) or channel in self.channels

    def __len__(self) -> int:
        if self.time is not None:
            return int(self.time.shape[0])
        return int(next(iter(self.channels.values())).shape[0]) if self.channels else 0

    @property
    def t(self) -> np.ndarray | None:
        """The time (s), as fits and diagnoses name it."""
        return self.time

    @property
    def y(self) -> np.ndarray:
        """The response channel (what a model is compared with), as floats."""
        if self.response is None:
            raise ValueError(f"trace '{self.name}': no response channel chosen (channels: {fmt_list(self.channels)})")
        return np.asarray(self[self.response], dtype=float)

    @property
    def x(self) -> np.ndarray | None:
        """The channel ``y`` is plotted against in loops, or None."""
        return None if self.against is None else self.channels[self.against]

    @property
    def norm(self) -> float:
        """A fit's normalization of the residual: ``scale`` if given, else the amplitude of
        ``y`` (peak to peak, else max |y|, else 1)."""
        if self.scale is not None:
            return float(self.scale)
        amp = float(np.ptp(self.y))
        return amp if amp > 0 else float(np.max(np.abs(self.y))) or 1.0

    @property
    def unit(self) -> str:
        """The unit of ``y``: the SI unit of a known channel ("1" if dimensionless), else the
        unit given in ``units`` ("" if none)."""
        if self.response in CHANNELS:
            si = SI_UNIT[CHANNELS[self.response]]
            return "1" if si == "-" else si
        return self.units.get(self.response, "")

    def label(self, channel: str) -> str:
        """The axis label of ``channel`` in plots."""
        return self.labels.get(channel, channel)

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

    @property
    def voltage_history(self):
        """The commanded voltage history (t -> V, a ``dejax.loads`` history): the measured
        ``voltage`` channel, linear between the samples, else the ``loading`` table, else None."""
        from dejax import loads

        if "voltage" in self.channels:
            return loads.PiecewiseLinear(self.time, self.channels["voltage"])
        return None if self.loading is None else loads.from_spec(self.loading)

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


def from_samples(name: str, y, data=None, t=None, x=None, weight: float = 1.0, scale: float | None = None,
                 ylabel: str = "y", xlabel: str = "x", unit: str = "") -> Trace:
    """A trace known by its samples alone (fit's ``Target``): ``y`` (n,) the values a model
    fed ``data`` predicts, at times ``t`` (s, or None), plotted against ``x`` in loops;
    ``weight``, ``scale`` as in ``Trace``; ``ylabel``, ``xlabel`` the axis labels; ``unit``
    the unit of ``y`` (SI, "1" = dimensionless)."""
    channels = {"y": np.asarray(y, dtype=float)}
    if x is not None:
        channels["x"] = x
    return Trace(time=t, channels=channels, name=name, weight=weight, units={"y": unit} if unit else {},
                 response="y", against=None if x is None else "x", data=data, scale=scale,
                 labels={"y": ylabel, "x": xlabel})


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



def _check_channel_strings(mapping: dict, allowed, key: str, what: str, path, unknown) -> None:
    """Every key of ``mapping`` (channel -> string) is in ``allowed`` (else DataError
    ``unknown(channel)``) and maps to a string (else DataError naming ``what``)."""
    for ch, v in mapping.items():
        if ch not in allowed:
            raise DataError(unknown(ch), file=path, key=f"{key}.{ch}")
        if not isinstance(v, str):
            raise DataError(f"{what} for channel '{ch}' must be a string, got {v!r}", file=path, key=f"{key}.{ch}")

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
        raise DataError(f"duplicate header(s) {fmt_list(dup)}", file=path, row=1, line=hline)
    if len(records) < 2:
        raise DataError(f"no data rows after the header ({fmt_list(header)})", file=path, row=1, line=hline)

    if columns is None:
        columns = {h: h for h in header if h in CHANNELS}
        if not columns:
            raise DataError(
                f"no column mapping given and no header is a channel name; present columns: "
                f"{fmt_list(header)}; channels: {fmt_list(CHANNELS)}", file=path, row=1, line=hline)
    columns = dict(columns)
    units = dict(units or {})
    _check_channel_strings(columns, CHANNELS, "columns", "column name", path,
                           lambda ch: f"unknown channel '{ch}'{suggest(ch, CHANNELS)}; known channels: "
                                      f"{fmt_list(CHANNELS)}")
    _check_channel_strings(units, columns, "units", "unit", path,
                           lambda ch: f"unit given for channel '{ch}', which is not among the mapped columns "
                                      f"({fmt_list(columns)})")
    for ch in units:
        to_si([], units[ch], ch, file=path)  # validates the unit
    missing_ch = [ch for ch in required if ch not in columns]
    if missing_ch:
        raise DataError(f"required channel(s) {fmt_list(missing_ch)} not mapped; mapped: "
                        f"{fmt_list(columns)}; present columns: {fmt_list(header)}", file=path)
    index = {}
    for ch, col in columns.items():
        if col not in header:
            raise DataError(f"column '{col}' (channel '{ch}') not found{suggest(col, header)}; "
                            f"present columns: {fmt_list(header)}", file=path, row=1, line=hline,
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
        loading = check_loading(dict(loading), path, "loading")
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
