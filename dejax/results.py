"""Results on disk: HDF5 (written atomically, never half-written) and reading back.

Layout of a results file:

    /time                    (n+1,) s
    /outputs/<name>          (n+1, ...) recorded outputs (SI units)
    /newton_iterations       (n,) Newton iterations per step
    /snapshots/<k>/q, q0, phi  optional full states at chosen steps (attrs: t), phi the
                             electrode voltages (V) at t
    attributes (root)        scenario parameters, dejax_version, command_line, dt (the step
                             used) and dt_requested (s), timings, status ("ok" | "failed"; a
                             failed run also has fail_time (s), fail_step, fail_status,
                             fail_reason, t_last_converged (s): its datasets stop at the last
                             converged step), and ``units``: JSON {attribute: unit} of the
                             numeric ones

Every dataset carries an attribute ``units`` ("1" = dimensionless; UNITS below). Files
are created with mode 0o666 & ~umask, as ``open`` would make them.
"""
from __future__ import annotations

import contextlib
import json
import os
import tempfile
from pathlib import Path

import h5py
import numpy as np

from . import __version__, parameters


UNITS = {
    # outputs and time
    "time": "s", "lateral_stretch": "1", "thickness_stretch": "1", "stretch": "1", "voltage": "V", "x_P": "m",
    "v_P": "m/s", "field": "V/m", "twist_angle": "rad", "x_end": "m", "stress": "Pa", "newton_iterations": "1",
    # snapshots
    "q": "m (positions), 1 (gradient vectors)", "q0": "m (positions), 1 (gradient vectors)", "Cv": "1",
    "strain_norm_nodes": "1", "strain_norm_gauss": "1", "potential_nodes": "V", "phi": "V", "t": "s",
    # scenario and material parameters
    "phi_max": "V", "phibar_max": "1", "L": "m", "h": "m", "r": "m", "lx": "m", "ly": "m", "lz": "m",
    "thickness": "m", "length": "m", "width": "m", "turns": "1", "mesh": "1", "gauss_order": "1", "freq": "Hz",
    "t_ramp": "s", "damping": "1/s", **parameters.UNITS,
    # run attributes
    "dt": "s", "dt_requested": "s", "t_end": "s", "rho_inf": "1", "newton_tol": "1", "dt_min": "s",
    "cutbacks": "1", "dt_smallest": "s", "compile_s": "s", "run_s": "s", "newton_mean": "1", "newton_max": "1",
    "fail_time": "s", "fail_step": "1", "t_last_converged": "s", "steps": "1", "steps_planned": "1",
}
"""Units of the datasets and numeric attributes of a results file (SI; "1" = dimensionless)."""


def unit_of(name: str) -> str:
    """Unit of a dataset or attribute name (UNITS), "unknown" for a name not listed."""
    return UNITS.get(name, "unknown")


class OutputPathError(ValueError):
    """The results path cannot be written (missing folder, not writable, a directory, ...)."""


def _probe_writable(folder: Path) -> bool:
    """Whether a file can really be created in ``folder`` (catches read-only mounts, ACLs)."""
    try:
        fd, tmp = tempfile.mkstemp(prefix=".dejax-probe.", dir=folder)
    except OSError:
        return False
    os.close(fd)
    os.remove(tmp)
    return True


def check_output_path(path) -> Path:
    """Validate that ``path`` can be created or replaced; raise OutputPathError otherwise."""
    p = Path(path)
    if p.exists() and p.is_dir():
        raise OutputPathError(f"output path {str(p)!r} is a directory, not a file")
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.exists():
        raise OutputPathError(f"cannot write {str(p)!r}: folder {str(parent)!r} does not exist")
    if not parent.is_dir():
        raise OutputPathError(f"cannot write {str(p)!r}: {str(parent)!r} is a file, not a folder")
    if not os.access(parent, os.W_OK) or not _probe_writable(parent):
        raise OutputPathError(f"cannot write {str(p)!r}: folder {str(parent)!r} is not writable")
    if p.exists() and not os.access(p, os.W_OK):
        raise OutputPathError(f"cannot write {str(p)!r}: the existing file is not writable")
    return p


def check_output_dir(path) -> Path:
    """Validate that the folder ``path`` exists writable or can be created (nothing is created);
    raise OutputPathError otherwise."""
    p = Path(path)
    if p.exists():
        if not p.is_dir():
            raise OutputPathError(f"output folder {str(p)!r} is a file, not a folder")
        if not os.access(p, os.W_OK) or not _probe_writable(p):
            raise OutputPathError(f"cannot write into folder {str(p)!r}: it is not writable")
        return p
    ancestor = p.absolute().parent
    while not ancestor.exists():
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise OutputPathError(f"cannot create folder {str(p)!r}: {str(ancestor)!r} is a file, not a folder")
    if not os.access(ancestor, os.W_OK) or not _probe_writable(ancestor):
        raise OutputPathError(f"cannot create folder {str(p)!r}: {str(ancestor)!r} is not writable")
    return p


def file_mode() -> int:
    """Mode of a new file under the current umask (0o666 & ~umask), as ``open`` gives."""
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


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


def _attr_units(attrs) -> dict:
    """{name: unit} of the numeric attributes (strings and flags have none)."""
    def numeric(v):
        a = np.asarray(v)
        return a.dtype.kind in "iuf" and not isinstance(v, (bool, np.bool_))
    return {k: unit_of(k) for k, v in attrs.items() if k != "units" and numeric(v)}


@contextlib.contextmanager
def atomic_file(path):
    """Yield a temporary file's path in ``path``'s folder; when the block ends without error
    it becomes ``path`` (renamed, mode as ``open`` gives), otherwise it is removed: a
    failure never leaves a half-written file."""
    p = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=p.parent if str(p.parent) else ".")
    os.close(fd)
    try:
        yield tmp
        os.chmod(tmp, file_mode())
        os.replace(tmp, p)
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise


def write_h5(path, time, outputs: dict, params: dict | None = None, iterations=None, snapshots=None, attrs=None) -> Path:
    """Write a results file atomically (``atomic_file``).

    Raises OutputPathError (nothing is left behind) if the path cannot be written.
    """
    p = check_output_path(path)
    with atomic_file(p) as tmp:
        with h5py.File(tmp, "w") as f:
            f.create_dataset("time", data=np.asarray(time, dtype=float))
            f["time"].attrs["units"] = "s"
            g = f.create_group("outputs")
            for name, val in outputs.items():
                g.create_dataset(name, data=np.asarray(val))
                g[name].attrs["units"] = unit_of(name)
            if iterations is not None:
                f.create_dataset("newton_iterations", data=np.asarray(iterations))
                f["newton_iterations"].attrs["units"] = "1"
            if snapshots:
                sg = f.create_group("snapshots")
                for k, snap in snapshots.items():
                    kg = sg.create_group(str(k))
                    for name, val in snap.items():
                        if name == "t":
                            kg.attrs["t"] = float(val)
                        else:
                            kg.create_dataset(name, data=np.asarray(val))
                            kg[name].attrs["units"] = unit_of(name)
                    kg.attrs["t_units"] = "s"
            for k, v in (params or {}).items():
                f.attrs[k] = _attr(v)
            for k, v in (attrs or {}).items():
                f.attrs[k] = _attr(v)
            f.attrs["dejax_version"] = __version__
            f.attrs["units"] = json.dumps(_attr_units(f.attrs))
    return p


def _text(v) -> str:
    return v.decode() if isinstance(v, bytes) else str(v)


def read_h5(path) -> dict:
    """Read a results file into a dict: time, outputs (dict), attrs (dict), iterations, snapshots,
    units ({output name: unit}, from the datasets' ``units`` attributes, else UNITS)."""
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
            "units": {k: _text(f["outputs"][k].attrs.get("units", unit_of(k))) for k in f["outputs"]},
        }
        if "snapshots" in f:
            for k in f["snapshots"]:
                g = f["snapshots"][k]
                snap = {name: g[name][()] for name in g}
                snap["t"] = g.attrs.get("t")
                res["snapshots"][int(k)] = snap
    return res
