"""The report of a gap diagnosis (``fitting.diagnose.Diagnosis``): ``report.md`` (where the
gap lies, which effect explains it, how far it shrinks), ``report.json`` and two figures
(``traces.png``: data, baseline and best effect with residuals; ``breakdown.png``: residual
per cycle, feature gaps, the ranking)."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Sequence

import numpy as np

from .diagnose import Diagnosis
from .traces import Trace

__all__ = ["write_report"]


def _figures(diag: Diagnosis, traces: Sequence[Trace], out: Path) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    files = []
    nt = len(traces)
    fig, ax = plt.subplots(nt, 2, figsize=(11, 2.6 * nt), squeeze=False)
    for i, tr in enumerate(traces):
        ax[i, 0].plot(tr.time, tr.y, ".", ms=2, color="k", label="measured")
        ax[i, 0].plot(tr.time, diag.preds["baseline"][tr.name], label="baseline")
        if diag.best:
            ax[i, 0].plot(tr.time, diag.preds[diag.best][tr.name], "--", label=f"+ {diag.best}")
        ax[i, 0].set_title(f"{tr.name} ({tr.role}) {tr.conditions}", fontsize=8)
        ax[i, 1].plot(tr.time, diag.preds["baseline"][tr.name] - tr.y, label="baseline residual")
        if diag.best:
            ax[i, 1].plot(tr.time, diag.preds[diag.best][tr.name] - tr.y, label=f"+ {diag.best}")
        ax[i, 1].axhspan(-diag.noise, diag.noise, color="0.85", label="+- noise")
        ax[i, 0].legend(fontsize=7)
        ax[i, 1].legend(fontsize=7)
    ax[-1, 0].set_xlabel("t (s)")
    ax[-1, 1].set_xlabel("t (s)")
    fig.tight_layout()
    fig.savefig(out / "traces.png", dpi=90)
    plt.close(fig)
    files.append("traces.png")

    fig, ax = plt.subplots(1, 3, figsize=(13, 3.4))
    for e in diag.breakdown_before["traces"]:
        ax[0].plot(np.arange(1, len(e["per_cycle_rms"]) + 1), e["per_cycle_rms"], "o-", label=e["name"])
    ax[0].axhline(diag.noise, color="0.5", ls=":", label="noise")
    ax[0].set_xlabel("cycle")
    ax[0].set_ylabel("baseline residual RMS")
    ax[0].legend(fontsize=7)
    feats = list(diag.breakdown_before["features"])
    rel0 = [diag.breakdown_before["features"][f]["relative"] or 0.0 for f in feats]
    x = np.arange(len(feats))
    ax[1].bar(x - 0.2, rel0, 0.4, label="baseline")
    if diag.breakdown_after:
        rel1 = [diag.breakdown_after["features"][f]["relative"] or 0.0 for f in feats]
        ax[1].bar(x + 0.2, rel1, 0.4, label=f"+ {diag.best}")
    ax[1].set_xticks(x, feats, rotation=30, fontsize=8)
    ax[1].set_ylabel("RMS feature gap / |measured|")
    ax[1].legend(fontsize=7)
    names = [c["name"] for c in diag.ranking]
    vals = [c["rms_holdout"] if c["rms_holdout"] is not None else c["rms_fit"] for c in diag.ranking]
    ax[2].barh(np.arange(len(names))[::-1], vals, color=["C2" if c["significant"] else "C7" for c in diag.ranking])
    ax[2].set_yticks(np.arange(len(names))[::-1], names, fontsize=7)
    b = diag.baseline["rms_holdout"] if diag.baseline["rms_holdout"] is not None else diag.baseline["rms_fit"]
    ax[2].axvline(b, color="C3", label="baseline")
    ax[2].axvline(diag.noise, color="0.5", ls=":", label="noise")
    ax[2].set_xlabel("holdout RMS")
    ax[2].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "breakdown.png", dpi=90)
    plt.close(fig)
    files.append("breakdown.png")
    return files


def _refit_lines(refit) -> list[str]:
    """The report's lines on the baseline's refit (none without ``--refit``)."""
    if not refit:
        return []
    b = refit["before"]
    hold = f", holdout {b['rms_holdout']:.3e}" if b["rms_holdout"] is not None else ""
    factors = ", ".join(f"{n.split(':', 1)[1]} x {v:.4g} +- {refit['stderr'][n]:.2g}"
                        for n, v in refit["values"].items())
    return [f"- baseline refitted (its parameters fitted again, alone and then with every candidate): {factors}; "
            f"before the refit RMS fit {b['rms_fit']:.3e}{hold}"]


def write_report(diag: Diagnosis, traces: Sequence[Trace], out, title: str = "Sim-to-real gap diagnosis") -> dict:
    """Write report.md, report.json and PNG figures into ``out``; return {kind: path}."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    figs = _figures(diag, traces, out)
    (out / "report.json").write_text(json.dumps(diag.as_dict(), indent=1, default=float))
    alt = ([f"Equivalent explanations (holdout mean square within 2 sd of the best's): "
            f"{', '.join(diag.alternatives)}.", ""] if diag.alternatives else [])
    L = [f"# {title}", "", f"**Verdict: {diag.verdict}.**", ""] + alt + [
         f"- noise level sigma = {diag.noise:.3e}; baseline fit RMS = {diag.baseline['rms_fit']:.3e}; "
         f"RMS^2/sigma^2 = {diag.chi2_ratio:.2f} (limit {diag.chi2_limit:.2f}); n_fit = {diag.n_fit}",
         ] + _refit_lines(diag.baseline.get("refit")) + [
         "", "## Where the gap lies (baseline residual)", "",
         "| trace | role | conditions | RMS | mean | loading | unloading | transient | steady | per cycle |",
         "|---|---|---|---|---|---|---|---|---|---|"]
    for e in diag.breakdown_before["traces"]:
        st = f"{e['steady_rms']:.2e}" if e["steady_rms"] is not None else "-"
        L.append(f"| {e['name']} | {e['role']} | {e['conditions']} | {e['rms']:.2e} | {e['mean_residual']:.2e} | "
                 f"{e['loading_rms']:.2e} | {e['unloading_rms']:.2e} | {e['transient_rms']:.2e} | {st} | "
                 + " ".join(f"{v:.1e}" for v in e["per_cycle_rms"]) + " |")
    L += ["", "| feature | RMS gap (model - measured) | mean gap | relative |", "|---|---|---|---|"]
    for f, d in diag.breakdown_before["features"].items():
        rel = f"{d['relative']:.3f}" if d["relative"] is not None else "-"
        L.append(f"| {f} | {d['rms_gap']:.3e} | {d['mean_gap']:.3e} | {rel} |")
    L += ["", "## Which effect explains it", "", "```", diag.table(), "```", "",
          "Ranking: effects with Delta BIC below -10 first, then by holdout RMS. Uncertainties: Gauss-Newton.", ""]
    if diag.shrinkage:
        L += ["## How far it shrinks", "",
              "Beside each gap and shrinkage: +- its sd over replicate measurements (new noise of the "
              "estimated sigma) and the fitted effect's Gauss-Newton parameter covariance "
              "(`gap.shrinkage_spread`).", "",
              "| set | RMS before | RMS after | gap before | gap after | shrinkage |", "|---|---|---|---|---|---|"]
        for role in ("fit", "holdout"):
            if role in diag.shrinkage:
                s = diag.shrinkage[role]
                sp = s.get("spread") or {}
                L.append(f"| {role} | {s['rms_before']:.3e} | {s['rms_after']:.3e} | "
                         f"{_pm(s['gap_before'], sp.get('gap_before'))} | {_pm(s['gap_after'], sp.get('gap_after'))} | "
                         f"{_pm(s['gap_shrinkage'], sp.get('shrinkage'), percent=True)} |")
        L += ["", "| feature | gap before | gap after | shrinkage |", "|---|---|---|---|"]
        for f, s in diag.shrinkage["features"].items():
            sp = s.get("spread") or {}
            L.append(f"| {f} | {_pm(s['gap_before'], sp.get('gap_before'))} | {_pm(s['gap_after'], sp.get('gap_after'))} | "
                     f"{_pm(s['shrinkage'], sp.get('shrinkage'), percent=True)} |")
    L += ["", "## Figures", ""] + [f"![{f}]({f})" for f in figs]
    (out / "report.md").write_text("\n".join(L) + "\n")
    return {"markdown": str(out / "report.md"), "json": str(out / "report.json"), "figures": [str(out / f) for f in figs]}


def _pm(value, spread, percent: bool = False) -> str:
    """``value`` +- the sd of ``spread`` (``gap.shrinkage_spread``), as a percentage if ``percent``."""
    if value is None:
        return "-"
    sd = (spread or {}).get("sd")
    if percent:
        return f"{100 * value:.0f} %" + (f" +- {100 * sd:.0f}" if sd is not None else "")
    return f"{value:.3e}" + (f" +- {sd:.1e}" if sd is not None else "")
