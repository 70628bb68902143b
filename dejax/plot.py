"""``dejax plot r.h5 [--out DIR]``: PNG figures of a results file (headless, matplotlib Agg).

Figures (those that apply to the file's outputs):
  <stem>_x.png         x_P(t) (mm) with the per-cycle max/min/mean markers (rolled)
  <stem>_loop.png      hysteresis loop x_P against the nominal field (V/m)
  <stem>_kc.png        creep parameter k_c per cycle (needs >= 2 whole cycles)
  <stem>_twist.png     twist angle against phibar / voltage (torsional)
  <stem>_outputs.png   every other recorded output against time (any scenario)
  <stem>_snap<k>.png   deformed mesh coloured by the strain norm, per snapshot
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np


def _plt():
    import matplotlib

    if "matplotlib.pyplot" not in sys.modules:  # a script or the CLI: no display needed
        matplotlib.use("Agg")  # (a notebook has chosen its backend, e.g. inline: keep it)
    import matplotlib.pyplot as plt

    return plt


def _freq(attrs):
    f = attrs.get("freq")
    try:
        return float(f) if f is not None else None
    except (TypeError, ValueError):
        return None


def axis_label(name: str, unit: str | None = None) -> str:
    """``name (unit)``; dimensionless ("1") as ``name (-)``; the unit from results.UNITS if not given."""
    from .results import unit_of

    unit = unit or unit_of(name)
    if unit == "unknown":
        return name
    return f"{name} ({'-' if unit == '1' else unit})"


def failure_note(attrs) -> str:
    """"run failed at t = ... s (cause); data up to t = ... s" for a failed run's file, else ""."""
    if attrs.get("status") != "failed":
        return ""
    cause = attrs.get("fail_status", "failure")
    return (f"run failed at t = {float(attrs.get('fail_time', float('nan'))):.4g} s ({cause}); "
            f"data up to t = {float(attrs.get('t_last_converged', float('nan'))):.4g} s")


def plot_x(t, x, table=None, ax=None, label=None):
    plt = _plt()
    if ax is None:
        _, ax = plt.subplots(figsize=(6, 3.5))
    ax.plot(t, np.asarray(x) * 1e3, lw=1, label=label)
    if table is not None and len(table["cycle"]):
        tm = table["t_start"]
        ax.plot(tm, table["mean"] * 1e3, "k.", ms=4)
    ax.set_xlabel("t (s)")
    ax.set_ylabel("x_P (mm)")
    ax.grid(alpha=0.3)
    return ax


def plot_loop(field, x, ax=None, label=None):
    plt = _plt()
    if ax is None:
        _, ax = plt.subplots(figsize=(4.5, 4))
    ax.plot(np.asarray(field) / 1e6, np.asarray(x) * 1e3, lw=1, label=label)
    ax.set_xlabel("nominal field (MV/m)")
    ax.set_ylabel("x_P (mm)")
    ax.grid(alpha=0.3)
    return ax


def plot_kc(table, ax=None, label=None):
    plt = _plt()
    if ax is None:
        _, ax = plt.subplots(figsize=(4.5, 3.5))
    ax.plot(table["cycle"] + 1, table["k_c"], "o-", label=label)
    ax.set_xlabel("cycle")
    ax.set_ylabel("k_c")
    ax.grid(alpha=0.3)
    return ax


def plot_mesh(x_nodes, conn, values, ax=None, title=None, vmin=None, vmax=None):
    """Deformed mesh: element faces as 3D polygons coloured by the mean nodal value."""
    plt = _plt()
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    if ax is None:
        fig = plt.figure(figsize=(5, 4.5))
        ax = fig.add_subplot(projection="3d")
    faces = [(0, 1, 2, 3), (4, 5, 6, 7), (0, 1, 5, 4), (2, 3, 7, 6), (0, 3, 7, 4), (1, 2, 6, 5)]
    polys, vals = [], []
    for e in np.asarray(conn):
        for f in faces:
            ids = e[list(f)]
            polys.append(x_nodes[ids])
            vals.append(values[ids].mean())
    vals = np.asarray(vals)
    vmin = vals.min() if vmin is None else vmin
    vmax = vals.max() if vmax is None else vmax
    cmap = plt.get_cmap("viridis")
    norm = plt.Normalize(vmin, vmax if vmax > vmin else vmin + 1e-12)
    pc = Poly3DCollection(polys, facecolors=cmap(norm(vals)), edgecolors="k", linewidths=0.2, alpha=0.9)
    ax.add_collection3d(pc)
    lo, hi = x_nodes.min(0), x_nodes.max(0)
    c, s = 0.5 * (lo + hi), 0.5 * (hi - lo).max()
    ax.set_xlim(c[0] - s, c[0] + s)
    ax.set_ylim(c[1] - s, c[1] + s)
    ax.set_zlim(c[2] - s, c[2] + s)
    sm = plt.cm.ScalarMappable(norm=norm, cmap=cmap)
    plt.colorbar(sm, ax=ax, shrink=0.6, label="strain norm")
    if title:
        ax.set_title(title)
    return ax


def plot_file(path, out_dir=None) -> list[Path]:
    """Write the PNGs of a results file; returns their paths."""
    from . import outputs as po
    from .results import read_h5

    plt = _plt()
    res = read_h5(path)
    p = Path(path)
    out = Path(out_dir) if out_dir else p.parent
    out.mkdir(parents=True, exist_ok=True)
    stem = p.stem
    t, o, attrs = res["time"], res["outputs"], res["attrs"]
    written = []

    def save(fig, name):
        fp = out / f"{stem}_{name}.png"
        fig.tight_layout()
        fig.savefig(fp, dpi=120)
        plt.close(fig)
        written.append(fp)

    done = set()
    if "x_P" in o:
        f = _freq(attrs)
        table = po.cycle_table(t, o["x_P"], o.get("field"), f) if f else None
        fig, ax = plt.subplots(figsize=(6, 3.5))
        plot_x(t, o["x_P"], table, ax)
        save(fig, "x")
        done |= {"x_P"}
        if "field" in o:
            fig, ax = plt.subplots(figsize=(4.5, 4))
            plot_loop(o["field"], o["x_P"], ax)
            save(fig, "loop")
            done |= {"field"}
        if table is not None and len(table["cycle"]) >= 2:
            fig, ax = plt.subplots(figsize=(4.5, 3.5))
            plot_kc(table, ax)
            save(fig, "kc")
    if "twist_angle" in o:
        fig, ax = plt.subplots(figsize=(4.5, 3.5))
        v = o.get("voltage", t)
        ax.plot(np.asarray(v) / 1e3, np.degrees(o["twist_angle"]))
        ax.set_xlabel("voltage (kV)")
        ax.set_ylabel("twist angle (deg)")
        ax.grid(alpha=0.3)
        save(fig, "twist")
        done |= {"twist_angle"}
    rest = [k for k in o if k not in done and np.asarray(o[k]).ndim == 1]
    if rest:
        fig, axs = plt.subplots(len(rest), 1, figsize=(6, 2.2 * len(rest)), sharex=True, squeeze=False)
        for ax, k in zip(axs[:, 0], rest):
            ax.plot(t, o[k], lw=1)
            ax.set_ylabel(axis_label(k, res.get("units", {}).get(k)))
            ax.grid(alpha=0.3)
        axs[-1, 0].set_xlabel("t (s)")
        note = failure_note(attrs)
        if note:
            fig.suptitle(note, fontsize=9, color="firebrick")
        save(fig, "outputs")
    if res["snapshots"]:
        try:
            mesh = po.mesh_from_attrs(attrs)
        except (ValueError, KeyError, TypeError) as e:
            print(f"dejax plot: snapshots skipped: {e}", file=sys.stderr)
            mesh = None
        if mesh is not None:
            for k, snap in sorted(res["snapshots"].items()):
                q = np.asarray(snap["q"]).reshape(-1, 4, 3)
                vals = np.asarray(snap["strain_norm_nodes"]) if "strain_norm_nodes" in snap else \
                    np.asarray(po.strain_norm_nodes(snap["q"]))
                fig = plt.figure(figsize=(5, 4.5))
                ax = fig.add_subplot(projection="3d")
                tt = snap.get("t")
                plot_mesh(q[:, 0, :], mesh.conn, vals, ax, title=f"t = {float(tt):.4g} s" if tt is not None else None)
                save(fig, f"snap{k}")
    return written
