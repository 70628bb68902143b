"""The one registry of scenarios: name -> builder (and mesh from a results file's parameters)."""
from __future__ import annotations

import dataclasses
from typing import Callable

from . import cube, strip, tensile, tube


@dataclasses.dataclass(frozen=True)
class Scenario:
    """A scenario of the registry: ``build(**params) -> Problem`` and, where a results file's
    parameters (``Problem.params``, HDF5 attributes) determine it, ``mesh(params) -> Mesh``."""

    name: str
    build: Callable
    mesh: Callable | None = None


REGISTRY = {s.name: s for s in (Scenario("block", cube.block, cube.mesh_from_params),
                                Scenario("rolled", tube.rolled, tube.mesh_from_params),
                                Scenario("torsional", strip.torsional, strip.mesh_from_params),
                                Scenario("uniaxial", tensile.uniaxial))}
"""Scenario name -> Scenario: the one list of scenarios (experiment files, results files, CLI)."""
NAMES = tuple(REGISTRY)
"""The scenario names, in order."""


def get(name: str) -> Scenario:
    """The registered scenario ``name``; ValueError listing the known ones otherwise."""
    if name not in REGISTRY:
        raise ValueError(f"unknown scenario {name!r}; known: {', '.join(NAMES)}")
    return REGISTRY[name]
