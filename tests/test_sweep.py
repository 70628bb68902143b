"""Parameter sweeps of the rolled DEA (dejax.sweep)."""
import json
import os
import subprocess
import sys
import types
import warnings

import numpy as np
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


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


# Run in a fresh process: the device count is fixed when JAX's CPU backend starts. Three
# cases on two devices: the batch is padded to four, two cases per device. It records
# where the batch's input (time grids) and output (x_P) shards lie, and the batch's series;
# the sequential reference runs in the test's own process (one device), with the settings
# of the sweep command's test in test_cli_ux.py (1x4x1, 2 cycles of 10 steps): one
# compiled program for both, loaded from the compilation cache by whichever runs second.
SHARDED_CASES = {"freq": [20.0, 40.0, 60.0]}
SHARDED_BASE = dict(phi_max=25e3)
SHARDED_KW = dict(shape=(1, 4, 1), n_cycles=2, steps_per_cycle=10, keep_series=True)
_SHARDED_SCRIPT = r"""
import json
import jax
import numpy as np
from dejax import compile_cache, sweep

if not compile_cache.disabled_by_env():
    compile_cache.enable()
placed = {}
batched = sweep._batched

def shards(a):
    return sorted([s.device.id, s.index[0].start or 0, int(s.data.shape[0])] for s in a.addressable_shards)

def spy(M, Lg, G, *rest):
    outs, status = batched(M, Lg, G, *rest)
    x = np.asarray(outs["x_P"])
    placed.update(grid=shards(G), x_P=shards(outs["x_P"]), status=shards(status), batch=int(x.shape[0]),
                  pad_minus_last=float(np.max(np.abs(x[-1] - x[-2]))))
    return outs, status

sweep._batched = spy
cases = sweep.cases_from_grid(%r, %r)
rows_v, info_v = sweep.run_sweep(cases, method="vmap", **%r)
ser = lambda rows: [dict(ok=r["ok"], **{k: np.asarray(v).tolist() for k, v in r["series"].items()}) for r in rows]
print("RESULT", json.dumps(dict(jax_devices=len(jax.devices()), placed=placed, info_v=info_v, vmap=ser(rows_v))))
""" % (SHARDED_CASES, SHARDED_BASE, SHARDED_KW)


def test_sweep_vmap_sharded_over_two_cpu_devices(tmp_path):
    """method="vmap" shards the cases over two (emulated CPU) devices and gives the
    sequential single-device results, case by case."""
    flags = [f for f in os.environ.get("XLA_FLAGS", "").split() if "xla_force_host_platform_device_count" not in f]
    env = dict(os.environ, JAX_PLATFORMS="cpu",
               XLA_FLAGS=" ".join(flags + ["--xla_force_host_platform_device_count=2"]),
               # a pool of 2 threads (2 cores) for 2 devices can deadlock in the batched LU (sweep._warn_cpu_pool)
               PJRT_NPROC="4")
    with open(tmp_path / "out", "w") as fo, open(tmp_path / "err", "w") as fe:  # files: no pipe to fill meanwhile
        proc = subprocess.Popen([sys.executable, "-c", _SHARDED_SCRIPT], cwd=ROOT, env=env, stdout=fo, stderr=fe)
        from dejax import sweep  # the sequential reference here, on this process's single device, meanwhile

        rows_s, info_s = sweep.run_sweep(sweep.cases_from_grid(SHARDED_CASES, SHARDED_BASE), method="sequential",
                                         **SHARDED_KW)
        proc.wait(timeout=600)
    out, err = (tmp_path / "out").read_text(), (tmp_path / "err").read_text()
    assert proc.returncode == 0, err[-4000:]
    res = json.loads(next(ln for ln in out.splitlines() if ln.startswith("RESULT "))[len("RESULT "):])
    res["info_s"] = info_s
    res["sequential"] = [dict(ok=r["ok"], **{k: np.asarray(v).tolist() for k, v in r["series"].items()})
                         for r in rows_s]

    assert res["jax_devices"] == 2
    assert res["info_v"]["n_devices"] == 2 and res["info_v"]["n_cases"] == 3 and res["info_v"]["n_batch"] == 4
    assert res["info_s"]["n_devices"] == 1
    # split, not replicated: each device holds two of the four cases, in and out
    for name in ("grid", "x_P", "status"):
        assert res["placed"][name] == [[0, 0, 2], [1, 2, 2]], (name, res["placed"][name])
    assert res["placed"]["batch"] == 4 and res["placed"]["pad_minus_last"] < 1e-15  # padded with the last case
    assert len(res["vmap"]) == len(res["sequential"]) == 3  # padding dropped

    for v, s in zip(res["vmap"], res["sequential"]):
        assert v["ok"] and s["ok"]
        np.testing.assert_array_equal(v["time"], s["time"])
        for k in ("x_P", "voltage", "field"):
            a, b = np.asarray(v[k]), np.asarray(s[k])
            np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-12 * np.max(np.abs(b)), err_msg=k)
    x = [np.asarray(s["x_P"]) for s in res["sequential"]]
    assert min(np.max(np.abs(xi)) for xi in x) > 1e-7  # the tube moves (m) ...
    assert np.max(np.abs(x[0] - x[2])) > 1e-2 * np.max(np.abs(x[0]))  # ... differently per case


def test_cpu_pool_warning(monkeypatch):
    """The deadlock guard warns for as many CPU devices as pool threads, not otherwise."""
    from dejax import sweep

    cpu2 = [types.SimpleNamespace(platform="cpu")] * 2
    monkeypatch.delenv("NPROC", raising=False)
    monkeypatch.setenv("PJRT_NPROC", "2")
    with pytest.warns(RuntimeWarning, match="PJRT_NPROC=4"):
        sweep._warn_cpu_pool(cpu2)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sweep._warn_cpu_pool([types.SimpleNamespace(platform="gpu")] * 2)
        monkeypatch.setenv("PJRT_NPROC", "4")
        sweep._warn_cpu_pool(cpu2)
