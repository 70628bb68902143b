"""Parameter sweeps of the rolled DEA (dejax.sweep)."""
import numpy as np
import pytest


@pytest.mark.slow
def test_sweep_sequential_and_vmap_agree():
    from dejax import sweep

    cases = sweep.cases_from_grid({"freq": [20.0, 40.0]}, dict(phi_max=25e3))
    rows_s, info_s = sweep.run_sweep(cases, (1, 4, 1), n_cycles=2, steps_per_cycle=40, method="sequential")
    rows_v, info_v = sweep.run_sweep(cases, (1, 4, 1), n_cycles=2, steps_per_cycle=40, method="vmap")
    print("sweep timings: sequential", info_s, "vmap", info_v)
    for a, b in zip(rows_s, rows_v):
        assert a["ok"] and b["ok"]
        for k in ("x_max", "x_min", "mean", "k_c", "loop_area"):
            np.testing.assert_allclose(a[k], b[k], rtol=1e-7)
    assert rows_s[0]["x_max"] > 0
