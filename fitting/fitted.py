"""The fitted experiment file: ``dejax fit``'s ``fitted.toml``.

The input experiment file as written (every section and key kept, the TOML comments
excepted), with

* each free parameter at its fitted value (material parameters in ``[material]`` and
  ``[[material.units]]``, ``c_d`` as ``[solver] damping``), commented with its standard
  error (absolute and relative) and initial value;
* ``[fit.result]``: per free parameter its ``value``, ``unit``, ``stderr``, ``rel_stderr``
  (1) and ``initial`` (``fitting.schema.FIT_RESULT_KEYS``);
* every ``[[traces]] file`` rewritten relative to the folder of the new file (absolute
  when they share no folder below the root), commented with the trace's RMS error.

``dejax run``, ``dejax diagnose`` and ``dejax fit`` read it like any experiment file.
"""
from __future__ import annotations

import copy
import os
from pathlib import Path
from typing import Any, Mapping

from dejax import parameters

from .data import read_document
from .toml_writer import dumps, write_atomic

__all__ = ["parameter_path", "relative_path", "fitted_document", "fit_result_table", "fit_comments", "write_fitted",
           "FITTED_NAME"]

FITTED_NAME = "fitted.toml"
"""The file name ``dejax fit --out DIR`` writes in DIR."""


def parameter_path(name: str) -> tuple:
    """The key path of a named parameter in an experiment document: ``mu_inf`` ->
    ("material", "mu_inf"), ``eta_2`` -> ("material", "units", 1, "eta"), ``c_d`` ->
    ("solver", "damping"), ``geometry.h`` -> ("geometry", "h"), ``effects.e.p`` ->
    ("effects", "e", "p")."""
    if name == "c_d":
        return ("solver", "damping")
    if name.startswith(("geometry.", "effects.")):
        return tuple(name.split("."))
    m = parameters.PATTERN.match(name)
    if m is None:
        raise KeyError(f"unknown parameter '{name}'")
    if m.group(3) is None:
        return ("material", name)
    return ("material", "units", int(m.group(3)) - 1, m.group(2))


def _set(doc: dict, path: tuple, value) -> None:
    """``doc[path[0]][path[1]]... = value``, creating missing tables."""
    node = doc
    for k in path[:-1]:
        node = node[k] if isinstance(k, int) else node.setdefault(k, {})
    node[path[-1]] = value


def _within(value: float, bounds) -> float:
    """``value`` clipped into the file's [lower, upper] (a fit's log-space optimum may sit
    one rounding off its bound, which the loader would reject)."""
    if bounds is None:
        return value
    return min(max(value, float(bounds[0])), float(bounds[1]))


def relative_path(path, start) -> str:
    """``path`` relative to the folder ``start`` (POSIX separators) when they share a folder
    below the file system's root, else absolute (a data folder elsewhere stays found when
    ``start`` moves)."""
    path, start = Path(path).resolve(), Path(start).resolve()
    try:
        shared = Path(os.path.commonpath([path, start]))
    except ValueError:  # another drive (Windows)
        return path.as_posix()
    return path.as_posix() if shared == Path(shared.anchor) else Path(os.path.relpath(path, start)).as_posix()


def fitted_document(doc: Mapping, values: Mapping[str, float], source_dir, out_dir,
                    result: Mapping[str, Mapping[str, Any]] | None = None) -> dict:
    """A copy of the experiment document ``doc`` (read from a file in ``source_dir``) with
    the parameters ``values`` (name -> value in its SI unit) set, ``[fit.result]`` =
    ``result`` (dropped when None) and the trace files relative to ``out_dir``."""
    out = copy.deepcopy(dict(doc))
    bounds = out.get("fit", {}).get("bounds", {})
    for name, v in values.items():
        _set(out, parameter_path(name), _within(float(v), bounds.get(name)))
    fit = out.get("fit")
    if isinstance(fit, dict):
        fit.pop("result", None)
    if result is not None:
        _set(out, ("fit", "result"), {k: dict(v) for k, v in result.items()})
    for trace in out.get("traces", []):
        if isinstance(trace, dict) and isinstance(trace.get("file"), str):
            trace["file"] = relative_path(Path(source_dir) / trace["file"], Path(out_dir))
    return out


def fit_result_table(res) -> dict:
    """``[fit.result]`` of a ``fitting.fit.FitResult``: per free parameter value, unit,
    stderr, rel_stderr, initial."""
    return {k: dict(value=float(res.params[k]), unit=parameters.unit(k), stderr=float(res.stderr[k]),
                    rel_stderr=float(res.rel_stderr[k]), initial=float(res.p0[k])) for k in res.free}


def fit_comments(doc: Mapping, res) -> dict:
    """Comments of the fitted file (key path -> text): each free parameter's standard error
    and initial value, each trace's RMS error."""
    out = {}
    for k in res.free:
        u = parameters.unit(k)
        unit = "" if u == "1" else f" {u}"
        bound = " (at a bound)" if k in res.at_bound else ""
        out[parameter_path(k)] = (f"fitted{bound}: +- {res.stderr[k]:.3g}{unit} ({100 * res.rel_stderr[k]:.2f} %), "
                                  f"initial {res.p0[k]:.6g}{unit}")
    for i, trace in enumerate(doc.get("traces", [])):
        name = trace.get("name", Path(str(trace.get("file", ""))).stem)
        r = res.rms.get(name)
        if r is not None:
            unit = "" if r.get("unit") in ("", "1", None) else f" {r['unit']}"
            out[("traces", i, "file")] = (f"{r['role']}: RMS {r['rms']:.4g}{unit} "
                                          f"({100 * r['rel_rms']:.3g} % of the amplitude)")
    return out


def write_fitted(exp, res, out_dir) -> Path:
    """Write ``out_dir/fitted.toml`` (atomically) for the experiment ``exp``
    (``fitting.data.Experiment``) fitted as ``res`` (``fitting.fit.FitResult``)."""
    out_dir = Path(out_dir)
    _, doc = read_document(exp.path)
    new = fitted_document(doc, {k: res.params[k] for k in res.free}, Path(exp.path).parent, out_dir,
                          fit_result_table(res))
    header = (f"{exp.name}: fitted by dejax fit from {relative_path(Path(exp.path), out_dir)}\n"
              f"loss {res.loss0:.6g} -> {res.loss:.6g} in {res.n_evals} evaluations; standard errors in the "
              f"comments and in [fit.result]")
    return write_atomic(out_dir / FITTED_NAME, dumps(new, fit_comments(doc, res), header))
