"""Channels of a trace, their physical quantities and SI units, and unit conversion.

``CHANNELS``: channel -> quantity; ``SI_UNIT``: quantity -> SI unit; ``UNITS``: quantity ->
accepted unit -> (scale, offset) with SI value = scale * value + offset; ``to_si`` converts.
"""
from __future__ import annotations

import math

import numpy as np

from .schema import DataError, fmt_list, suggest

__all__ = ["CHANNELS", "SI_UNIT", "UNITS", "to_si"]

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


def to_si(values, unit: str, channel: str, *, file=None):
    """Convert ``values`` of ``channel`` given in ``unit`` to SI (numpy array)."""
    quantity = CHANNELS[channel]
    table = UNITS[quantity]
    if unit not in table:
        raise DataError(
            f"unknown unit '{unit}' for channel '{channel}' ({quantity}){suggest(unit, table)}; "
            f"known units: {fmt_list(table)}",
            file=file, key=f"units.{channel}",
        )
    scale, offset = table[unit]
    return np.asarray(values, dtype=float) * scale + offset
