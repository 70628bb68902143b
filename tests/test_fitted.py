"""The fitted experiment file: parameters to key paths, the document, load -> write -> load."""
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from fitting.data import load_experiment, read_document
from fitting.fitted import FITTED_NAME, fit_comments, fitted_document, parameter_path, relative_path, write_fitted

EXAMPLES = Path(__file__).resolve().parents[1] / "data" / "examples"


@pytest.mark.parametrize("name, path", [
    ("mu_inf", ("material", "mu_inf")), ("eps", ("material", "eps")),
    ("mu_1", ("material", "units", 0, "mu")), ("eta_12", ("material", "units", 11, "eta")),
    ("c_d", ("solver", "damping")), ("geometry.h", ("geometry", "h")),
    ("effects.voltage_lag.tau", ("effects", "voltage_lag", "tau")),
])
def test_parameter_path(name, path):
    assert parameter_path(name) == path


def test_parameter_path_of_an_unknown_name():
    with pytest.raises(KeyError, match="eta_inf"):
        parameter_path("eta_inf")


def test_fitted_document_sets_values_within_bounds_and_moves_trace_paths(tmp_path):
    doc = {"material": {"mu_inf": 1.0, "units": [{"mu": 2.0}]}, "fit": {"bounds": {"mu_1": [1.0, 3.0]},
                                                                        "result": {"old": {}}},
           "traces": [{"file": "run.csv"}, {"file": "sub/b.csv"}]}
    src, out = tmp_path / "data", tmp_path / "fits" / "one"
    new = fitted_document(doc, {"mu_inf": 5.0, "mu_1": 3.0000000000000004, "c_d": 0.5}, src, out,
                          result={"mu_inf": {"value": 5.0}})
    assert new["material"] == {"mu_inf": 5.0, "units": [{"mu": 3.0}]}  # one rounding past its bound: clipped
    assert new["solver"] == {"damping": 0.5} and new["fit"]["result"] == {"mu_inf": {"value": 5.0}}
    assert [t["file"] for t in new["traces"]] == ["../../data/run.csv", "../../data/sub/b.csv"]
    assert doc["material"]["mu_inf"] == 1.0 and doc["traces"][0]["file"] == "run.csv"  # a copy
    assert "result" not in fitted_document(doc, {}, src, out)["fit"]


def test_trace_paths_relative_within_a_shared_folder_else_absolute():
    assert relative_path("/data/lab/run.csv", "/data/fits/one") == "../../lab/run.csv"
    assert relative_path("/data/run.csv", "/data") == "run.csv"
    assert relative_path("/data/lab/run.csv", "/tmp/fit") == "/data/lab/run.csv"


def _fake_result(exp, scale=1.25):
    """A FitResult stand-in: every free parameter moved by ``scale`` (inside the bounds)."""
    p0 = exp.parameters()
    free = list(exp.fit.free)
    params = {k: p0[k] * scale for k in free}
    return SimpleNamespace(free=free, params=params, p0={k: p0[k] for k in free}, at_bound=[],
                           stderr={k: 0.01 * v for k, v in params.items()}, rel_stderr={k: 0.01 for k in free},
                           rms={exp.traces[0].name: dict(role="fit", rms=1e-3, rel_rms=0.02, unit="m")},
                           loss=0.5, loss0=2.0, n_evals=7)


@pytest.mark.parametrize("example", sorted(p.name for p in EXAMPLES.glob("*.toml")))
def test_load_write_load_gives_the_same_experiment(tmp_path, example):
    exp = load_experiment(EXAMPLES / example)
    res = _fake_result(exp)
    path = write_fitted(exp, res, tmp_path)
    assert path == tmp_path / FITTED_NAME
    back = load_experiment(path)
    expected = dict(exp.parameters(), **res.params)
    assert back.parameters() == expected  # exact: the written floats read back bit for bit
    assert back.fit.result == {k: dict(value=res.params[k], unit=back.fit.result[k]["unit"],
                                       stderr=res.stderr[k], rel_stderr=0.01, initial=res.p0[k]) for k in res.free}
    for attr in ("name", "scenario", "description", "geometry", "solver", "effects"):
        assert getattr(back, attr) == getattr(exp, attr), attr
    assert (back.fit.free, back.fit.bounds, back.fit.options) == (exp.fit.free, exp.fit.bounds, exp.fit.options)
    assert len(back.traces) == len(exp.traces)
    for a, b in zip(exp.traces, back.traces):
        assert (a.name, a.role, a.conditions, a.loading, a.weight) == (b.name, b.role, b.conditions, b.loading, b.weight)
        assert a.source.resolve() == b.source.resolve() and set(a.channels) == set(b.channels)
        assert all(np.array_equal(a.channels[c], b.channels[c]) for c in a.channels)
    # a fitted file fitted again: written from itself, the same again
    (tmp_path / "again").mkdir()
    again = load_experiment(write_fitted(back, _fake_result(back, scale=1.0), tmp_path / "again"))
    assert again.parameters() == expected and again.traces[0].source.resolve() == exp.traces[0].source.resolve()


def test_comments_name_standard_errors_and_rms():
    exp = load_experiment(EXAMPLES / "block_example.toml")
    res = _fake_result(exp)
    _, doc = read_document(exp.path)
    c = fit_comments(doc, res)
    mu = res.params["mu_inf"]
    assert c[("material", "mu_inf")] == f"fitted: +- {0.01 * mu:.3g} Pa (1.00 %), initial {mu / 1.25:.6g} Pa"
    assert c[("material", "units", 0, "eta")].endswith("Pa s")
    assert c[("traces", 0, "file")] == "fit: RMS 0.001 m (2 % of the amplitude)"
