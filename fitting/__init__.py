"""fitting: parameter identification and sim-to-real diagnosis for dejax.

Modules:
  data      experiment files (one TOML + CSV traces): ``load_experiment``,
            ``load_trace_csv``, ``Experiment``, ``Trace``, ``DataError``
  datasets  loaders for the measured VHB curves shipped under ``data/``

Importing ``fitting`` imports ``dejax``, which enables float64 in JAX.
"""
import dejax  # noqa: F401  (enables float64)

from .data import DataError, Experiment, FitSpec, Trace, load_experiment, load_trace_csv

__all__ = ["DataError", "Experiment", "FitSpec", "Trace", "load_experiment", "load_trace_csv"]
