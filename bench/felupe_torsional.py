"""Independent reference for the torsional strip (paper Sec. 5): the same pre-twisted strip,
material, electrodes and supports as ``dejax.scenarios.torsional``, solved by FElupe 11.3
(``pip install felupe tensortrax``, optionally pypardiso) with tri-quadratic 27-node hexahedra (Lagrange, no nodal
gradients) and FElupe's (u, p, J) three-field form (discontinuous linear p and J per cell),
quasi-static, hyperelastic. Shares no code with dejax: geometry map, unit potential,
free energy and Newton loop are written here from the paper.

Free energy per unit reference volume (paper Eq. 18):
    psi = -mu Jm/2 ln(1 - (I1bar - 3)/Jm) + K/2 (J - 1)^2 - eps/2 J E0 . C^-1 E0,
with the nominal field E0 = -phi Grad(t(X)/h + 1/2), t(X) = -y sin(theta) + z cos(theta),
theta = 2 pi x / L, phi = phibar h sqrt(mu/eps).
Supports: x = 0 face u_x = 0; its mid-thickness line u_z = 0; its centre u_y = 0. The x = L
face keeps a common axial displacement (one tied unknown) and is free otherwise.
Twist angle: least-squares rotation about x of the x = L face's nodes about their centroid
(as dejax's ``twist_angle`` output), and the rotation of its mid-thickness line.

usage: python bench/felupe_torsional.py NX NW NT N_INCREMENTS [PHIBAR_MAX] [--out FILE.json]
e.g.   python bench/felupe_torsional.py 24 4 2 10 0.5 --out data/reference/torsional_felupe_24x4x2.json
"""
import argparse
import json
import platform
import time

import felupe as fem
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import tensortrax.math as tm

try:  # MKL Pardiso when installed, else SuperLU
    from pypardiso import spsolve as _spsolve
except ImportError:
    _spsolve = spla.spsolve

H = 1e-3  # thickness (m)
L, W = 60 * H, 10 * H
MU, K, JM, EPS = 12e3, 5e9, 15.0, 3.4e-11  # paper Sec. 5, hyperelastic case


def twist_map(P):
    """(n, 3) parameter points (u, v, w) in [0, L] x [0, W] x [0, H] -> reference positions."""
    th = 2 * np.pi * P[:, 0] / L
    s, t = P[:, 1] - W / 2, P[:, 2] - H / 2
    return np.stack([P[:, 0], s * np.cos(th) - t * np.sin(th), s * np.sin(th) + t * np.cos(th)], axis=1)


def unit_potential_gradient(X):
    """(..., 3) Grad of t(X)/H + 1/2 (1/m) at reference positions X (..., 3)."""
    rate = 2 * np.pi / L
    th = rate * X[..., 0]
    y, z = X[..., 1], X[..., 2]
    return np.stack([rate * (-y * np.cos(th) - z * np.sin(th)), -np.sin(th), np.cos(th)], axis=-1) / H


def energy(C, statevars, phi):
    """psi(C) (J/m^3), tensortrax math (FElupe's automatic differentiation); statevars
    carries the unit potential gradient (3, points, cells), constant in time."""
    J = tm.sqrt(tm.linalg.det(C))
    I1bar = J ** (-2 / 3) * tm.trace(C)
    E0 = -phi * np.asarray(statevars)
    psi = -0.5 * MU * JM * tm.log(1 - (I1bar - 3) / JM) + 0.5 * K * (J - 1) ** 2
    E0E0 = np.einsum("i...,j...->ij...", E0, E0)
    psi = psi - 0.5 * EPS * J * tm.einsum("ij...,ij...->...", tm.linalg.inv(C), E0E0)
    return psi, statevars


def solve(shape, n_inc, phibar_max, tol=1e-8, max_iter=30, verbose=True):
    nx, nw, nt = shape
    box = fem.Cube(a=(0, 0, 0), b=(L, W, H), n=(nx + 1, nw + 1, nt + 1))
    mesh = fem.mesh.convert(box, order=2, calc_midfaces=True, calc_midvolumes=True)
    P = mesh.points.copy()
    mesh.points[:] = twist_map(P)
    region = fem.RegionTriQuadraticHexahedron(mesh)
    field = fem.FieldsMixed(region, n=3)
    h = np.broadcast_to(region.h, region.h.shape[:2] + (mesh.ncells,))
    Xq = np.einsum("aqc,cai->iqc", h, mesh.points[mesh.cells])  # (3, nqp, ncells)
    grad_pot = np.moveaxis(unit_potential_gradient(np.moveaxis(Xq, 0, -1)), -1, 0)
    umat_inner = fem.Hyperelastic(energy, nstatevars=3, phi=0.0)
    umat = fem.ThreeFieldVariation(umat_inner)
    solid = fem.SolidBody(umat, field, statevars=grad_pot)

    # dof bookkeeping: full vector = [u (npoints x 3), p, J]; reduced = free dofs, tied u_x on x = L
    n_u = mesh.points.size
    n_full = sum(f.values.size for f in field.fields)
    tolx = 1e-9 * H
    at0 = np.isclose(P[:, 0], 0, atol=tolx)
    atL = np.isclose(P[:, 0], L, atol=tolx)
    mid0 = at0 & np.isclose(P[:, 2], H / 2, atol=tolx)
    centre0 = mid0 & np.isclose(P[:, 1], W / 2, atol=tolx)
    fixed = np.concatenate([3 * np.flatnonzero(at0), 3 * np.flatnonzero(mid0) + 2, 3 * np.flatnonzero(centre0) + 1])
    tied = 3 * np.flatnonzero(atL)
    keep = np.setdiff1d(np.arange(n_full), np.concatenate([fixed, tied]))
    n_red = keep.size + 1
    rows = np.concatenate([keep, tied])
    cols = np.concatenate([np.arange(keep.size), np.full(tied.size, keep.size)])
    T = sp.csr_matrix((np.ones(rows.size), (rows, cols)), shape=(n_full, n_red))

    face = np.flatnonzero(atL)
    line = np.flatnonzero(atL & np.isclose(P[:, 2], H / 2, atol=tolx))
    line = line[np.argsort(P[line, 1])]

    def twist(u):
        Y = mesh.points[face, 1:] - mesh.points[face, 1:].mean(0)
        y = Y + u[face, 1:] - u[face, 1:].mean(0)
        lsq = np.arctan2(np.sum(Y[:, 0] * y[:, 1] - Y[:, 1] * y[:, 0]), np.sum(Y[:, 0] * y[:, 0] + Y[:, 1] * y[:, 1]))
        a, b = mesh.points[line[[0, -1]], 1:] + u[line[[0, -1]], 1:]
        A, B = mesh.points[line[[0, -1]], 1:]
        d, D = b - a, B - A
        return float(lsq), float(np.arctan2(D[0] * d[1] - D[1] * d[0], D @ d))

    scale = H * np.sqrt(MU / EPS)

    def residual():
        return T.T @ np.asarray(solid.assemble.vector(field).todense()).ravel()

    def newton(phibar):
        """Equilibrium at phibar from the current state; True if converged (tol relative to
        the first residual), with the iterations; the field is left at the last iterate."""
        nonlocal field
        umat_inner.kwargs["phi"] = phibar * scale
        rr = residual()
        r0 = max(np.linalg.norm(rr), 1e-300)
        for k in range(1, max_iter + 1):
            dx = _spsolve((T.T @ solid.assemble.matrix(field) @ T).tocsr(), -rr)
            field += T @ dx
            rr = residual()
            if not np.all(np.isfinite(rr)):
                return False, k
            if np.linalg.norm(rr) <= tol * r0:
                return True, k
        return False, max_iter

    phibars = np.linspace(0.0, phibar_max, n_inc + 1)
    out = dict(phibar=[0.0], twist_angle=[0.0], twist_angle_midline=[0.0], iterations=[0], cutbacks=[0])
    tic = time.perf_counter()
    current = 0.0
    with np.errstate(invalid="ignore", divide="ignore"):
        for target in phibars[1:]:
            step, its, cuts = target - current, 0, 0
            while current < target - 1e-12:
                trial = min(current + step, target)
                saved = [f.values.copy() for f in field.fields]
                ok, k = newton(trial)
                its += k
                if ok:
                    solid.results.update_statevars()
                    current = trial
                    continue
                for f, v in zip(field.fields, saved):  # cut back: restore, halve
                    f.values[:] = v
                step, cuts = 0.5 * (trial - current), cuts + 1
                if step < 1e-6 * phibar_max:
                    raise RuntimeError(f"FElupe Newton did not converge at phibar = {trial}")
            lsq, mid = twist(field[0].values)
            for key, val in (("phibar", float(target)), ("twist_angle", lsq), ("twist_angle_midline", mid),
                             ("iterations", its), ("cutbacks", cuts)):
                out[key].append(val)
            if verbose:
                print(f"phibar {target:.3f}: twist {lsq:.6f} rad (mid-line {mid:.6f}), {its} iterations, "
                      f"{cuts} cut-backs", flush=True)
    out.update(mesh=list(shape), element="hexahedron27, (u, p, J) three-field", unknowns=int(n_red),
               n_increments=n_inc, wall_s=time.perf_counter() - tic, newton_tol=tol,
               felupe=fem.__version__, python=platform.python_version(),
               material=dict(mu=MU, K=K, Jm=JM, eps=EPS), geometry=dict(length=L, width=W, thickness=H, turns=1))
    return out


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("nx", type=int)
    ap.add_argument("nw", type=int)
    ap.add_argument("nt", type=int)
    ap.add_argument("n_increments", type=int)
    ap.add_argument("phibar_max", type=float, nargs="?", default=0.5)
    ap.add_argument("--out")
    a = ap.parse_args()
    res = solve((a.nx, a.nw, a.nt), a.n_increments, a.phibar_max)
    print(json.dumps({k: res[k] for k in ("mesh", "unknowns", "wall_s")}))
    if a.out:
        with open(a.out, "w") as f:
            json.dump(res, f, indent=1)
