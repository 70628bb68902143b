"""Voltage histories and prescribed-motion histories: callables t (s) -> value.

Each history is an ``equinox.Module`` whose parameters are differentiable
fields, evaluated with jax.numpy so it can be sampled on a time grid inside
jit (``history(times)``).
"""
from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np


class RampHold(eqx.Module):
    """Paper Eq. (41): phi = phi_m/2 (1 + sin(pi t / t_ramp - pi/2)) for t <= t_ramp, then phi_m.

    phi_m in V, t_ramp in s (the paper uses 1 s).
    """

    phi_m: jax.Array
    t_ramp: jax.Array

    def __init__(self, phi_m, t_ramp=1.0):
        self.phi_m = jnp.asarray(phi_m, dtype=float)
        self.t_ramp = jnp.asarray(t_ramp, dtype=float)

    def __call__(self, t):
        t = jnp.asarray(t, dtype=float)
        ramp = 0.5 * self.phi_m * (1.0 + jnp.sin(jnp.pi * t / self.t_ramp - 0.5 * jnp.pi))
        return jnp.where(t <= self.t_ramp, ramp, self.phi_m)


class Sine(eqx.Module):
    """Paper Eq. (42): phi = offset + phi_m/2 (1 + sin(2 pi f t + phase)); with the defaults
    phase = 1.5 pi, offset = 0 it starts from 0 V at t = 0. phi_m, offset in V, f in Hz,
    phase in rad."""

    phi_m: jax.Array
    freq: jax.Array
    phase: jax.Array
    offset: jax.Array

    def __init__(self, phi_m, freq, phase=1.5 * np.pi, offset=0.0):
        self.phi_m = jnp.asarray(phi_m, dtype=float)
        self.freq = jnp.asarray(freq, dtype=float)
        self.phase = jnp.asarray(phase, dtype=float)
        self.offset = jnp.asarray(offset, dtype=float)

    def __call__(self, t):
        return self.offset + 0.5 * self.phi_m * (1.0 + jnp.sin(2.0 * jnp.pi * self.freq * jnp.asarray(t) + self.phase))


class PiecewiseLinear(eqx.Module):
    """Linear interpolation through (times, values); constant outside. Values in V (or -)."""

    times: jax.Array
    values: jax.Array

    def __init__(self, times, values):
        times = np.asarray(times, dtype=float)
        if times.ndim != 1 or times.size < 1 or np.any(np.diff(times) <= 0):
            raise ValueError("PiecewiseLinear: times must be a strictly increasing 1-D sequence")
        values = jnp.asarray(values, dtype=float)
        if values.shape != times.shape:
            raise ValueError(f"PiecewiseLinear: {values.shape[0]} values for {times.size} times")
        self.times = jnp.asarray(times)
        self.values = values

    def __call__(self, t):
        return jnp.interp(jnp.asarray(t, dtype=float), self.times, self.values)


class Constant(eqx.Module):
    """A constant value (V or -)."""

    value: jax.Array

    def __init__(self, value):
        self.value = jnp.asarray(value, dtype=float)

    def __call__(self, t):
        return jnp.zeros_like(jnp.asarray(t, dtype=float)) + self.value


class Scaled(eqx.Module):
    """``scale * base(t)``: e.g. phibar h sqrt(mu/eps) for the torsional strip."""

    base: eqx.Module
    scale: jax.Array

    def __call__(self, t):
        return self.scale * self.base(t)


SPEC_KINDS = ("sine", "ramp_hold", "constant", "piecewise")
"""The kinds of a loading table (``from_spec``), as the experiment files name them."""


def from_spec(spec):
    """The history of a loading table (SI): ``{"kind": "sine", "phi_max", "freq"[, "phase",
    "offset"]}`` (``Sine``), ``{"kind": "ramp_hold", "phi_max"[, "t_ramp"]}`` (``RampHold``),
    ``{"kind": "constant", "phi"}`` (``Constant``) or ``{"kind": "piecewise", "times",
    "values"}`` (``PiecewiseLinear``); optional keys take the classes' defaults."""
    kind = spec["kind"]
    if kind == "sine":
        return Sine(spec["phi_max"], spec["freq"], spec.get("phase", 1.5 * np.pi), spec.get("offset", 0.0))
    if kind == "ramp_hold":
        return RampHold(spec["phi_max"], spec.get("t_ramp", 1.0))
    if kind == "constant":
        return Constant(spec["phi"])
    if kind == "piecewise":
        return PiecewiseLinear(spec["times"], spec["values"])
    raise ValueError(f"unknown loading kind {kind!r}; known: {', '.join(SPEC_KINDS)}")


def sample(histories, times) -> jax.Array:
    """Evaluate a sequence of histories on a time grid: (n_times, n_histories)."""
    times = jnp.asarray(times, dtype=float)
    if not histories:
        return jnp.zeros((times.shape[0], 0))
    return jnp.stack([jnp.broadcast_to(h(times), times.shape) for h in histories], axis=1)


@eqx.filter_jit
def evaluate(history, times) -> jax.Array:
    """``history(times)`` outside jit, as one compiled program per history structure and grid
    length (evaluated eagerly, each of its operations would be compiled on its own)."""
    return history(jnp.asarray(times, dtype=float))


def read_csv(path) -> PiecewiseLinear:
    """A voltage history from a CSV file: a header line, then rows ``time (s), voltage (V)``,
    times strictly increasing; linear between rows, constant outside (``PiecewiseLinear``).

    Raises ValueError naming the file, row (1-based, the header is row 1) and column of any
    cell that is missing, not a finite number, or out of order.
    """
    import csv
    from pathlib import Path

    p = Path(path)
    if not p.is_file():
        raise ValueError(f"{p}: voltage history file not found")
    with open(p, newline="") as f:
        rows = [r for r in csv.reader(f)]
    if not rows:
        raise ValueError(f"{p}: empty file; expected a header and rows 'time (s), voltage (V)'")
    header, body = rows[0], rows[1:]
    if len(header) < 2:
        raise ValueError(f"{p}, row 1: the header names {len(header)} column(s); expected two: time (s), voltage (V)")
    times, values = [], []
    for i, r in enumerate(body, start=2):
        if not r or all(not c.strip() for c in r):
            continue
        if len(r) < 2:
            raise ValueError(f"{p}, row {i}: {len(r)} column(s); expected two: time (s), voltage (V)")
        cells = []
        for j, (name, cell) in enumerate(zip(header[:2], r[:2]), start=1):
            try:
                v = float(cell)
            except ValueError:
                raise ValueError(f"{p}, row {i}, column {j} ({name.strip()!r}): {cell!r} is not a number") from None
            if not np.isfinite(v):
                raise ValueError(f"{p}, row {i}, column {j} ({name.strip()!r}): {cell!r} is not finite")
            cells.append(v)
        if times and cells[0] <= times[-1]:
            raise ValueError(f"{p}, row {i}, column 1: time {cells[0]:g} s does not increase (previous row "
                             f"{times[-1]:g} s)")
        times.append(cells[0])
        values.append(cells[1])
    if len(times) < 2:
        raise ValueError(f"{p}: {len(times)} data row(s); a voltage history needs at least two")
    return PiecewiseLinear(times, values)
