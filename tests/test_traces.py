"""CSV traces (fitting.traces): the reader's units, and errors that name the file, the row
and the column."""
import numpy as np
import pytest

from fitting.schema import DataError
from fitting.traces import load_trace_csv
from helpers import CSV, raises  # noqa: E402  (tests/helpers.py)


def test_load_trace_csv_defaults_and_units(tmp_path):
    p = tmp_path / "m.csv"
    p.write_text("stretch,stress,temperature\n1.0,0.0,20\n1.5,12.5,20\n")
    tr = load_trace_csv(p, units={"stress": "kPa", "temperature": "degC"})
    assert tr.time is None and len(tr) == 2
    np.testing.assert_allclose(tr["stress"], [0.0, 12.5e3])
    np.testing.assert_allclose(tr["temperature"], [293.15, 293.15])
    assert tr.units == {"stretch": "-", "stress": "kPa", "temperature": "degC"}


@pytest.mark.parametrize("text", ["", "\n\n", "# only a comment\n"])
def test_empty_csv(tmp_path, text):
    p = tmp_path / "empty.csv"
    p.write_text(text)
    raises(["empty.csv", "empty"], load_trace_csv, p, {"time": "t"})


def test_header_only_csv(tmp_path):
    p = tmp_path / "hdr.csv"
    p.write_text("time,displacement\n")
    raises(["hdr.csv", "row 1", "no data rows"], load_trace_csv, p)


def test_missing_column_lists_present(tmp_path):
    p = tmp_path / "run.csv"
    p.write_text(CSV)
    e = raises(["run.csv", "row 1", "'disp_m'", "present columns: t_ms, disp_mm, U_kV, note"],
               load_trace_csv, p, {"time": "t_ms", "displacement": "disp_m"})
    assert e.row == 1 and e.column == "disp_m" and e.file.endswith("run.csv")
    assert "did you mean 'disp_mm'" in str(e)


def test_unknown_channel(tmp_path):
    p = tmp_path / "run.csv"
    p.write_text(CSV)
    raises(["run.csv", "unknown channel 'displacment'", "did you mean 'displacement'", "known channels"],
           load_trace_csv, p, {"time": "t_ms", "displacment": "disp_mm"})


def test_decimal_comma_hint(tmp_path):
    p = tmp_path / "c.csv"
    p.write_text('time,displacement\n0,"0,5"\n')
    raises(["c.csv", "row 2", "column 'displacement'", "'0,5'", "decimal comma"], load_trace_csv, p)


@pytest.mark.parametrize("cell", ["nan", "NaN", "inf", "-Infinity"])
def test_non_finite_cell(tmp_path, cell):
    p = tmp_path / "nf.csv"
    p.write_text(f"time,displacement\n0,0\n1,{cell}\n")
    raises(["nf.csv", "row 3", "column 'displacement'", f"'{cell}'", "non-finite"], load_trace_csv, p)


def test_empty_cell(tmp_path):
    p = tmp_path / "ec.csv"
    p.write_text("time,displacement\n0,0\n1,\n")
    raises(["ec.csv", "row 3", "column 'displacement'", "empty cell"], load_trace_csv, p)


@pytest.mark.parametrize("times, bad_row", [("0,1,1,2", 4), ("0,2,1,3", 4)])
def test_non_increasing_time(tmp_path, times, bad_row):
    p = tmp_path / "t.csv"
    rows = "\n".join(f"{t},0" for t in times.split(","))
    p.write_text("time_s,x\n" + rows + "\n")
    e = raises(["t.csv", f"row {bad_row}", "column 'time_s'", "increase strictly"], load_trace_csv, p,
               {"time": "time_s", "displacement": "x"})
    assert e.row == bad_row


def test_ragged_row(tmp_path):
    p = tmp_path / "r.csv"
    p.write_text("time,displacement\n0,0\n1,2,3\n")
    raises(["r.csv", "row 3", "expected 2 cells", "found 3"], load_trace_csv, p)


def test_semicolon_csv_rejected(tmp_path):
    p = tmp_path / "s.csv"
    p.write_text("time;displacement\n0;0\n")
    raises(["s.csv", "row 1", "semicolon"], load_trace_csv, p)
