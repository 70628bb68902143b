"""fitting: parameter identification and sim-to-real diagnosis for dejax.

Modules (each imports only those above it):
  schema       experiment-file keys, loading tables, ``DataError``
  units        channels, their SI units, unit conversion (``to_si``)
  traces       ``Trace`` and the CSV reader ``load_trace_csv``
  data         experiment files (one TOML + CSV traces): ``load_experiment``, ``Experiment``
  datasets     loaders for the measured VHB curves shipped under ``data/``
  fit          parameter identification (optax Adam, then L-BFGS) and ``FitResult``
  experiment   forward models of fits (uniaxial, block, rolled) from experiment files
  sensitivity  forward-mode design sensitivities of the rolled tube
  effects      the library of candidate unmodelled effects
  diagnose     where the sim-to-real gap lies, which effect explains it, how far it shrinks
  report       the diagnosis report (markdown, JSON, figures)
  cli          the verbs fit, sensitivity, diagnose (registered by ``dejax.cli``)

Importing ``fitting`` imports ``dejax``, which enables float64 in JAX.
"""
import dejax  # noqa: F401  (enables float64)

from .data import Experiment, FitSpec, load_experiment
from .schema import DataError
from .traces import Trace, load_trace_csv

__all__ = ["DataError", "Experiment", "FitSpec", "Trace", "load_experiment", "load_trace_csv"]
