"""Results on disk: HDF5 (written atomically, never half-written) and reading back.

Layout of a results file:

    /time                    (n+1,) s
    /outputs/<name>          (n+1, ...) recorded outputs (SI units)
    /newton_iterations       (n,) Newton iterations per step
    /snapshots/<k>/q, Cv     optional full states at chosen steps (attrs: t)
    attributes (root)        scenario parameters, status, dejax version, timings
"""
from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import h5py
import numpy as np

from . import __version__


class OutputPathError(ValueError):
    """The results path cannot be written (missing folder, not writable, a directory, ...)."""


def check_output_path(path) -> Path:
    """Validate that ``path`` can be created or replaced; raise OutputPathError otherwise."""
    p = Path(path)
    if p.exists() and p.is_dir():
        raise OutputPathError(f"output path {str(p)!r} is a directory, not a file")
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.exists():
        raise OutputPathError(f"cannot write {str(p)!r}: folder {str(parent)!r} does not exist")
    if not os.access(parent, os.W_OK):
        raise OutputPathError(f"cannot write {str(p)!r}: folder {str(parent)!r} is not writable")
    if p.exists() and not os.access(p, os.W_OK):
        raise OutputPathError(f"cannot write {str(p)!r}: the existing file is not writable")
    return p


def _attr(value):
    """Convert a parameter to something HDF5 attributes accept."""
    if isinstance(value, (str, bool, int, float, np.integer, np.floating)):
        return value
    try:
        arr = np.asarray(value)
    except Exception:
        return json.dumps(value, default=str)
    if arr.dtype == object:
        return json.dumps(value, default=str)
    return arr


def write_h5(path, time, outputs: dict, params: dict | None = None, iterations=None, snapshots=None, attrs=None) -> Path:
    """Write a results file atomically: a temporary file in the same folder, renamed at the end.

    Raises OutputPathError (nothing is left behind) if the path cannot be written.
    """
    p = check_output_path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=p.parent if str(p.parent) else ".")
    os.close(fd)
    try:
        with h5py.File(tmp, "w") as f:
            f.create_dataset("time", data=np.asarray(time, dtype=float))
            f["time"].attrs["units"] = "s"
            g = f.create_group("outputs")
            for name, val in outputs.items():
                g.create_dataset(name, data=np.asarray(val))
            if iterations is not None:
                f.create_dataset("newton_iterations", data=np.asarray(iterations))
            if snapshots:
                sg = f.create_group("snapshots")
                for k, snap in snapshots.items():
                    kg = sg.create_group(str(k))
                    for name, val in snap.items():
                        if name == "t":
                            kg.attrs["t"] = float(val)
                        else:
                            kg.create_dataset(name, data=np.asarray(val))
            for k, v in (params or {}).items():
                f.attrs[k] = _attr(v)
            for k, v in (attrs or {}).items():
                f.attrs[k] = _attr(v)
            f.attrs["dejax_version"] = __version__
        os.replace(tmp, p)
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise
    return p


def read_h5(path) -> dict:
    """Read a results file into a dict: time, outputs (dict), attrs (dict), iterations, snapshots."""
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"results file {str(p)!r} does not exist")
    with h5py.File(p, "r") as f:
        res = {
            "time": f["time"][()],
            "outputs": {k: f["outputs"][k][()] for k in f["outputs"]},
            "attrs": {k: (v.decode() if isinstance(v, bytes) else v) for k, v in f.attrs.items()},
            "iterations": f["newton_iterations"][()] if "newton_iterations" in f else None,
            "snapshots": {},
        }
        if "snapshots" in f:
            for k in f["snapshots"]:
                g = f["snapshots"][k]
                snap = {name: g[name][()] for name in g}
                snap["t"] = g.attrs.get("t")
                res["snapshots"][int(k)] = snap
    return res
