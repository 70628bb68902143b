"""Results files (dejax.results): HDF5 written atomically with units, read back; output paths
checked before any computation."""
import json
import os

import h5py
import numpy as np
import pytest

from dejax import results as R
from dejax import scenarios


def test_write_read_round_trip_with_units_params_and_snapshots(tmp_path):
    p = scenarios.block(phi_max=8e3)
    t = np.linspace(0.0, 1.0, 5)
    out = {"lateral_stretch": 1 + 0.01 * t, "voltage": 8e3 * t}
    snap = {"t": 1.0, "q": np.arange(6.0), "phi": np.array([8e3])}
    path = R.write_h5(tmp_path / "r.h5", t, out, p.params, iterations=np.array([3, 2, 2, 1]),
                      snapshots={4: snap}, attrs={"status": "ok", "dt": 0.25})
    res = R.read_h5(path)
    np.testing.assert_array_equal(res["time"], t)
    np.testing.assert_array_equal(res["outputs"]["voltage"], out["voltage"])
    assert res["units"] == {"lateral_stretch": "1", "voltage": "V"}
    np.testing.assert_array_equal(res["iterations"], [3, 2, 2, 1])
    assert res["snapshots"][4]["t"] == 1.0 and list(res["snapshots"][4]["q"]) == list(range(6))
    a = res["attrs"]
    assert a["scenario"] == "block" and a["status"] == "ok" and a["dejax_version"]
    np.testing.assert_allclose(a["eta"], [3000.0])
    units = json.loads(a["units"])
    assert units["mu_inf"] == "Pa" and units["eta"] == "Pa s" and units["dt"] == "s" and "status" not in units
    with h5py.File(path) as f:
        assert f["time"].attrs["units"] == "s" and f["snapshots/4/q"].attrs["units"].startswith("m")
    assert [n for n in os.listdir(tmp_path)] == ["r.h5"]  # no temporary file left


def test_unit_of():
    assert R.unit_of("x_P") == "m" and R.unit_of("mu") == "Pa" and R.unit_of("nonsense") == "unknown"


def test_output_paths_are_checked_before_anything_is_written(tmp_path):
    (tmp_path / "a-file").write_text("x")
    with pytest.raises(R.OutputPathError, match="is a directory"):
        R.check_output_path(tmp_path)
    with pytest.raises(R.OutputPathError, match="does not exist"):
        R.check_output_path(tmp_path / "missing" / "r.h5")
    with pytest.raises(R.OutputPathError, match="is a file, not a folder"):
        R.check_output_dir(tmp_path / "a-file")
    assert R.check_output_dir(tmp_path / "new" / "deeper") == tmp_path / "new" / "deeper"
    assert not (tmp_path / "new").exists()
    with pytest.raises(R.OutputPathError):
        R.write_h5(tmp_path / "missing" / "r.h5", [0.0], {})
    with pytest.raises(FileNotFoundError, match="does not exist"):
        R.read_h5(tmp_path / "none.h5")
