"""Figures of results files (dejax.plot and the plot verb): PNGs, axes with units, failed runs."""
import jax.numpy as jnp
import numpy as np
import pytest

from dejax import integrate as it
from dejax import model as mdl
from dejax import outputs as po
from dejax import scenarios
from dejax.results import write_h5
from helpers import rest_state as _rest  # noqa: E402  (tests/helpers.py)


@pytest.fixture(scope="module")
def tube():
    return scenarios.rolled("IV", shape=(1, 4, 1), freq=30.0)


def test_plot_writes_pngs(tube, tmp_path):
    from dejax import cli

    m = tube.model
    f = 30.0
    t = np.linspace(0, 3 / f, 301)
    field = 0.5 * 2.5e7 * (1 - np.cos(2 * np.pi * f * t))
    x = 1e-4 * (1 - np.cos(2 * np.pi * f * t - 0.3)) + 1e-5 * t * f
    s0 = _rest(m)
    snaps = po.snapshots_from_states(tube, {0: s0})
    h5 = write_h5(tmp_path / "r.h5", t, {"x_P": x, "v_P": np.gradient(x, t), "field": field, "voltage": field * 2e-3},
                  tube.params, snapshots=snaps)
    import argparse

    parser = argparse.ArgumentParser()
    cli.register_plot(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["plot", str(h5), "--out", str(tmp_path / "png")])
    assert args.func(args) == 0
    names = sorted(p.name for p in (tmp_path / "png").iterdir())
    assert {"r_x.png", "r_loop.png", "r_kc.png", "r_outputs.png", "r_snap0.png"} <= set(names)
    args = parser.parse_args(["plot", str(tmp_path / "missing.h5")])
    assert args.func(args) == 2


def test_outputs_figure_axes_carry_units(tmp_path, monkeypatch):
    import matplotlib.axes

    from dejax import plot
    from dejax.results import read_h5

    t = np.linspace(0.0, 1.0, 11)
    h5 = write_h5(tmp_path / "r.h5", t, {"v_P": np.sin(t), "voltage": 1e3 * t, "thickness_stretch": 1 - 0.1 * t})
    assert read_h5(h5)["units"] == {"v_P": "m/s", "voltage": "V", "thickness_stretch": "1"}
    labels = []
    setter = matplotlib.axes.Axes.set_ylabel
    monkeypatch.setattr(matplotlib.axes.Axes, "set_ylabel", lambda self, s, *a, **k: (labels.append(s),
                                                                                       setter(self, s, *a, **k))[1])
    plot.plot_file(h5, tmp_path / "png")
    assert {"v_P (m/s)", "voltage (V)", "thickness_stretch (-)"} <= set(labels)


def test_plot_of_a_failed_run_says_so(tmp_path, monkeypatch):
    import matplotlib.figure

    from dejax import plot

    t = np.linspace(0.0, 0.24, 25)
    h5 = write_h5(tmp_path / "f.h5", t, {"lateral_stretch": 1 + t, "voltage": 1e5 * t},
                  attrs=dict(status="failed", fail_time=0.25, fail_status="instability", t_last_converged=0.24))
    titles = []
    sup = matplotlib.figure.Figure.suptitle
    monkeypatch.setattr(matplotlib.figure.Figure, "suptitle",
                        lambda self, s, *a, **k: (titles.append(s), sup(self, s, *a, **k))[1])
    plot.plot_file(h5, tmp_path / "png")
    assert titles == ["run failed at t = 0.25 s (instability); data up to t = 0.24 s"]
    ok = write_h5(tmp_path / "ok.h5", t, {"voltage": t}, attrs=dict(status="ok"))
    plot.plot_file(ok, tmp_path / "png")
    assert len(titles) == 1
