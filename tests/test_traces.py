"""CSV traces (fitting.traces): the reader's units, errors that name the file, the row
and the column, and the record's views (response, its unit and scale, the voltage history)."""
import dataclasses
import math

import numpy as np
import pytest

from fitting.traces import Trace, from_samples, load_trace_csv
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


def test_response_views_of_a_csv_trace(tmp_path):
    """The experiment's trace with its response chosen: y, x, unit and norm in SI; the
    voltage history is the measured column, linear between the samples."""
    p = tmp_path / "run.csv"
    p.write_text(CSV)
    tr = load_trace_csv(p, {"time": "t_ms", "displacement": "disp_mm", "voltage": "U_kV"},
                        {"time": "ms", "displacement": "mm", "voltage": "kV"}, conditions={"freq": 5.0})
    with pytest.raises(ValueError, match="run': no response channel chosen"):
        tr.y
    tg = dataclasses.replace(tr, response="displacement", against="voltage")
    np.testing.assert_allclose(tg.y, [0.0, 0.5e-3, 1e-3, 1.5e-3], rtol=1e-15)
    np.testing.assert_allclose(tg.x, [0.0, 1.5e3, 3e3, 4.5e3], rtol=1e-15)
    np.testing.assert_allclose(tg.t, [0.0, 1e-3, 2e-3, 3e-3], rtol=1e-15)
    assert tg.unit == "m" and tg.norm == pytest.approx(1.5e-3, rel=1e-15) and tg.frequency == 5.0
    assert tg.label("displacement") == "displacement"
    assert dataclasses.replace(tg, response="voltage").unit == "V"
    np.testing.assert_allclose(tg.voltage_history(np.array([0.5e-3, 2.5e-3])), [750.0, 3750.0], rtol=1e-12)


def test_voltage_history_of_a_loading_table():
    """Without a voltage column the loading table: phi_max / 2 (1 + sin(2 pi f t + 3 pi / 2))."""
    t = np.linspace(0.0, 0.5, 5)
    tr = Trace(t, {"stretch": 1.0 + t}, loading={"kind": "sine", "phi_max": 10e3, "freq": 2.0}, response="stretch")
    np.testing.assert_allclose(tr.voltage_history(np.array([0.125, 0.25])), [5e3, 10e3], rtol=1e-12)
    assert tr.frequency == 2.0 and tr.unit == "1"
    assert Trace(t, {"stretch": t}).voltage_history is None


def test_trace_from_samples():
    tg = from_samples("a", [1, 3, 2], {"k": 1}, x=[0.0, 1.0, 2.0], ylabel="stress (Pa)", xlabel="stretch", unit="Pa")
    assert tg.name == "a" and tg.y.dtype == float and list(tg.y) == [1.0, 3.0, 2.0] and tg.data == {"k": 1}
    assert tg.norm == 2.0 and tg.unit == "Pa" and tg.t is None and list(tg.x) == [0.0, 1.0, 2.0]
    assert tg.label(tg.response) == "stress (Pa)" and tg.label(tg.against) == "stretch"
    assert from_samples("b", [-2.0, -2.0]).norm == 2.0  # no amplitude: max |y|
    assert from_samples("c", [0.0, 0.0]).norm == 1.0
    c = from_samples("d", [1.0, 5.0], scale=0.5)
    assert c.norm == 0.5 and c.unit == "" and c.x is None and c.label(c.response) == "y"
    assert math.isclose(dataclasses.replace(c, scale=None).norm, 4.0)
