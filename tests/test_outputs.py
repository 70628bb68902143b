"""Post-processing (dejax.outputs): no time stepping, so no
compilation of the stepper; states are built from known deformations."""
import jax.numpy as jnp
import numpy as np
import pytest

from dejax import integrate as it
from dejax import model as mdl
from dejax import outputs as po
from dejax import scenarios
from dejax.results import read_h5, write_h5
from helpers import rest_state as _rest  # noqa: E402  (tests/helpers.py)


@pytest.fixture(scope="module")
def tube():
    return scenarios.rolled("IV", shape=(1, 4, 1), freq=30.0)


def _homogeneous(q0, A):
    q = np.asarray(q0).reshape(-1, 4, 3)
    return (q @ np.asarray(A).T).reshape(-1)


def test_strain_norm_of_homogeneous_stretch_and_rotation(tube):
    m = tube.model
    lam = np.array([1.2, 0.9, 1.05])
    q = _homogeneous(m.q0, np.diag(lam))
    exact = np.sqrt(np.sum((0.5 * (lam**2 - 1)) ** 2))
    g = np.asarray(po.strain_norm_gauss(m, q))
    n = np.asarray(po.strain_norm_nodes(q))
    assert g.shape == m.dV.shape and n.shape == (m.q0.size // 12,)
    np.testing.assert_allclose(g, exact, rtol=1e-10)
    np.testing.assert_allclose(n, exact, rtol=1e-12)
    c, s = np.cos(0.7), np.sin(0.7)
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    qr = _homogeneous(m.q0, R)
    assert np.max(np.asarray(po.strain_norm_gauss(m, qr))) < 1e-12
    assert np.max(np.asarray(po.strain_norm_nodes(qr))) < 1e-12


def test_cycle_table_of_a_known_lagging_sine():
    f, b, V, d, drift = 30.0, 1e-4, 2e7, 0.3, 1e-7
    t = np.linspace(0, 4 / f, 4 * 200 + 1)
    w = 2 * np.pi * f
    x = b * np.sin(w * t - d) + drift * t * f + 1e-4
    v = V * np.sin(w * t)
    tab = po.cycle_table(t, x, v, f)
    assert len(tab["cycle"]) == 4
    # a slow drift moves the cycle's midpoint by about drift * (k + 1/2) (to within the drift)
    np.testing.assert_allclose(tab["mean"], 1e-4 + drift * (np.arange(4) + 0.5), atol=drift)
    np.testing.assert_allclose(tab["x_max"] - tab["x_min"], 2 * b, rtol=1e-3)
    assert np.all(np.diff(tab["k_c"]) > 0)
    np.testing.assert_allclose(tab["k_c"], tab["mean"] / tab["mean"][1])
    # loop area of x against v: pi b V sin(delta) (the drift adds V * drift * ... over a
    # cycle: integral of v dx_drift = V drift f * integral sin = 0)
    np.testing.assert_allclose(tab["loop_area"], np.pi * b * V * np.sin(d), rtol=1e-3)
    assert "k_c" in po.format_cycle_table(tab)
    # fewer than one whole cycle: empty table
    assert len(po.cycle_table(t[:100], x[:100], v[:100], f)["cycle"]) == 0


def test_vtu_export_and_h5_snapshots_round_trip(tube, tmp_path):
    meshio = pytest.importorskip("meshio")
    m, mesh = tube.model, tube.extras["mesh"]
    A = np.diag([1.1, 1.0, 1.0])
    q = _homogeneous(m.q0, A)
    p = po.write_vtu(tmp_path / "a.vtu", mesh, q, phi=[1000.0], model=m)
    back = meshio.read(p)
    X = np.asarray(mesh.X)
    np.testing.assert_allclose(back.points, X @ A.T, atol=1e-15)
    np.testing.assert_allclose(back.point_data["displacement"], X @ A.T - X, atol=1e-15)
    assert back.cells_dict["hexahedron"].shape == (mesh.n_elements, 8)
    np.testing.assert_allclose(back.point_data["strain_norm"], 0.5 * (1.1**2 - 1), rtol=1e-12)
    # potential 0 V on the inner, 1000 V on the outer surface; field -1000/h radial
    pot = back.point_data["potential"]
    np.testing.assert_allclose(pot[mesh.nodes("inner")], 0.0, atol=1e-9)
    np.testing.assert_allclose(pot[mesh.nodes("outer")], 1000.0, rtol=1e-12)
    # VTK hexahedra must have positive volume (node order = VTK order)
    x = back.points[back.cells_dict["hexahedron"][0]]
    vol = np.dot(np.cross(x[1] - x[0], x[3] - x[0]), x[4] - x[0])
    assert vol > 0

    s0 = _rest(m)
    s1 = it.State(t=s0.t + 0.01, q=q, v=s0.v, qdd=s0.qdd, a=s0.a, Cv=s0.Cv)
    snaps = po.snapshots_from_states(tube, {0: s0, 10: s1})
    t = np.linspace(0, 0.01, 11)
    h5 = write_h5(tmp_path / "r.h5", t, {"x_P": np.zeros(11), "field": np.zeros(11)}, tube.params, snapshots=snaps)
    res = read_h5(h5)
    assert sorted(res["snapshots"]) == [0, 10]
    np.testing.assert_allclose(res["snapshots"][10]["q"], q)
    assert res["snapshots"][10]["strain_norm_gauss"].shape == m.dV.shape
    paths = po.vtu_from_h5(h5, tmp_path / "vtu")
    assert len(paths) == 2 and (tmp_path / "vtu" / "r.pvd").exists()
    np.testing.assert_allclose(meshio.read(paths[1]).points, X @ A.T, atol=1e-15)
