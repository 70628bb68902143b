"""fitting.report: the diagnosis written as report.json, report.md and figures.

The diagnoses come from the analytic forward model of ``tests/helpers.py`` (seconds)."""
import json
import os

from fitting import diagnose as dg
from fitting import report
from helpers import AnalyticForward, analytic_traces


def test_report_names_the_best_candidate_with_the_spread_of_each_gap(tmp_path):
    tr = analytic_traces({"sensor_offset": {"c": 1e-3}}, seed=5)
    d = dg.diagnose(AnalyticForward(), tr, ["sensor_offset", "voltage_lag"])
    files = report.write_report(d, tr, tmp_path)
    js = json.loads((tmp_path / "report.json").read_text())
    assert js["best"] == "sensor_offset" and js["ranking"][0]["name"] == "sensor_offset"
    md = (tmp_path / "report.md").read_text()
    assert "gap explained by 'sensor_offset'" in md
    holdout_row = next(line for line in md.splitlines() if line.startswith("| holdout |"))
    assert holdout_row.count("+-") == 3  # gap before, gap after, shrinkage, each with its sd
    assert js["shrinkage"]["holdout"]["spread"]["shrinkage"]["sd"] > 0
    assert files["figures"]
    for f in files["figures"]:
        assert os.path.getsize(f) > 1000


def test_a_refitted_baseline_shows_in_the_report(tmp_path):
    tr = analytic_traces({"refit:mu_inf": {"factor": 1.1}}, seed=6)
    d = dg.diagnose(AnalyticForward(), tr, ["sensor_offset"], refit=["mu_inf"])
    report.write_report(d, tr, tmp_path)
    assert "baseline refitted" in (tmp_path / "report.md").read_text()
