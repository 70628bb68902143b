"""Loaders of the shipped VHB measurements, checked against the raw files read independently."""
import csv
import re
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

import fitting  # noqa: F401
from fitting import datasets
from fitting.schema import DataError

DATA = Path(__file__).resolve().parents[1] / "data"
HOSSAIN = DATA / "vhb4910-hossain2012"
VHB4905 = DATA / "vhb4905-electromechanical"


def hossain_files():
    out = []
    for d in sorted(HOSSAIN.glob("stretch_*")):
        for f in sorted(d.glob("*.txt")):
            out.append((float(d.name.split("_")[1]), float(f.stem), f))
    return out


def test_licences_and_readme_shipped():
    for d in (HOSSAIN, VHB4905):
        assert "MIT License" in (d / "LICENSE").read_text(encoding="utf-8")
    readme = (DATA / "README.md").read_text(encoding="utf-8")
    for needle in ("Hossain", "vCANN", "HyperCalibration.jl", "Liao", "Dippel", "Alkhoury", "MIT"):
        assert needle in readme


def test_hossain_listing_matches_folders():
    files = hossain_files()
    assert len(files) == 11  # 4 peaks x 3 rates, 3.0 at 0.03 missing
    assert datasets.hossain2012_curves() == [(p, r) for p, r, _ in files]
    assert (3.0, 0.03) not in datasets.hossain2012_curves()


@pytest.mark.parametrize("peak, rate, path", hossain_files(), ids=lambda v: str(v) if not isinstance(v, Path) else "")
def test_hossain_curve(peak, rate, path):
    t, lam, stress = datasets.load_hossain2012(peak, rate)
    raw = np.array([[float(c) for c in line.split(",")]
                    for line in path.read_text().splitlines() if line.strip()])
    assert 88 <= len(lam) <= 128 and len(lam) == len(raw)
    np.testing.assert_array_equal(lam, raw[:, 0])
    np.testing.assert_allclose(stress, raw[:, 1] * 1e3)  # kPa -> Pa
    assert abs(lam.max() - peak) <= 0.01 * peak  # digitizing tolerance
    assert 10e3 < stress.max() < 200e3  # tens of kPa, in Pa
    # time: non-decreasing from 0; (lam - 1) / rate while loading, then back
    assert t[0] == 0.0 and np.all(np.diff(t) >= 0)
    i = int(np.argmax(lam))
    np.testing.assert_allclose(t[: i + 1], (lam[: i + 1] - 1.0) / rate, atol=1e-9)
    np.testing.assert_allclose(t[-1], (2 * lam[i] - 1.0 - lam[-1]) / rate, rtol=1e-12)


def test_hossain_missing_curve():
    with pytest.raises(DataError, match=r"available .*\(3, 0.05\)"):
        datasets.load_hossain2012(3.0, 0.03)


def raw_rows(path):
    """Rows of a VHB 4905 file read independently: bytes as Latin-1 (ids and numbers are ASCII)."""
    text = path.read_bytes().decode("latin-1")
    rows = list(csv.reader(text.splitlines(), delimiter=";"))
    return rows[0], rows[1:]


@pytest.mark.parametrize("set_name", ["set3_relaxation", "set4_loading", "set6_coupled"])
def test_vhb4905_counts_and_ranges(set_name):
    header, rows = raw_rows(VHB4905 / f"{set_name}.csv")
    counts = Counter(r[0] for r in rows)
    curves = datasets.load_vhb4905(set_name)
    assert len(curves) == len(counts)
    assert [c["id"] for c in curves] == [int(k) for k in counts]  # file order
    for c in curves:
        n = counts[str(c["id"])]
        assert len(c["stretch"]) == len(c["stress"]) == len(c["time"]) == n
        assert c["set"] == set_name
        assert 250.0 < c["temp"] < 360.0  # K (-20 to 80 C)
        assert "°C" in c["description"] and "\ufffd" not in c["description"]
        # description temperature (deg C) matches the temp column (K)
        m = re.match(r"(?:Relaxation, )?(-?\d+)°C", c["description"])
        assert m and float(m.group(1)) + 273.15 == pytest.approx(c["temp"])
        assert np.all(np.isfinite(c["stress"])) and np.all(np.isfinite(c["stretch"]))
        assert 0.95 < c["stretch"].min() and c["stretch"].max() < 10.0
        assert 1e4 < np.abs(c["stress"]).max() < 1e7  # Pa
        assert np.all(np.diff(c["time"]) >= 0)
        assert c["peak_stretch"] == c["stretch"].max()


def test_vhb4905_set_details():
    set3 = datasets.load_vhb4905("set3")
    assert len(set3) == 4
    for c, lam in zip(set3, (1.25, 2.0, 3.0, 4.0)):
        assert np.all(c["stretch"] == lam) and c["rate"] is None and c["voltage"] is None
        assert not c["time_reconstructed"]
        np.testing.assert_allclose(c["time"], np.arange(900.0, 11700.0 + 1, 900.0))
        # relaxing: decreasing overall, never rising by more than digitizing noise (~0.5 kPa steps)
        assert c["stress"][-1] < 0.8 * c["stress"][0] and np.all(np.diff(c["stress"]) < 1e3)
    set4 = datasets.load_vhb4905("set4_loading")
    assert len(set4) == 31  # as the README says
    assert {c["rate"] for c in set4} == {0.01, 0.03, 0.05, 0.1}
    assert all(c["voltage"] is None and c["time_reconstructed"] for c in set4)
    c = set4[0]  # id 100, 0.1 1/s: loading time = (peak - first stretch) / rate
    i = int(np.argmax(c["stretch"]))
    assert c["time"][i] == pytest.approx((c["stretch"][i] - c["stretch"][0]) / 0.1)
    set6 = datasets.load_vhb4905("set6_coupled")
    assert [c["voltage"] for c in set6] == [0.0, 0.0, 6000.0, 6000.0]
    assert all(c["rate"] == 0.2 and abs(c["peak_stretch"] - 3.0) < 0.03 for c in set6)
    # the applied field stiffens less: at 6 kV the peak stress is lower than at 0 V (same temperature)
    assert set6[2]["stress"].max() < set6[0]["stress"].max()
    with pytest.raises(DataError, match="unknown VHB 4905 set"):
        datasets.load_vhb4905("set5")


def test_reconstruct_time():
    t = datasets.reconstruct_time([1.0, 1.5, 2.0, 1.8, 1.2], 0.5)
    np.testing.assert_allclose(t, [0.0, 1.0, 2.0, 2.4, 3.6])
    # digitizing noise never makes time go backwards
    t = datasets.reconstruct_time([1.0, 1.5, 1.49, 2.0, 1.5, 1.52, 1.2], 1.0)
    assert np.all(np.diff(t) >= 0)
