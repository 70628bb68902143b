"""Tests of the mesh generators and importer in dejax.mesh.

References are independent of the mesh code: analytic volumes, the exact
geometric maps written out here again, finite differences, and meshes
generated here and written through meshio.
"""
import numpy as np
import jax
import jax.numpy as jnp
import pytest

import dejax  # noqa: F401  (float64)
from dejax import element as E
from dejax import mesh as M

H, R, LEN = 2e-3, 2e-3, 8e-3  # paper Sec. 6 tube (m)


def ref_data(m, order=4):
    return E.mesh_reference_data(m.X, m.conn, m.dXdxi, order)


def gauss_positions(m, N):
    """(n_el, n_gp, 3) interpolated reference positions N @ e0."""
    e0 = jax.vmap(E.reference_element_coordinates)(m.X[m.conn])  # (n_el, 32, 3)
    return jnp.einsum("egs,esi->egi", N, e0)


def volumes_one_call(meshes, order=4):
    """Per-mesh dV arrays from a single mesh_reference_data call (one compile)."""
    X = jnp.concatenate([m.X for m in meshes])
    offs = np.cumsum([0] + [m.n_nodes for m in meshes])
    conn = np.concatenate([m.conn + o for m, o in zip(meshes, offs)])
    dXdxi = jnp.concatenate([m.dXdxi for m in meshes])
    dV = E.mesh_reference_data(X, conn, dXdxi, order)[2]
    cuts = np.cumsum([0] + [m.n_elements for m in meshes])
    return [dV[a:b] for a, b in zip(cuts[:-1], cuts[1:])]


def tube_volume(h, r, L):
    return np.pi * ((r + h) ** 2 - r**2) * L


# ---------------------------------------------------------------------------
# rolled tube
# ---------------------------------------------------------------------------


def test_tube_volume_converges_under_circumferential_refinement():
    exact = tube_volume(H, R, LEN)
    ns_list = (5, 10, 20, 40)
    meshes = [M.rolled_tube_mesh(H, R, LEN, shape=(1, ns, 1)) for ns in ns_list]
    errs = []
    for dV in volumes_one_call(meshes):
        assert float(dV.min()) > 0.0
        errs.append(abs(float(dV.sum()) / exact - 1.0))
    rates = [np.log(errs[i] / errs[i + 1]) / np.log(2.0) for i in range(len(errs) - 1)]
    print("tube volume rel. errors", dict(zip(ns_list, errs)), "rates", rates)
    assert errs[2] < 1e-3  # 20 circumferential elements
    assert all(rt > 3.5 for rt in rates)  # cubic Hermite-type interpolation: O(n_s^-4)


def test_tube_default_mesh_geometry():
    n_l, n_s, n_r = 12, 20, 4
    m = M.rolled_tube_mesh(H, R, LEN)  # default shape (12, 20, 4)
    assert m.n_elements == n_l * n_s * n_r
    assert m.n_nodes == (n_l + 1) * n_s * (n_r + 1)  # closed: no duplicated seam
    N, G, dV = ref_data(m, order=3)
    assert float(dV.min()) > 0.0
    assert abs(float(dV.sum()) / tube_volume(H, R, LEN) - 1.0) < 1e-4

    # Gauss-point positions against the exact map (written out independently)
    pos = np.asarray(gauss_positions(m, N))
    rho = np.hypot(pos[..., 1], pos[..., 2])
    tol = 1e-6 * R
    assert rho.min() >= R - tol and rho.max() <= R + H + tol
    assert pos[..., 0].min() >= -LEN - 1e-15 and pos[..., 0].max() <= 1e-15
    pts, _ = E.gauss_rule(3)
    ei = np.stack(np.unravel_index(np.arange(m.n_elements), (n_l, n_s, n_r)), axis=1)
    frac = (ei[:, None, :] + (1.0 + pts[None]) / 2.0) / np.array([n_l, n_s, n_r])
    u, ang, w = frac[..., 0] * LEN, frac[..., 1] * 2 * np.pi, frac[..., 2] * H
    exact = np.stack([-u, (R + w) * np.cos(ang), (R + w) * np.sin(ang)], axis=-1)
    dev = np.abs(pos - exact).max()
    rdev = np.abs(rho - (R + w)).max()
    # cubic Hermite interpolation of a circle of radius rho over an arc dtheta:
    # error <= rho dtheta^4 / 384 (about 1e-7 m here)
    bound = (R + H) * (2 * np.pi / n_s) ** 4 / 384
    print(f"tube Gauss-point max position deviation {dev:.3e} m, radius deviation {rdev:.3e} m, bound {bound:.3e} m")
    assert dev < 2 * bound

    # node sets
    X = np.asarray(m.X)
    rho_n = np.hypot(X[:, 1], X[:, 2])
    top, bottom = m.nodes("top"), m.nodes("bottom")
    inner, outer = m.nodes("inner"), m.nodes("outer")
    assert len(top) == len(bottom) == n_s * (n_r + 1)
    assert len(inner) == len(outer) == (n_l + 1) * n_s
    np.testing.assert_allclose(X[top, 0], 0.0, atol=1e-15)
    np.testing.assert_allclose(X[bottom, 0], -LEN, rtol=1e-12)
    np.testing.assert_allclose(rho_n[inner], R, rtol=1e-12)
    np.testing.assert_allclose(rho_n[outer], R + H, rtol=1e-12)
    np.testing.assert_array_equal(np.sort(M.face_nodes(m, "x", 0.0)), np.sort(top))
    assert len(m.nodes("P")) == 1 and len(m.nodes("P_outer")) == 1
    np.testing.assert_allclose(X[m.nodes("P")[0]], [0.0, R, 0.0], atol=1e-15)
    np.testing.assert_allclose(X[m.nodes("P_outer")[0]], [0.0, R + H, 0.0], atol=1e-15)
    # all nodes distinct (the periodic seam is not duplicated)
    d = np.linalg.norm(X[:, None] - X[None], axis=-1) + np.eye(len(X))
    assert d.min() > 1e-6 * H

    # radial unit potential
    assert m.n_channels == 1
    phi = np.asarray(m.potential[0])
    np.testing.assert_allclose(phi[inner, 0], 0.0, atol=1e-12)
    np.testing.assert_allclose(phi[outer, 0], 1.0, atol=1e-12)
    e_rho = np.stack([np.zeros_like(rho_n), X[:, 1] / rho_n, X[:, 2] / rho_n], axis=1)
    np.testing.assert_allclose(phi[:, 1:], e_rho / H, rtol=0, atol=1e-9 / H)


def test_tube_jvp_of_volume_matches_fd_and_analytic():
    def vol(h, r, L):
        m = M.rolled_tube_mesh(h, r, L, shape=(1, 20, 1))
        return ref_data(m)[2].sum()

    p = (H, R, LEN)
    analytic = (
        2 * np.pi * (R + H) * LEN,  # d/dh
        2 * np.pi * H * LEN,  # d/dr
        np.pi * ((R + H) ** 2 - R**2),  # d/dL
    )
    # forward mode (jacfwd = vmapped jvp: one compile for the three tangents)
    jac = jax.jacfwd(lambda q: vol(q[0], q[1], q[2]))(jnp.array(p))
    for i in range(3):
        dvol = jac[i]
        eps = 1e-6 * p[i]
        pp = list(p)
        pm = list(p)
        pp[i] += eps
        pm[i] -= eps
        fd = (float(vol(*pp)) - float(vol(*pm))) / (2 * eps)
        print(f"dV/dp{i}: jvp {float(dvol):.6e} fd {fd:.6e} analytic {analytic[i]:.6e}")
        assert abs(float(dvol) / fd - 1) < 1e-3
        assert abs(float(dvol) / analytic[i] - 1) < 1e-3


def test_tube_jvp_of_positions_and_potential():
    def fields(h, r, L):
        m = M.rolled_tube_mesh(h, r, L, shape=(2, 6, 1))
        return m.X, m.dXdxi, m.potential

    p = (H, R, LEN)
    jacs = jax.jacfwd(lambda q: fields(q[0], q[1], q[2]))(jnp.array(p))  # one forward pass, 3 tangents
    for i in range(3):
        tang = [j[..., i] for j in jacs]
        eps = 1e-7 * p[i]
        pp, pm = list(p), list(p)
        pp[i] += eps
        pm[i] -= eps
        for a, b, c in zip(tang, fields(*pp), fields(*pm)):
            fd = (np.asarray(b) - np.asarray(c)) / (2 * eps)
            scale = max(np.abs(fd).max(), np.abs(np.asarray(b)).max() / p[i])  # round-off level of fd
            np.testing.assert_allclose(np.asarray(a), fd, rtol=1e-5, atol=1e-6 * scale)


def test_tube_rejects_zero_radius():
    with pytest.raises(ValueError, match=r"\br\b.*small positive"):
        M.rolled_tube_mesh(H, 0.0, LEN)
    with pytest.raises(ValueError, match="h must be > 0"):
        M.rolled_tube_mesh(-1.0, R, LEN)


# ---------------------------------------------------------------------------
# twisted strip
# ---------------------------------------------------------------------------

LT, WT, HT = 60e-3, 10e-3, 1e-3


def test_strip_volume_and_twist():
    m = M.twisted_strip_mesh()
    assert m.n_elements == 768
    _, _, dV = ref_data(m, order=3)
    assert float(dV.min()) > 0.0
    err = abs(float(dV.sum()) / (LT * WT * HT) - 1.0)
    print(f"strip volume rel. error {err:.2e}")
    assert err < 1e-6

    X = np.asarray(m.X)
    x0, x1 = m.nodes("x0"), m.nodes("x1")
    np.testing.assert_allclose(X[x0, 0], 0.0, atol=1e-15)
    np.testing.assert_allclose(X[x1, 0], LT, rtol=1e-12)
    # one full turn: the x = L face coincides with the x = 0 face
    np.testing.assert_allclose(X[x1, 1:], X[x0, 1:], atol=1e-12 * WT)
    # every node lies in its cross-section rotated by theta(x)
    th = 2 * np.pi * X[:, 0] / LT
    s = X[:, 1] * np.cos(th) + X[:, 2] * np.sin(th)
    t = -X[:, 1] * np.sin(th) + X[:, 2] * np.cos(th)
    assert np.abs(s).max() <= WT / 2 * (1 + 1e-12) and np.abs(t).max() <= HT / 2 * (1 + 1e-12)
    np.testing.assert_allclose(t[m.nodes("top")], HT / 2, rtol=1e-10)
    np.testing.assert_allclose(t[m.nodes("bottom")], -HT / 2, rtol=1e-10)


@pytest.mark.parametrize("turns", [0.25, 0.5])
def test_strip_end_face_rotation(turns):
    m = M.twisted_strip_mesh(turns=turns, shape=(8, 2, 1))
    X = np.asarray(m.X)
    a = 2 * np.pi * turns
    Rm = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    yz0 = X[m.nodes("x0"), 1:]
    yz1 = X[m.nodes("x1"), 1:]
    np.testing.assert_allclose(yz1, yz0 @ Rm.T, atol=1e-12 * WT)
    # the x = 0 face is the untwisted rectangle
    np.testing.assert_allclose(np.sort(np.unique(np.round(yz0[:, 0] / WT, 12))), [-0.5, 0.0, 0.5])
    np.testing.assert_allclose(np.sort(np.unique(np.round(yz0[:, 1] / HT, 12))), [-0.5, 0.5])


def test_strip_potential_normal_to_mid_surface():
    m = M.twisted_strip_mesh()
    X = np.asarray(m.X)
    phi = np.asarray(m.potential[0])
    np.testing.assert_allclose(phi[m.nodes("bottom"), 0], 0.0, atol=1e-10)
    np.testing.assert_allclose(phi[m.nodes("top"), 0], 1.0, atol=1e-10)
    g = phi[:, 1:]
    k = 2 * np.pi / LT
    th = k * X[:, 0]
    s = X[:, 1] * np.cos(th) + X[:, 2] * np.sin(th)
    t = -X[:, 1] * np.sin(th) + X[:, 2] * np.cos(th)
    # tangents of the surface t = const (the mid-surface for t = 0): d/dx and d/ds
    T1 = np.stack([np.ones_like(th), -k * (s * np.sin(th) + t * np.cos(th)), k * (s * np.cos(th) - t * np.sin(th))], 1)
    T2 = np.stack([np.zeros_like(th), np.cos(th), np.sin(th)], 1)
    gn = np.linalg.norm(g, axis=1)
    assert np.abs(np.einsum("ni,ni->n", g, T1)).max() < 1e-9 * gn.max()
    assert np.abs(np.einsum("ni,ni->n", g, T2)).max() < 1e-9 * gn.max()
    # cross-sectional part has magnitude 1/thickness; full magnitude sqrt(1+(s k)^2)/thickness
    np.testing.assert_allclose(np.linalg.norm(g[:, 1:], axis=1), 1 / HT, rtol=1e-12)
    np.testing.assert_allclose(gn, np.sqrt(1 + (s * k) ** 2) / HT, rtol=1e-12)
    axis = np.abs(s) < 1e-12
    assert axis.sum() > 0
    np.testing.assert_allclose(gn[axis], 1 / HT, rtol=1e-12)


def test_strip_jvp_of_volume():
    def vol(length, width, thickness):
        m = M.twisted_strip_mesh(length, width, thickness, shape=(12, 2, 1))
        return ref_data(m, order=3)[2].sum()

    p = jnp.array([LT, WT, HT])
    analytic = (WT * HT, LT * HT, LT * WT)
    jac = jax.jacfwd(lambda q: vol(q[0], q[1], q[2]))(p)
    for i in range(3):
        assert abs(float(jac[i]) / analytic[i] - 1) < 1e-3


# ---------------------------------------------------------------------------
# meshio import
# ---------------------------------------------------------------------------


def hex_box(n, lengths, perturb=0.0, seed=0):
    """Structured hexahedral box written independently: points (n_pts, 3) and
    VTK-ordered cells; interior nodes optionally perturbed at random."""
    nx, ny, nz = n
    g = np.stack(np.meshgrid(*[np.linspace(0, lengths[d], n[d] + 1) for d in range(3)], indexing="ij"), -1)
    pid = np.arange((nx + 1) * (ny + 1) * (nz + 1)).reshape(nx + 1, ny + 1, nz + 1)
    pts = g.reshape(-1, 3).copy()
    if perturb:
        rng = np.random.default_rng(seed)
        h = np.array(lengths) / np.array(n)
        interior = np.ones(pid.shape, bool)
        for d in range(3):
            sl = [slice(None)] * 3
            sl[d] = 0
            interior[tuple(sl)] = False
            sl[d] = -1
            interior[tuple(sl)] = False
        ii = pid[interior]
        pts[ii] += perturb * h * rng.uniform(-1, 1, (len(ii), 3))
    offs = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)]
    cells = np.array(
        [[pid[i + a, j + b, k + c] for a, b, c in offs] for i in range(nx) for j in range(ny) for k in range(nz)]
    )
    return pts, cells


def test_meshio_box_roundtrip(tmp_path):
    meshio = pytest.importorskip("meshio")
    lengths = (3e-3, 2e-3, 1e-3)
    pts, cells = hex_box((3, 2, 2), lengths)
    path = tmp_path / "box.vtu"
    meshio.write(path, meshio.Mesh(pts, [("hexahedron", cells)]))
    m = M.mesh_from_meshio(
        path,
        potential_maps=[lambda X: X[2] / lengths[2]],
        node_sets={"x0": lambda X: np.abs(X[:, 0]) < 1e-12, "corner": [0]},
    )
    assert m.n_elements == 12 and m.n_nodes == len(pts)
    N, G, dV = ref_data(m, order=3)
    assert float(dV.min()) > 0
    np.testing.assert_allclose(float(dV.sum()), np.prod(lengths), rtol=1e-12)
    e0 = jax.vmap(E.reference_element_coordinates)(m.X[m.conn])
    F = jax.vmap(E.deformation_gradient)(e0, G)  # (n_el, n_gp, 3, 3)
    np.testing.assert_allclose(np.asarray(F), np.broadcast_to(np.eye(3), F.shape), atol=1e-12)
    np.testing.assert_allclose(np.asarray(m.potential[0, :, 1:]), np.tile([0, 0, 1 / lengths[2]], (m.n_nodes, 1)))
    np.testing.assert_array_equal(m.nodes("x0"), M.face_nodes(m, 0, 0.0))
    assert len(m.nodes("x0")) == 3 * 3
    np.testing.assert_array_equal(m.nodes("corner"), [0])


def test_meshio_distorted_and_flipped_cells():
    meshio = pytest.importorskip("meshio")
    lengths = (2.0, 1.5, 1.0)
    pts, cells = hex_box((3, 3, 2), lengths, perturb=0.25)
    # flip half of the cells (top/bottom faces swapped: negatively oriented)
    flipped = cells.copy()
    flipped[::2] = flipped[::2][:, [4, 5, 6, 7, 0, 1, 2, 3]]
    for c in (cells, flipped):
        m = M.mesh_from_meshio(meshio.Mesh(pts, [("hexahedron", c)], point_sets={"p0": np.array([0])}))
        N, G, dV = ref_data(m, order=3)
        assert float(dV.min()) > 0
        # boundary unchanged, interior perturbed: total volume is still the box's
        np.testing.assert_allclose(float(dV.sum()), np.prod(lengths), rtol=1e-12)
        e0 = jax.vmap(E.reference_element_coordinates)(m.X[m.conn])
        F = jax.vmap(E.deformation_gradient)(e0, G)
        np.testing.assert_allclose(np.asarray(F), np.broadcast_to(np.eye(3), F.shape), atol=1e-10)
        # Gauss-point positions reproduce each cell's trilinear map
        P, _ = E.gauss_rule(3)
        tri = np.prod(1 + E.NODE_CORNERS[None] * P[:, None], axis=2) / 8  # (n_gp, 8)
        exact = np.einsum("gj,ejm->egm", tri, np.asarray(m.X)[m.conn])
        np.testing.assert_allclose(np.asarray(gauss_positions(m, N)), exact, atol=1e-12)
        np.testing.assert_array_equal(m.nodes("p0"), [0])


def test_meshio_drops_unused_points_and_mixed_blocks():
    meshio = pytest.importorskip("meshio")
    pts, cells = hex_box((1, 1, 1), (1.0, 1.0, 1.0))
    pts = np.vstack([pts, [[5.0, 5.0, 5.0]]])  # orphan point
    quad = np.array([[0, 1, 3, 2]])
    m = M.mesh_from_meshio(meshio.Mesh(pts, [("quad", quad), ("hexahedron", cells)]))
    assert m.n_nodes == 8 and m.n_elements == 1
    np.testing.assert_allclose(float(ref_data(m, 2)[2].sum()), 1.0, rtol=1e-12)


def test_meshio_errors(tmp_path):
    meshio = pytest.importorskip("meshio")
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    with pytest.raises(ValueError, match="tetra"):
        M.mesh_from_meshio(meshio.Mesh(pts, [("tetra", np.array([[0, 1, 2, 3]]))]))
    bad = tmp_path / "bad.vtu"
    bad.write_text("this is not a mesh")
    with pytest.raises(ValueError, match="could not read"):
        M.mesh_from_meshio(bad)
    with pytest.raises(FileNotFoundError):
        M.mesh_from_meshio(tmp_path / "missing.vtu")
    # tangled cell: two nodes of the bottom face swapped
    hp, hc = hex_box((1, 1, 1), (1.0, 1.0, 1.0))
    with pytest.raises(ValueError, match="tangled"):
        M.mesh_from_meshio(meshio.Mesh(hp, [("hexahedron", hc[:, [0, 1, 3, 2, 4, 5, 6, 7]])]))


def test_face_nodes():
    m = M.block_mesh(1e-3, shape=(2, 2, 2))
    np.testing.assert_array_equal(np.sort(M.face_nodes(m, "z", 1e-3)), np.sort(m.nodes("z1")))
    np.testing.assert_array_equal(np.sort(M.face_nodes(m, 0, 0.0)), np.sort(m.nodes("x0")))
    with pytest.raises(ValueError, match="no node"):
        M.face_nodes(m, 1, 0.3e-3)


def test_content_key_and_static_compare_by_content():
    """Equal topologies built twice share one compiled program: keys by content, not identity."""
    a = np.arange(6, dtype=np.int64).reshape(2, 3)
    same = {"c": a.copy(), "n": [np.arange(2)]}
    assert M.content_key({"c": a, "n": [np.arange(2)]}) == M.content_key(same)
    assert hash(M.Static(same)) == hash(M.Static({"c": a, "n": [np.arange(2)]}))
    assert M.Static(same) == M.Static({"c": a, "n": [np.arange(2)]})
    for other in (a.astype(np.int32), a.reshape(3, 2), a + 1, (a,)):
        assert M.content_key(other) != M.content_key(a)
    assert M.Static(a) != M.Static(a + 1)
