"""dejax.bench: the accuracy measure reported beside the timings (issue 10)."""
import numpy as np

from dejax import bench


def test_deviation_is_the_largest_gap_over_the_reference_peak():
    t_ref = np.linspace(0.0, 1.0, 1001)
    x_ref = np.sin(2 * np.pi * t_ref)
    # a coarser run with a known error: 1 % of the peak at t = 0.5, zero at the ends
    t = np.linspace(0.0, 1.0, 101)
    x = np.sin(2 * np.pi * t) + 0.01 * np.sin(np.pi * t) ** 8
    dev = bench.deviation(t, x, t_ref, x_ref)
    # linear interpolation of the coarse sine adds at most (2 pi dt)^2 / 8 = 4.9e-4 of the peak
    assert 0.01 - 5e-4 <= dev <= 0.01 + 5e-4
    assert bench.deviation(t_ref, x_ref, t_ref, x_ref) == 0.0


def test_reference_cache_lives_under_the_dejax_cache_dir(tmp_path, monkeypatch):
    monkeypatch.setenv("DEJAX_CACHE_DIR", str(tmp_path))
    assert bench.reference_path("tube-4x8x1") == tmp_path / "bench" / "tube-4x8x1.npz"


def test_command_cases_time_a_child_dejax_process(tmp_path):
    """F1 and D1 time whole dejax commands in a child process: its wall time, its own peak
    memory (reported by the child), and a failing command raises with its exit code."""
    import pytest

    from dejax import bench

    r = bench.run_command(["verify", "--help"], tmp_path / "cache")
    assert r["wall_s"] > 0 and 10 < r["peak_mb"] < 4000 and "verify" in r["stdout"]
    with pytest.raises(RuntimeError, match="exit 2"):
        bench.run_command(["fit", str(tmp_path / "missing.toml")], tmp_path / "cache")
    assert bench._example("vhb4910_uniaxial.toml").exists() and bench._example("block_d1.toml").exists()


def test_a_changed_cpu_reference_is_flagged():
    """The machine-speed yardstick printed beside every bench run: a change of more than
    20 % during a run is reported, a steady one is not."""
    assert bench.cpu_reference(10 ** 5) > 0
    assert bench.speed_note(1.50, 1.70) is None  # 13 %
    note = bench.speed_note(2.72, 1.74)  # 56 %, measured around a bench run on 2026-12-06
    assert note is not None and "56 %" in note and "2.72 -> 1.74" in note
    assert bench.speed_note(1.74, 2.72) is not None
