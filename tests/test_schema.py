"""The experiment-file schema (fitting.schema): error locations, suggestions, loading tables."""
import math

import numpy as np
import pytest

from fitting import schema as S


def test_data_error_names_file_row_line_column_and_key():
    e = S.DataError("bad cell", file="t.csv", row=3, line=5, column="x")
    assert str(e) == "t.csv: row 3 (line 5), column 'x': bad cell"
    assert (e.file, e.row, e.line, e.column, e.key) == ("t.csv", 3, 5, "x", None)
    assert str(S.DataError("missing", file="e.toml", key="fit")) == "e.toml: [fit]: missing"
    assert str(S.DataError("bad", key="fit.bounds.mu_1")) == "fit.bounds.mu_1: bad"
    assert isinstance(e, ValueError)


def test_suggest_and_fmt_list():
    assert S.suggest("Kv", ["V", "kV"]) == " (did you mean 'kV'?)"
    assert S.suggest("dispalcement", ["displacement", "voltage"]) == " (did you mean 'displacement'?)"
    assert S.suggest("zzz", ["displacement"]) == ""
    assert S.fmt_list([]) == "(none)" and S.fmt_list(["a", "b"]) == "a, b"


def test_check_loading_fills_defaults_and_rejects_bad_tables():
    assert S.check_loading({"kind": "sine", "phi_max": 1e3, "freq": 2}, "e.toml", "loading") == {
        "kind": "sine", "phi_max": 1e3, "freq": 2.0, "phase": 1.5 * math.pi, "offset": 0.0}
    for spec, part in [({}, "missing 'kind'"),
                       ({"kind": "square"}, "unknown loading kind 'square'"),
                       ({"kind": "sine", "phi_max": 1.0}, "needs 'freq'"),
                       ({"kind": "sine", "phi_max": 1.0, "freq": 0.0}, "must be > 0"),
                       ({"kind": "ramp_hold", "phi_max": 1.0, "t_ramp": -1.0}, "must be > 0"),
                       ({"kind": "constant", "phi": 1.0, "freq": 2.0}, "unknown key 'freq'"),
                       ({"kind": "piecewise", "times": [0.0, 1.0], "values": [1.0]}, "equal lengths"),
                       ({"kind": "piecewise", "times": [1.0, 0.0], "values": [1.0, 2.0]}, "increase strictly")]:
        with pytest.raises(S.DataError, match=part):
            S.check_loading(spec, "e.toml", "loading")


def test_loading_voltage_is_the_loads_history():
    t = np.linspace(0.0, 0.5, 11)
    v = S.loading_voltage({"kind": "sine", "phi_max": 2.0, "freq": 2.0, "phase": 0.0, "offset": -1.0}, t)
    np.testing.assert_allclose(np.asarray(v), np.sin(4 * np.pi * t), atol=1e-12)
    np.testing.assert_allclose(np.asarray(S.loading_voltage({"kind": "constant", "phi": 3.0}, t)), 3.0)
