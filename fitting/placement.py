"""Where a fit or a diagnosis runs: on the host CPU for few-element problems when JAX's
default backend is an accelerator (``dejax fit`` / ``dejax diagnose`` ``--device``).

A one-element problem's time step is a few hundred tiny kernels; on a GPU each is a
launch, so such problems are launch-latency bound there. Measured on one NVIDIA H200
against this project's 2-core CPU (``bench/results/h200-2026-12-04``): D1 (one-element
block diagnosis) did not finish in 330 s on the GPU against 106-109 s on the CPU, F1 (the
one-element VHB fit) took 29.7 s against 19.1 s; the tube 4x8x1 (32 elements) ran 5x
faster on the GPU (R1 0.88 s against 4.58 s). Between 1 and 32 elements nothing is
measured: ``CPU_MAX_ELEMENTS`` keeps to the measured side.
"""
from __future__ import annotations

import contextlib
import math

import jax

from .experiment import DEFAULT_MESH

DEVICE_CHOICES = ("auto", "cpu", "default")
CPU_MAX_ELEMENTS = 1
"""``--device auto`` runs problems of at most this many elements on the host CPU when the
default backend is an accelerator (measured: 1 element faster on the CPU, 32 on the GPU)."""


def n_elements(exp) -> int:
    """Number of elements of an experiment's mesh (``[geometry] mesh``, else the scenario's
    default; a diagnosis may use a coarser one, never a finer one)."""
    mesh = exp.geometry.get("mesh", DEFAULT_MESH.get(exp.scenario, (1, 1, 1)))
    return int(math.prod(int(n) for n in mesh))


def device_for(elements: int, choice: str = "auto", backend: str | None = None):
    """The ``jax.Device`` to run a problem of ``elements`` elements on, or None for JAX's
    default. ``choice``: "auto" (the host CPU when ``backend``, default
    ``jax.default_backend()``, is not the CPU and elements <= CPU_MAX_ELEMENTS), "cpu"
    (always the host CPU) or "default" (JAX's default device)."""
    if choice not in DEVICE_CHOICES:
        raise ValueError(f"--device {choice!r}: choose from {', '.join(DEVICE_CHOICES)}")
    backend = jax.default_backend() if backend is None else backend
    if choice == "default" or (choice == "auto" and (backend == "cpu" or elements > CPU_MAX_ELEMENTS)):
        return None
    try:
        return jax.devices("cpu")[0]
    except RuntimeError as e:  # JAX_PLATFORMS without cpu
        if choice == "cpu":
            raise ValueError(f"--device cpu: JAX has no CPU backend here ({e}); add 'cpu' to JAX_PLATFORMS") from e
        return None


@contextlib.contextmanager
def placed(device):
    """Run the block on ``device`` (``jax.default_device``); None: JAX's default."""
    if device is None:
        yield
    else:
        with jax.default_device(device):
            yield
