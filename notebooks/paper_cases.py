"""The rolled-tube studies of the paper's Section 6 as named runs of ``dejax run rolled``.

Each run is made once, by the command line in this process (``dejax.cli.main``), and kept
as a compact ``<name>.npz`` (time, x_P, v_P, nominal field, voltage; the run's attributes
as JSON; for the field runs the strain norm at the nodes at t = 0, T/2, T) in
``RESULTS``. ``paper_rolled.ipynb`` reads them; ``python notebooks/run_all.py`` makes the
missing ones. The full-size results are committed (notebooks/results/rolled/), so the
notebook re-executes in seconds; delete a file to recompute that run.

Sizes: full = the paper's 12 x 20 x 4 mesh, ten cycles; ``DEJAX_SMALL=1`` = a 1 x 4 x 1 mesh
and two cycles (a smoke run whose numbers are not converged), in a separate folder.

Time step: 67 steps per cycle (dt = 4.98e-4 s at 30 Hz) with Newton to a relative residual
of 1e-4: on R1 (`dejax bench --cases R1 --reference`) this deviates 0.2 % of the peak x_P
from dt = 1e-4 s with Newton to 1e-10.
"""
from __future__ import annotations

import contextlib
import io
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np

SMALL = os.environ.get("DEJAX_SMALL") == "1"
ROOT = Path(__file__).resolve().parent
RESULTS = Path(os.environ.get("DEJAX_RESULTS", ROOT / "results")) / ("rolled-small" if SMALL else "rolled")
MESH = (1, 4, 1) if SMALL else (12, 20, 4)
CYCLES = 2 if SMALL else 10
STEPS_PER_CYCLE = 40 if SMALL else 67
NEWTON_TOL = 1e-4
FIELD = 2.5e7  # phi_m / h of the base case (50 kV on 2 mm), V/m

# Fig. 24: the voltage (kV) at each half-cycle turning point of 30 Hz (ten cycles: 21 levels)
PATTERNS = {
    # VP1, memory and wiping-out: a major loop, nested minor loops, then the major branch again
    "VP1": [0, 50, 10, 40, 20, 30, 20, 40, 10, 50, 0, 50, 0, 40, 10, 30, 20, 30, 10, 40, 0],
    # VP2, congruency: the same 20-40 kV minor loop reached from above (after 50 kV) and from below (after 0 kV)
    "VP2": [0, 50, 20, 40, 20, 40, 0, 40, 20, 40, 20, 50, 20, 40, 20, 40, 0, 40, 20, 40, 0],
}


def _mesh_name(shape) -> str:
    return "x".join(str(n) for n in shape)


def mesh_study() -> list[tuple]:
    """Fig. 12: one direction refined at a time from the paper's mesh (n_s, then n_l, then n_r)."""
    if SMALL:
        return [(1, 3, 1), (1, 4, 1), (2, 4, 1)]
    nl, ns, nr = MESH
    return ([(nl, s, nr) for s in (4, 8, 12, 16)] + [(l, ns, nr) for l in (4, 8)] + [(nl, ns, r) for r in (1, 2)]
            + [MESH])


FREQS = [10.0, 30.0] if SMALL else [10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0]
FIELD_FREQS = [10.0, 30.0] if SMALL else [10.0, 30.0, 50.0, 70.0]
MODELS = ["I", "IV"] if SMALL else ["I", "II", "III", "IV"]
HS = [2e-3, 8e-3] if SMALL else [2e-3, 8e-3, 14e-3]
LS = [10e-3, 38e-3] if SMALL else [10e-3, 38e-3, 66e-3]
RS = [2e-6, 28e-3] if SMALL else [2e-6, 28e-3, 56e-3]  # r = 0 as 1e-3 h: the mesh map is degenerate at r = 0
PHIS = [6e3, 10e3] if SMALL else [6e3, 8e3, 10e3]


def cases() -> dict:
    """name -> dict(args=[...] of ``dejax run rolled``, freq=Hz, field=bool), in the order
    ``run_all.py`` makes them (the paper's base case and the cheap runs first)."""
    c = {}

    def add(name, *args, freq=30.0, cycles=CYCLES, mesh=MESH, field=False):
        c[name] = dict(args=["--mesh", _mesh_name(mesh), "--freq", f"{freq:g}", "--cycles", f"{cycles:g}", *args],
                       freq=freq, field=field)

    add("IV")  # Model IV, 50 kV, 30 Hz, h = r = 2 mm, L = 8 mm: the paper's base case
    for s in mesh_study():
        if tuple(s) != MESH:
            add("mesh-" + _mesh_name(s), mesh=s)
    for m in MODELS:
        if m != "IV":
            add("model-" + m, "--model", m)
    add("hyperelastic", "--model", "hyperelastic")
    for f in FIELD_FREQS:  # Fig. 17: the first cycle at 25 kV
        add(f"field-{f:g}Hz", "--phi-max", "25e3", freq=f, cycles=1, field=True)
    for m in ("IV", "hyperelastic"):  # Fig. 19: the first cycle at 50 kV
        add(f"field-{m}", "--model", m, cycles=1, field=True)
    for p in PHIS:
        add(f"phi-{p / 1e3:g}kV", "--phi-max", f"{p:g}")
    for h in HS[1:]:
        add(f"h-{h * 1e3:g}mm", "--h", f"{h:g}", "--phi-max", f"{FIELD * h:g}")
    for L in LS:
        add(f"L-{L * 1e3:g}mm", "--L", f"{L:g}")
    for r in RS:
        add(f"r-{r * 1e3:g}mm", "--r", f"{r:g}")
    for k in PATTERNS:
        add(k, "--voltage", str(pattern_csv(k)), cycles=len(PATTERNS[k]) // 2)
    for f in FREQS:
        add(f"freq-{f:g}Hz", "--phi-max", "25e3", freq=f)
    return c


def pattern_csv(name: str, freq: float = 30.0) -> Path:
    """Write Fig. 24's pattern ``name`` as a voltage CSV (time s, voltage V; one level per
    half-cycle, linear in between) into RESULTS; returns its path."""
    levels = np.asarray(PATTERNS[name], dtype=float) * 1e3
    t = np.arange(levels.size) / (2.0 * freq)
    path = RESULTS / f"{name}.csv"
    RESULTS.mkdir(parents=True, exist_ok=True)
    np.savetxt(path, np.c_[t, levels], delimiter=",", header="time_s,voltage_V", comments="", fmt="%.9g")
    return path


def _solver() -> str:
    try:
        import pypardiso  # noqa: F401

        return "pardiso"
    except ImportError:
        return "auto"


def _field_frames(vtu_dir: Path, stem: str) -> dict:
    """Points (m), hexahedra and strain norm of the VTU frames of a field run."""
    import meshio

    frames = sorted(vtu_dir.glob(f"{stem}_*.vtu"))
    out = {}
    for k, f in enumerate(frames):
        m = meshio.read(f)
        out[f"frame{k}_points"] = np.asarray(m.points)
        out[f"frame{k}_strain_norm"] = np.asarray(m.point_data["strain_norm"])
    out["cells"] = np.asarray(meshio.read(frames[0]).cells[0].data)
    return out


def path(name: str) -> Path:
    return RESULTS / f"{name}.npz"


def run(name: str, force: bool = False) -> dict:
    """The results of run ``name`` (made now unless already in RESULTS): a dict of arrays
    and ``attrs`` (the results file's attributes, plus wall_s of the whole command)."""
    p = path(name)
    if p.exists() and not force:
        return load(name)
    import h5py

    from dejax import cli
    from dejax.results import read_h5

    spec = cases()[name]
    freq = spec["freq"]
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / f"{name}.h5"
        argv = ["run", "rolled", *spec["args"], "--dt", repr(1.0 / (freq * STEPS_PER_CYCLE) * (1 + 1e-9)),
                "--newton-tol", f"{NEWTON_TOL:g}", "--solver", _solver(), "--out", str(out), "--quiet"]
        if spec["field"]:
            argv += ["--vtu", str(Path(tmp) / "vtu"), "--vtu-frames", "2"]
        tic = time.perf_counter()
        buf = io.StringIO()
        with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(buf):
            rc = cli.main(argv)
        wall = time.perf_counter() - tic
        if not out.exists():
            raise RuntimeError(f"run {name}: dejax run rolled wrote no results (exit {rc}): {buf.getvalue()}")
        res = read_h5(out)
        with h5py.File(out) as f:
            attrs = {k: (v.tolist() if hasattr(v, "tolist") else v) for k, v in f.attrs.items()}
        shown = [a for i, a in enumerate(argv) if a != "--out" and (i == 0 or argv[i - 1] != "--out")]
        attrs.update(wall_s=wall, exit_code=rc, argv=" ".join(shown),
                     message=buf.getvalue().strip().splitlines()[-1] if buf.getvalue().strip() else "")
        arrays = {"time": np.asarray(res["time"]), **{k: np.asarray(v) for k, v in res["outputs"].items()}}
        if spec["field"] and rc == 0:
            arrays.update(_field_frames(Path(tmp) / "vtu", out.stem))
    RESULTS.mkdir(parents=True, exist_ok=True)
    tmp_path = p.with_suffix(".tmp.npz")
    np.savez_compressed(tmp_path, attrs=np.asarray(json.dumps(attrs, default=str)), **arrays)
    os.replace(tmp_path, p)
    return load(name)


def load(name: str) -> dict:
    with np.load(path(name)) as d:
        out = {k: d[k] for k in d.files if k != "attrs"}
        out["attrs"] = json.loads(str(d["attrs"]))
    return out


def run_all(names=None, force=False, log=print) -> float:
    """Make every missing run (or ``names``); returns the wall time (s)."""
    tic = time.perf_counter()
    todo = list(cases()) if names is None else list(names)
    for i, name in enumerate(todo, 1):
        if path(name).exists() and not force:
            continue
        r = run(name, force=force)
        a = r["attrs"]
        log(f"[{i}/{len(todo)}] {name}: {a.get('status')} in {a['wall_s']:.0f} s ({a.get('steps')} steps, "
            f"Newton {a.get('newton_mean', float('nan')):.2f}/step; {time.perf_counter() - tic:.0f} s so far)")
    return time.perf_counter() - tic
