"""The paper's scenarios as ready-made problems: mesh + material + constraints + loading + outputs.

Each builder returns a ``Problem``; ``Problem.simulate(t_end, dt)`` runs it. All
builders are differentiable in their float arguments (geometry, material,
voltage) when called inside ``jax.jvp`` / ``jax.grad``.

Modules: ``problem`` (``Problem``), ``materials`` (the paper's tables), one per scenario
(``cube``: the block, ``tube``: the rolled DEA, ``strip``: the torsional strip, ``tensile``:
the uniaxial test; each with its output function), and ``registry`` (name -> builder),
which every other module uses instead of switching on names.
"""
from .cube import block
from .materials import TABLE2, block_material, rolled_material, torsional_material
from .problem import Problem
from .registry import NAMES, REGISTRY, Scenario, get
from .strip import torsional
from .tensile import uniaxial
from .tube import rolled

__all__ = ["Problem", "TABLE2", "block_material", "rolled_material", "torsional_material", "block", "rolled",
           "torsional", "uniaxial", "Scenario", "REGISTRY", "NAMES", "get"]
