"""Material parameters by name: the one scheme between a ``Material`` and plain dicts.

Names: ``mu_inf``, ``K_inf``, ``Jm_inf``, ``eps``, ``rho`` (the equilibrium network) and,
per viscous unit i = 1..N, ``mu_i``, ``K_i``, ``Jm_i``, ``eta_i``; the structural damping
``c_d`` (1/s) travels with them in fits. Experiment files, fits, sensitivities and the
diagnosis use these names; results files store ``fields`` (the unit parameters as lists).

* ``names(n)``: the names of a material with n units, in order;
* ``flat(material, damping=None)``: name -> float;
* ``material_kwargs(params, n)`` / ``from_flat(params, n)``: a Material (keyword arguments)
  from a dict with every name of ``names(n)`` (values may be traced);
* ``replace(material, params)``: the material with the named leaves replaced (same
  structure, so compiled code is reused);
* ``fields(material)``: the results-file attributes (``mu``, ``K``, ``Jm``, ``eta`` as
  arrays over the units);
* ``to_vector(params, names)`` / ``from_vector(p, names, base)``: the vector (k,) of the
  values of k names, in their order (what fits and sensitivities differentiate: Jacobian
  columns and covariances follow the names), and back to a dict;
* ``unit(name)``: the SI unit of a name.
"""
from __future__ import annotations

import re
from typing import Any, Mapping, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .material import Material

SCALARS = ("mu_inf", "K_inf", "Jm_inf", "eps", "rho")
"""The equilibrium-network parameters, in order."""
UNIT_KEYS = ("mu", "K", "Jm", "eta")
"""The parameters of each viscous unit, in order."""
UNITS = {"mu_inf": "Pa", "K_inf": "Pa", "Jm_inf": "1", "eps": "F/m", "rho": "kg/m^3",
         "mu": "Pa", "K": "Pa", "Jm": "1", "eta": "Pa s"}
"""SI units of the scalars and of the unit keys ("1" = dimensionless)."""
PATTERN = re.compile(r"^(mu_inf|K_inf|Jm_inf|eps|rho|c_d|(mu|K|Jm|eta)_(\d+))$")
"""A parameter name; group 2 is the unit key and group 3 the unit number of a unit parameter."""


def names(n_units: int) -> list[str]:
    """The parameter names of a material with ``n_units`` viscous units (no ``c_d``)."""
    out = list(SCALARS)
    for i in range(n_units):
        out += [f"{k}_{i + 1}" for k in UNIT_KEYS]
    return out


def flat(material: Material, damping=None) -> dict:
    """All named parameters of ``material`` (and ``c_d`` = ``damping`` if given) as floats."""
    p = {k: float(getattr(material, k)) for k in SCALARS}
    for key in UNIT_KEYS:
        for i, v in enumerate(np.asarray(getattr(material, key))):
            p[f"{key}_{i + 1}"] = float(v)
    if damping is not None:
        p["c_d"] = float(damping)
    return p


def material_kwargs(params: Mapping[str, Any], n_units: int) -> dict:
    """Keyword arguments of ``Material`` from the values of ``names(n_units)`` in ``params``:
    the unit parameters as tuples of floats, or stacked arrays when any value is an array
    (e.g. traced inside a fit)."""
    kw = {k: params[k] for k in SCALARS}
    for key in UNIT_KEYS:
        vals = [params[f"{key}_{i + 1}"] for i in range(n_units)]
        if any(not isinstance(v, (int, float)) for v in vals):
            kw[key] = jnp.stack([jnp.asarray(v, dtype=float) for v in vals])
        else:
            kw[key] = tuple(float(v) for v in vals)
    return kw


def from_flat(params: Mapping[str, Any], n_units: int) -> Material:
    """The Material of the values of ``names(n_units)`` in ``params`` (others ignored)."""
    return Material(**material_kwargs(params, n_units))


def replace(material: Material, params: Mapping[str, Any]) -> Material:
    """A copy of ``material`` with the named parameters replaced (``c_d`` is skipped: it is
    the model's damping). KeyError for an unknown name or a unit the material lacks."""
    m = material
    for name, v in params.items():
        g = PATTERN.match(name)
        if not g:
            raise KeyError(f"unknown parameter {name!r} (expected mu_inf, K_inf, Jm_inf, eps, rho, c_d, mu_i, K_i, Jm_i, eta_i)")
        if name == "c_d":
            continue
        if g.group(2):
            key, i = g.group(2), int(g.group(3)) - 1
            n = getattr(m, key).shape[0]
            if not 0 <= i < n:
                raise KeyError(f"parameter {name!r}: the material has {n} viscous unit(s)")
            m = eqx.tree_at(lambda mm: getattr(mm, key), m, getattr(m, key).at[i].set(jnp.asarray(v, dtype=float)))
        else:
            m = eqx.tree_at(lambda mm: getattr(mm, name), m, jnp.asarray(v, dtype=float))
    return m


def fields(material: Material) -> dict:
    """The material as results-file attributes: the five scalars and ``mu``, ``K``, ``Jm``,
    ``eta`` (arrays over the units)."""
    return {k: getattr(material, k) for k in SCALARS + UNIT_KEYS}


def to_vector(params: Mapping[str, Any], names: Sequence[str]) -> jax.Array:
    """(k,) float array of the values of the k ``names`` in ``params``, in that order (values
    may be traced). Names need not be material parameters (a sensitivity adds the geometry
    h, L, r). KeyError naming the names without a value."""
    missing = [k for k in names if k not in params]
    if missing:
        raise KeyError(f"no value for parameter(s) {', '.join(map(repr, missing))}")
    return jnp.stack([jnp.asarray(params[k], dtype=float) for k in names]) if len(names) else jnp.zeros(0)


def from_vector(p, names: Sequence[str], base: Mapping[str, Any] | None = None) -> dict:
    """``base`` (name -> value, default empty) with the values of ``names`` set to the entries
    of ``p`` (k,), which may be traced: the inverse of ``to_vector``."""
    if jnp.shape(p) != (len(names),):
        raise ValueError(f"parameter vector of shape {jnp.shape(p)} for {len(names)} names {list(names)}")
    out = dict(base or {})
    out.update({k: p[i] for i, k in enumerate(names)})
    return out


def unit(name: str) -> str:
    """SI unit of a parameter name (mu_inf, mu_1, eta_2, c_d, ...); "1" = dimensionless,
    "unknown" for a name that is no parameter."""
    if name == "c_d":
        return "1/s"
    g = PATTERN.match(name)
    return UNITS.get(g.group(2) if g and g.group(2) else name, "unknown")
