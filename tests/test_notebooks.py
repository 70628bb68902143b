"""Execute every notebook in notebooks/ at small size (DEJAX_SMALL=1) with nbclient.

Each notebook compiles a few steppers (~15-80 s each on 2 shared CPU cores), so this is
marked slow: ``pytest --runslow tests/test_notebooks.py``."""
from pathlib import Path

import numpy as np
import pytest

NOTEBOOKS = sorted((Path(__file__).resolve().parent.parent / "notebooks").glob("*.ipynb"))


@pytest.mark.slow
@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.name for p in NOTEBOOKS])
def test_notebook_runs_small(path, monkeypatch, tmp_path):
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    monkeypatch.setenv("DEJAX_SMALL", "1")
    monkeypatch.setenv("MPLBACKEND", "Agg")
    monkeypatch.setenv("DEJAX_RESULTS", str(tmp_path / "results"))  # paper_rolled makes its small runs afresh
    nb = nbformat.read(path, as_version=4)
    client = nbclient.NotebookClient(nb, timeout=900, kernel_name="python3",
                                     resources={"metadata": {"path": str(tmp_path)}})
    client.execute()
    errors = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", []) if o.get("output_type") == "error"]
    assert not errors


def _paper_cases(monkeypatch, small):
    import importlib
    import sys

    monkeypatch.setenv("DEJAX_SMALL", "1" if small else "0")
    monkeypatch.syspath_prepend(str(NOTEBOOKS[0].parent))
    sys.modules.pop("paper_cases", None)
    return importlib.import_module("paper_cases")


@pytest.mark.parametrize("small", [False, True], ids=["full", "small"])
def test_paper_cases_are_valid_command_lines(small, monkeypatch, tmp_path):
    """Every run of paper_rolled.ipynb parses as a `dejax run rolled` command, and the full
    size is the paper's: 12 x 20 x 4, ten cycles, every figure's parameter values."""
    from dejax import cli

    monkeypatch.setenv("DEJAX_RESULTS", str(tmp_path))
    pc = _paper_cases(monkeypatch, small)
    parser = cli.build_parser()
    cases = pc.cases()
    for name, spec in cases.items():
        args = parser.parse_args(["run", "rolled", *spec["args"], "--out", str(tmp_path / f"{name}.h5")])
        assert args.freq == spec["freq"]
    if not small:
        base = parser.parse_args(["run", "rolled", *cases["IV"]["args"], "--out", "x.h5"])
        assert base.mesh == (12, 20, 4) and base.cycles == 10 and base.phi_max == 50e3 and base.model == "IV"
        assert {c for c in cases if c.startswith("freq-")} == {f"freq-{f}Hz" for f in range(10, 80, 10)}
        for name, key, value in [("h-14mm", "phi_max", 350e3), ("L-66mm", "L", 66e-3), ("r-56mm", "r", 56e-3),
                                 ("phi-8kV", "phi_max", 8e3), ("model-II", "model", "II")]:
            assert getattr(parser.parse_args(["run", "rolled", *cases[name]["args"], "--out", "x.h5"]), key) == value
    # the Fig. 24 patterns: one level per half-cycle, ten cycles
    for vp in pc.PATTERNS:
        t, v = np.loadtxt(pc.pattern_csv(vp), delimiter=",", skiprows=1).T
        assert len(v) == 21 and t[-1] == pytest.approx(10 / 30.0) and v.max() == 50e3
