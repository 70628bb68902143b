"""The TOML emitter: what it writes reads back equal (tomllib), comments, atomic writes."""
import math
import os
import tomllib

import numpy as np
import pytest

from fitting.toml_writer import dumps, write_atomic

DOC = {
    "title": "top-level key before any section",
    "strings": {"plain": "abc", "quote": 'say "hi"', "backslash": "C:\\data\\run.csv", "controls": "a\tb\nc\x01\x7f",
                "unicode": "µ = 67 kPa, ε₀", "empty": "", "hash": "# not a comment"},
    "numbers": {"zero": 0.0, "neg_zero": -0.0, "third": 1 / 3, "tenth": 0.1, "tiny": 5e-324,
                "huge": 1.7976931348623157e308,
                "exp": 1e16, "mixed": 123456789.123456789, "neg": -3.4e-11, "inf": math.inf, "minf": -math.inf,
                "int": 42, "neg_int": -7, "big_int": 2 ** 62, "yes": True, "no": False},
    "keys": {"a b": 1, "ü": 2, "": 3, "dotted.key": 4, "bare-key_1": 5},
    "arrays": {"empty": [], "mixed": [1, 2.5, "x", True], "nested": [[1, 2], [], ["a"]],
               "inline_tables": [{"a": 1}, 2], "flat": {"x": [1.0, 2.0], "y": {}}},
    "empty_section": {},
    "fit": {"free": ["mu_inf"], "bounds": {"mu_inf": [1e4, 1e6]},
            "result": {"mu_inf": {"value": 63846.21, "unit": "Pa", "stderr": float("nan")}}},
    "material": {"mu_inf": 67e3, "units": [{"mu": 1.0, "eta": 2.0}, {"mu": 3.0, "eta": 4.0}]},
    "traces": [
        {"file": "a.csv", "conditions": {"freq": 2.0}, "deep": {"inner": {"x": 1}}, "sub": [{"k": 1}, {"k": 2}]},
        {"file": "b.csv", "loading": {"kind": "piecewise", "times": [0.0, 1.0], "values": [0.0, 5e3]}},
    ],
}


def _same(a, b, path="") -> None:
    """Equal values, types and float bits (nan equal to nan, -0.0 not equal to 0.0)."""
    assert type(a) is type(b), (path, a, b)
    if isinstance(a, dict):
        assert list(a) == list(b), path
        for k in a:
            _same(a[k], b[k], f"{path}.{k}")
    elif isinstance(a, list):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b)):
            _same(x, y, f"{path}[{i}]")
    elif isinstance(a, float):
        assert (math.isnan(a) and math.isnan(b)) or (a == b and math.copysign(1, a) == math.copysign(1, b)), path
    else:
        assert a == b, path


def test_every_value_reads_back_the_same():
    text = dumps(DOC)
    back = tomllib.loads(text)
    _same({k: back[k] for k in DOC}, DOC)  # order: plain keys first, then sections in the document's order
    assert "[[traces]]" in text and "[[material.units]]" in text and "[fit.result]" in text
    assert 'bounds = { mu_inf = [10000.0, 1000000.0] }' in text  # a table of values only: inline
    assert dumps(back) == text  # writing what was read gives the same text


def test_numpy_scalars_are_written_as_python_numbers():
    back = tomllib.loads(dumps({"t": {"f": np.float64(0.1), "i": np.int64(3), "b": np.bool_(True)}}))
    _same(back, {"t": {"f": 0.1, "i": 3, "b": True}})


def test_comments_and_header_do_not_change_values():
    comments = {("material", "mu_inf"): "fitted: +- 1.2 kPa\nsecond line", ("material", "units", 1, "eta"): "unit 2",
                ("traces", 0): "first trace", ("fit",): "the fit"}
    text = dumps(DOC, comments, header="made by a test\nsecond line")
    _same({k: v for k, v in tomllib.loads(text).items()}, tomllib.loads(dumps(DOC)))
    lines = text.splitlines()
    assert lines[:2] == ["# made by a test", "# second line"]
    assert "mu_inf = 67000.0  # fitted: +- 1.2 kPa second line" in lines
    assert [line for line in lines if line.startswith("eta = ")] == ["eta = 2.0", "eta = 4.0  # unit 2"]
    assert lines.count("[[traces]]  # first trace") == 1 and "[fit]  # the fit" in lines


@pytest.mark.parametrize("bad, where", [({"s": {"x": object()}}, "s.x"), ({"s": {"a": [1, {2}]}}, "s.a.1"),
                                        ({"s": {1: 2}}, "keys must be strings")])
def test_unsupported_values_are_named(bad, where):
    with pytest.raises(TypeError, match=where.replace(".", r"\.")):
        dumps(bad)


def test_write_atomic_replaces_whole_or_not_at_all(tmp_path):
    p = tmp_path / "f.toml"
    assert write_atomic(p, "a = 1\n") == p and p.read_text() == "a = 1\n"
    mask = os.umask(0)
    os.umask(mask)
    assert p.stat().st_mode & 0o777 == 0o666 & ~mask
    with pytest.raises(TypeError):
        write_atomic(p, None)  # fails while writing
    assert p.read_text() == "a = 1\n" and sorted(x.name for x in tmp_path.iterdir()) == ["f.toml"]
