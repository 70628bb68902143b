"""Loaders for the measured VHB curves shipped under ``data/`` (see data/README.md).

Everything is returned in SI: stretch (-), nominal (first Piola-Kirchhoff)
stress (Pa), time (s), temperature (K), voltage (V), stretch rate (1/s).

VHB 4910, Hossain, Vu and Steinmann (2012), digitized by the vCANN project
---------------------------------------------------------------------------
``hossain2012_curves()`` lists the available ``(peak_stretch, rate)`` pairs
(11: peak 1.5, 2.0, 2.5, 3.0 at 0.01, 0.03, 0.05 1/s, except 3.0 at 0.03).
``load_hossain2012(peak_stretch, rate)`` returns a ``UniaxialCurve(time,
stretch, stress)``. The files hold stretch and stress (kPa) only, loading
then unloading, each branch monotonic in stretch; time is reconstructed from
the constant stretch rate: ``t = (lam - lam_0) / rate`` while loading (lam_0 =
1 exactly in all files, so this is the README's ``(lam - 1) / rate``), then
``t = t_peak + (lam_peak - lam) / rate`` while unloading. The unloading
branch ends where the digitized stress reaches about zero, at a residual
stretch of 1.12 to 1.36, not at lam = 1.

VHB 4905, collected by the HyperCalibration.jl project
------------------------------------------------------
``vhb4905_sets()`` lists the sets; ``load_vhb4905(set_name)`` returns a list
of curves, one dict per curve id, in file order, with keys

* ``id`` (int), ``description`` (str), ``set`` (str, e.g. "set4_loading"),
* ``temp`` (K), ``voltage`` (V, or None when the set has no voltage column,
  i.e. a purely mechanical test), ``rate`` (stretch rate 1/s, or None for
  the relaxation set),
* ``stretch`` (n,), ``stress`` (n,) in Pa, ``time`` (n,) in s,
* ``time_reconstructed`` (bool): True when the file has no time column and
  ``time`` was rebuilt from the constant stretch rate as for Hossain's curves
  (from the first digitized point ``lam_0``, which may differ from 1 by
  digitizing error), False when the time was recorded (relaxation set),
* ``peak_stretch`` (float).

``set_name`` is ``"set3_relaxation"``, ``"set4_loading"`` or ``"set6_coupled"``
(or just ``"set3"``, ``"set4"``, ``"set6"``). The files are semicolon-separated
with decimal commas. Despite the README's "Latin-1", only set6 is Latin-1
(degree sign written as the byte 0xBA, "º"); set3 and set4 are UTF-8 in which
the degree sign was already lost (U+FFFD). Both are decoded and the
description's degree sign is restored as "°".

Oddities of the data (kept as they are, not corrected):

* set4 ids 104 and 105 are described as "0°C, 0.1s-1, 100%" like id 103, but
  reach stretch 3 and 4 (200 % and 300 %), so their descriptions are wrong.
* set4 id 102's description writes "0,1s-1" (decimal comma); rate is 0.1.
* Loading-unloading curves in set4 and set6 are monotonic in stretch on each
  branch; unloading ends at a residual stretch (1.19 to 2.46 in set4) where
  the stress is about zero. Digitizing noise makes some first stretches
  slightly below 1 (down to 0.987, id 102) and some stresses slightly
  negative (down to -44 kPa against a 1.5 MPa peak, id 112 at -20 °C).
* set3 gives stress at 900 s intervals from 900 s to 11,700 s; the ramp
  and the instantaneous stress are not included. Its stresses are quantized
  (steps of about 0.46 kPa in id 101, one step up at 10,800 s) and fall by
  35 % (id 101) to 14 % (id 104) between 900 s and 1800 s, about as much as or
  more than over the remaining 2.75 hours: check the time origin before using
  the early points.
"""
from __future__ import annotations

import csv
import os
import re
from pathlib import Path
from typing import NamedTuple

import numpy as np

from .schema import DataError

__all__ = [
    "data_dir",
    "UniaxialCurve",
    "hossain2012_curves",
    "load_hossain2012",
    "vhb4905_sets",
    "load_vhb4905",
    "reconstruct_time",
]

HOSSAIN_DIR = "vhb4910-hossain2012"
VHB4905_DIR = "vhb4905-electromechanical"
VHB4905_SETS = ("set3_relaxation", "set4_loading", "set6_coupled")


def data_dir() -> Path:
    """The project's ``data/`` folder (override with the environment variable
    ``DEJAX_DATA_DIR``)."""
    env = os.environ.get("DEJAX_DATA_DIR")
    return Path(env) if env else Path(__file__).resolve().parents[1] / "data"


class UniaxialCurve(NamedTuple):
    """A uniaxial loading-unloading curve: time (s), stretch (-), nominal stress (Pa)."""

    time: np.ndarray
    stretch: np.ndarray
    stress: np.ndarray


def reconstruct_time(stretch, rate: float) -> np.ndarray:
    """Time (s) of a loading-unloading test at constant stretch rate ``rate`` (1/s).

    Loading (up to the peak stretch): ``t = (lam - lam_0) / rate``; unloading:
    ``t = t_peak + (lam_peak - lam) / rate``. Digitizing noise that would make
    the time go backwards is removed by a running maximum, so the result is
    non-decreasing.
    """
    lam = np.asarray(stretch, dtype=float)
    if lam.ndim != 1 or lam.size == 0:
        raise ValueError(f"reconstruct_time: stretch must be a non-empty 1-D array, got shape {lam.shape}")
    if not rate > 0:
        raise ValueError(f"reconstruct_time: rate = {rate} 1/s must be > 0")
    i = int(np.argmax(lam))
    t = np.empty_like(lam)
    t[: i + 1] = (lam[: i + 1] - lam[0]) / rate
    t[i + 1 :] = t[i] + (lam[i] - lam[i + 1 :]) / rate
    return np.maximum.accumulate(t)


# ---------------------------------------------------------------------------
# Hossain et al. (2012), VHB 4910
# ---------------------------------------------------------------------------


def hossain2012_curves() -> list[tuple[float, float]]:
    """Available ``(peak_stretch, rate)`` pairs (rate in 1/s), sorted."""
    root = data_dir() / HOSSAIN_DIR
    if not root.is_dir():
        raise DataError("Hossain 2012 data folder not found", file=root)
    out = []
    for d in root.iterdir():
        m = re.fullmatch(r"stretch_(\d+(?:\.\d+)?)", d.name)
        if not (m and d.is_dir()):
            continue
        for f in d.glob("*.txt"):
            try:
                out.append((float(m.group(1)), float(f.stem)))
            except ValueError:
                continue
    return sorted(out)


def _read_two_columns(path: Path) -> np.ndarray:
    rows = []
    for i, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
        if not line.strip():
            continue
        cells = [c.strip() for c in line.split(",")]
        if len(cells) != 2:
            raise DataError(f"expected 2 comma-separated values, found {len(cells)}", file=path, row=i)
        try:
            rows.append([float(c) for c in cells])
        except ValueError:
            raise DataError(f"cannot parse '{line.strip()}' as two numbers", file=path, row=i) from None
    a = np.asarray(rows, dtype=float)
    if a.size == 0:
        raise DataError("empty file", file=path)
    if not np.all(np.isfinite(a)):
        raise DataError("non-finite value", file=path)
    return a


def load_hossain2012(peak_stretch: float, rate: float) -> UniaxialCurve:
    """One VHB 4910 loading-unloading curve of Hossain et al. (2012).

    Args:
      peak_stretch: 1.5, 2.0, 2.5 or 3.0 (the folder value).
      rate: stretch rate |d lam / dt| in 1/s: 0.01, 0.03 or 0.05.

    Returns ``UniaxialCurve(time, stretch, stress)``: time in s (reconstructed,
    see the module docstring, non-decreasing, starting at 0), stretch (-),
    nominal stress in Pa (the file's kPa times 1000); 88 to 128 points.
    """
    available = hossain2012_curves()
    match = [c for c in available if abs(c[0] - peak_stretch) < 1e-9 and abs(c[1] - rate) < 1e-12]
    if not match:
        raise DataError(
            f"no Hossain 2012 curve for peak stretch {peak_stretch} at rate {rate} 1/s; available "
            f"(peak, rate): {', '.join(f'({p:g}, {r:g})' for p, r in available)}",
            file=data_dir() / HOSSAIN_DIR,
        )
    peak, r = match[0]
    folder = data_dir() / HOSSAIN_DIR / f"stretch_{peak:.1f}"
    path = next(f for f in folder.glob("*.txt") if float(f.stem) == r)
    a = _read_two_columns(path)
    lam, stress = a[:, 0], a[:, 1] * 1e3
    return UniaxialCurve(time=reconstruct_time(lam, r), stretch=lam, stress=stress)


# ---------------------------------------------------------------------------
# VHB 4905 sets (HyperCalibration.jl)
# ---------------------------------------------------------------------------


def vhb4905_sets() -> tuple[str, ...]:
    """Names of the VHB 4905 sets."""
    return VHB4905_SETS


def _decode(raw: bytes) -> str:
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        text = raw.decode("latin-1")
    # the degree sign: lost (U+FFFD) in the UTF-8 files, 'º' (0xBA) in the Latin-1 one
    return text.replace("\ufffd", "°").replace("º", "°")


def _decimal(text: str, path, row, column) -> float:
    s = text.strip().replace(",", ".")
    try:
        v = float(s)
    except ValueError:
        raise DataError(f"cannot parse '{text}' as a number", file=path, row=row, column=column) from None
    if not np.isfinite(v):
        raise DataError(f"non-finite value '{text}'", file=path, row=row, column=column)
    return v


def load_vhb4905(set_name: str) -> list[dict]:
    """Curves of one VHB 4905 set, one dict per curve id (see the module docstring)."""
    name = {s.split("_")[0]: s for s in VHB4905_SETS}.get(set_name, set_name)
    if name not in VHB4905_SETS:
        raise DataError(f"unknown VHB 4905 set '{set_name}'; known: {', '.join(VHB4905_SETS)} "
                        f"(or set3, set4, set6)")
    path = data_dir() / VHB4905_DIR / f"{name}.csv"
    if not path.is_file():
        raise DataError("file not found", file=path)
    rows = list(csv.reader(_decode(path.read_bytes()).splitlines(), delimiter=";"))
    if not rows:
        raise DataError("empty file", file=path)
    header = [h.strip() for h in rows[0]]
    need = {"id", "description", "temp", "stretch", "stress"}
    missing = need - set(header)
    if missing:
        raise DataError(f"missing column(s) {', '.join(sorted(missing))}; present: {', '.join(header)}",
                        file=path, row=1)
    col = {h: j for j, h in enumerate(header)}
    numeric = [h for h in header if h != "description"]
    curves: dict[int, dict] = {}
    for r, cells in enumerate(rows[1:], start=2):
        if not any(c.strip() for c in cells):
            continue
        if len(cells) != len(header):
            raise DataError(f"expected {len(header)} fields, found {len(cells)}", file=path, row=r)
        vals = {h: _decimal(cells[col[h]], path, r, h) for h in numeric}
        cid = int(vals["id"])
        c = curves.get(cid)
        if c is None:
            c = curves[cid] = {
                "id": cid,
                "description": cells[col["description"]].strip(),
                "set": name,
                "temp": vals["temp"],
                "voltage": vals.get("voltage"),
                "rate": vals.get("vel"),
                "_stretch": [], "_stress": [], "_time": [],
            }
        else:
            for key, h in (("temp", "temp"), ("voltage", "voltage"), ("rate", "vel")):
                if h in vals and vals[h] != c[key]:
                    raise DataError(f"curve {cid}: {h} changes within the curve ({c[key]} -> {vals[h]})",
                                    file=path, row=r, column=h)
        c["_stretch"].append(vals["stretch"])
        c["_stress"].append(vals["stress"])
        if "time" in vals:
            c["_time"].append(vals["time"])
    out = []
    for c in curves.values():
        lam = np.asarray(c.pop("_stretch"))
        stress = np.asarray(c.pop("_stress"))
        time = c.pop("_time")
        if time:
            c["time"] = np.asarray(time)
            c["time_reconstructed"] = False
        elif c["rate"] is not None:
            c["time"] = reconstruct_time(lam, c["rate"])
            c["time_reconstructed"] = True
        else:  # pragma: no cover - no such set
            c["time"] = None
            c["time_reconstructed"] = False
        c["stretch"] = lam
        c["stress"] = stress
        c["peak_stretch"] = float(lam.max())
        out.append(c)
    return out
