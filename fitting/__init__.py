"""fitting: parameter identification and sim-to-real diagnosis for dejax.

Modules (each imports only those above it):
  schema       experiment-file keys, loading tables, ``DataError``
  units        channels, their SI units, unit conversion (``to_si``)
  traces       ``Trace`` (the one record of a measured trace, for fits and diagnoses alike)
               and the CSV reader ``load_trace_csv``
  data         experiment files (one TOML + CSV traces): ``load_experiment``, ``Experiment``
  datasets     loaders for the measured VHB curves shipped under ``data/``
  toml_writer  TOML text of a document (``dumps``) and atomic file writes
  least_squares  bounded Levenberg-Marquardt (fit and the diagnosis's effect fits)
  fit          parameter identification (Levenberg-Marquardt, or optax Adam then L-BFGS) and
               ``FitResult``
  fitted       the fitted experiment file ``fitted.toml`` that ``dejax fit`` writes
  selection    choosing between fitted models: information criteria, multi-start agreement
  experiment   forward models of fits (uniaxial, block, rolled) from experiment files;
               the run of an experiment under one trace's loading (``dejax run FILE.toml``)
  sensitivity  forward-mode design sensitivities of the rolled tube
  effects      the library of candidate unmodelled effects, their normalized parameters
  forward      the diagnosis's forward model (baseline + effects, simulations cached), its
               residuals and their forward differences; built from experiment files
  gap          the noise level, the residual breakdown, the gap beyond the noise
  screening    candidate effects screened at the baseline (a score-type test)
  effect_fit   candidate effects fitted to the traces, the baseline held
  diagnose     the diagnosis: where the gap lies, which effect explains it (the ranking),
               how far it shrinks
  report       the diagnosis report (markdown, JSON, figures)
  cli          the verbs fit, sensitivity, diagnose (registered by ``dejax.cli``)

Importing ``fitting`` imports ``dejax``, which enables float64 in JAX.
"""
import dejax  # noqa: F401  (enables float64)

from .data import Experiment, FitSpec, load_experiment
from .schema import DataError
from .traces import Trace, load_trace_csv

__all__ = ["DataError", "Experiment", "FitSpec", "Trace", "load_experiment", "load_trace_csv"]
