"""Post-processing: per-cycle measures, the Appendix-5 strain norm, VTU export, HDF5 snapshots.

* ``cycle_table(time, x, v, freq)``: per-cycle x_max, x_min, mean, k_c and the loop
  area of x against v (e.g. x_P against the nominal field) via ``dejax.cycles``.
* ``strain_norm_gauss(model, q)`` / ``strain_norm_nodes(q)``: the paper's Appendix-5
  strain norm eps = sqrt(ex^2 + ey^2 + ez^2), ex = (r_x . r_x - 1)/2 (likewise y, z),
  at the Gauss points (from F) and at the nodes (from the nodal gradient coordinates
  r_x, r_y, r_z, which ANCF carries: exact nodal values, no extrapolation).
* ``to_meshio(mesh, q, phi)`` / ``write_vtu(path, mesh, q, phi)``: the deformed mesh as
  linear hexahedra through the element corner nodes' current positions, with point
  data displacement (m), strain_norm (-), potential (V) and nominal_field (V/m) and
  cell data strain_norm_mean; open in ParaView.
* ``snapshot(model, mesh, state, phi)``: dict for ``results.write_h5(snapshots={step: ...})``
  (q, Cv, t, strain norms, nodal potential); ``vtu_from_h5`` rebuilds the mesh from the
  file's scenario parameters and writes one VTU per snapshot (+ a .pvd time series).
"""
from __future__ import annotations

import json
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from . import cycles
from . import model as mdl

# ----------------------------------------------------------------------------- cycles

CYCLE_COLUMNS = ("cycle", "t_start", "x_max", "x_min", "mean", "amplitude", "k_c", "loop_area")


def cycle_table(time, x, v=None, freq=None, *, T=None, t0=None) -> dict:
    """Per-cycle measures of x (e.g. x_P, m) and of the x-v loop (v e.g. the field, V/m).

    Returns a dict of numpy arrays, one entry per whole cycle: cycle (0-based), t_start (s),
    x_max, x_min, mean (= (x_max + x_min)/2), amplitude, k_c (mean / mean of cycle 1; NaN
    with fewer than 2 cycles) and loop_area (signed area of the loop of x against v, units
    x*v, positive when x lags v; NaN without v). Empty arrays when no whole cycle is covered.
    """
    t = np.asarray(time, dtype=float)
    x = np.asarray(x, dtype=float)
    if freq is None and T is None:
        raise ValueError("cycle_table: give freq (Hz) or T (s)")
    period = float(T) if T is not None else 1.0 / float(freq)
    n_whole = int(np.floor((t[-1] - (t[0] if t0 is None else t0)) / period + 1e-9))
    if n_whole < 1:
        return {k: np.zeros(0) for k in CYCLE_COLUMNS}
    feats = cycles.cycle_features(t, x, None if v is None else np.asarray(v, dtype=float), T=period, t0=t0)
    n = int(feats["n_cycles"])
    start = (t[0] if t0 is None else t0) + period * np.arange(n)
    nan = np.full(n, np.nan)
    return {
        "cycle": np.arange(n),
        "t_start": start,
        "x_max": np.asarray(feats["x_max"]),
        "x_min": np.asarray(feats["x_min"]),
        "mean": np.asarray(feats["mean"]),
        "amplitude": np.asarray(feats["amplitude"]),
        "k_c": np.asarray(feats["k_c"]) if "k_c" in feats else nan,
        "loop_area": np.asarray(feats["loop_area"]) if "loop_area" in feats else nan,
    }


def solution_cycle_table(sol, freq, x="x_P", v="field") -> dict:
    """``cycle_table`` of a Solution (or a ``results.read_h5`` dict) of the rolled scenario."""
    if isinstance(sol, dict):
        time, outs = sol["time"], sol["outputs"]
    else:
        time, outs = sol.time, sol.outputs
    return cycle_table(np.asarray(time), np.asarray(outs[x]), None if v is None else np.asarray(outs[v]), freq)


def format_cycle_table(table: dict, x_scale=1e3, x_unit="mm") -> str:
    """Plain-text table (x in ``x_unit`` = metres * x_scale)."""
    lines = [f"{'cycle':>5} {'x_max':>10} {'x_min':>10} {'mean':>10} {'k_c':>8} {'loop_area':>12}   (x in {x_unit})"]
    for i in range(len(table["cycle"])):
        lines.append(
            f"{int(table['cycle'][i]):5d} {table['x_max'][i] * x_scale:10.5f} {table['x_min'][i] * x_scale:10.5f} "
            f"{table['mean'][i] * x_scale:10.5f} {table['k_c'][i]:8.4f} {table['loop_area'][i]:12.5g}"
        )
    return "\n".join(lines)


# ----------------------------------------------------------------------------- strain norm


def _norm_from_gradients(rx, ry, rz):
    e = [0.5 * (jnp.sum(g * g, axis=-1) - 1.0) for g in (rx, ry, rz)]
    return jnp.sqrt(e[0] ** 2 + e[1] ** 2 + e[2] ** 2)


@eqx.filter_jit
def strain_norm_gauss(model, q) -> jax.Array:
    """(n_el, n_gp) Appendix-5 strain norm at the Gauss points: r_x = F[:, 0] (dr/dX) etc."""
    F = mdl.deformation_gradients(model, jnp.asarray(q))
    return _norm_from_gradients(F[..., :, 0], F[..., :, 1], F[..., :, 2])


@jax.jit
def strain_norm_nodes(q) -> jax.Array:
    """(n_nodes,) Appendix-5 strain norm at the nodes, from the nodal gradient coordinates."""
    g = jnp.asarray(q).reshape(-1, 4, 3)
    return _norm_from_gradients(g[:, 1], g[:, 2], g[:, 3])


def nodal_potential(mesh, phi) -> tuple[np.ndarray, np.ndarray]:
    """(potential (n_nodes,) V, nominal field (n_nodes, 3) V/m) for channel voltages phi."""
    phi = np.atleast_1d(np.asarray(phi, dtype=float))
    pot = np.asarray(mesh.potential)  # (n_ch, n_nodes, 4)
    if pot.shape[0] == 0:
        n = mesh.n_nodes
        return np.zeros(n), np.zeros((n, 3))
    val = np.einsum("c,cn->n", phi, pot[:, :, 0])
    field = -np.einsum("c,cni->ni", phi, pot[:, :, 1:])
    return val, field


# ----------------------------------------------------------------------------- VTU


def to_meshio(mesh, q, phi=None, model=None):
    """meshio.Mesh of the deformed configuration (linear hexahedra through the corner nodes).

    Point data: displacement (m), strain_norm (-), and with ``phi`` (channel voltages)
    potential (V) and nominal_field (V/m). Cell data: strain_norm_mean (Gauss-point mean,
    needs ``model``). Element node order = VTK_HEXAHEDRON order (dejax.element.NODE_CORNERS).
    """
    import meshio

    qq = np.asarray(q, dtype=float).reshape(-1, 4, 3)
    X = np.asarray(mesh.X)
    x = qq[:, 0, :]
    point_data = {"displacement": x - X, "strain_norm": np.asarray(strain_norm_nodes(q))}
    if phi is not None:
        val, field = nodal_potential(mesh, phi)
        point_data["potential"] = val
        point_data["nominal_field"] = field
    cell_data = {}
    if model is not None:
        cell_data["strain_norm_mean"] = [np.asarray(strain_norm_gauss(model, q)).mean(axis=1)]
    return meshio.Mesh(x, [("hexahedron", np.asarray(mesh.conn))], point_data=point_data, cell_data=cell_data)


def write_vtu(path, mesh, q, phi=None, model=None) -> Path:
    """Write the deformed mesh (see ``to_meshio``) as a .vtu file; returns the path."""
    p = Path(path)
    to_meshio(mesh, q, phi, model).write(p, file_format="vtu")
    return p


def write_pvd(path, entries) -> Path:
    """ParaView time-series collection: entries = [(t, vtu file name relative to path's folder)]."""
    p = Path(path)
    rows = "\n".join(f'    <DataSet timestep="{t:.9g}" part="0" file="{f}"/>' for t, f in entries)
    p.write_text(f'<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1">\n  <Collection>\n{rows}\n'
                 "  </Collection>\n</VTKFile>\n")
    return p


# ----------------------------------------------------------------------------- HDF5 snapshots


def snapshot(model, mesh, state, phi=None) -> dict:
    """Snapshot dict for ``results.write_h5(..., snapshots={step: snapshot(...)})``:
    t, q, Cv, strain_norm_nodes, strain_norm_gauss, and (with phi) potential_nodes, phi."""
    q = np.asarray(state.q)
    out = {
        "t": float(state.t),
        "q": q,
        "Cv": np.asarray(state.Cv),
        "strain_norm_nodes": np.asarray(strain_norm_nodes(q)),
        "strain_norm_gauss": np.asarray(strain_norm_gauss(model, q)),
    }
    if phi is not None:
        out["phi"] = np.atleast_1d(np.asarray(phi, dtype=float))
        out["potential_nodes"] = nodal_potential(mesh, phi)[0]
    return out


def snapshots_from_states(problem, states: dict) -> dict:
    """{step: State} (e.g. from ``integrate.run_chunked``) -> {step: snapshot dict}."""
    mesh = problem.extras["mesh"]
    out = {}
    for k, s in sorted(states.items()):
        phi = np.asarray(problem.loading.phi(s.t)) if problem.loading.voltages else None
        out[int(k)] = snapshot(problem.model, mesh, s, phi)
    return out


def _param(attrs, key, default=None):
    v = attrs.get(key, default)
    if isinstance(v, str):
        try:
            return json.loads(v)
        except ValueError:
            return v
    return v


def mesh_from_attrs(attrs: dict):
    """Rebuild the reference mesh of a results file from its scenario parameters
    (``scenarios.REGISTRY[name].mesh``)."""
    from . import scenarios

    scen = attrs.get("scenario")
    entry = scenarios.REGISTRY.get(scen)
    if entry is None or entry.mesh is None:
        raise ValueError(f"cannot rebuild the mesh of scenario {scen!r} from the results file")
    return entry.mesh(dict(attrs, mesh=_param(attrs, "mesh")))


def vtu_from_h5(h5_path, out_dir) -> list[Path]:
    """One VTU per snapshot of a results file (plus ``<stem>.pvd``); returns the VTU paths."""
    from .results import read_h5

    res = read_h5(h5_path)
    if not res["snapshots"]:
        return []
    mesh = mesh_from_attrs(res["attrs"])
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    stem = Path(h5_path).stem
    paths, entries = [], []
    for k, snap in sorted(res["snapshots"].items()):
        p = out / f"{stem}_{k:06d}.vtu"
        write_vtu(p, mesh, snap["q"], snap.get("phi"))
        paths.append(p)
        entries.append((float(snap.get("t") or 0.0), p.name))
    write_pvd(out / f"{stem}.pvd", entries)
    return paths
