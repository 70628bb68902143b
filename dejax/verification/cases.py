"""Verification cases against independent references; ``dejax verify`` prints the table.

Each case returns ``Check`` rows (case, reference, error, tolerance, passed). The
references are independent of the finite-element code: the reduced homogeneous
block model solved with diffrax (``dejax.verification.models``), the closed-form Gent
equilibrium, theory of the generalized-alpha scheme (order 2, energy
conservation at rho_inf = 1) and Project Chrono's element data. Tests call the
same case functions at reduced sizes.
"""
from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .. import constraints as cs
from .. import integrate as it
from .. import loads
from .. import model as mdl
from .. import scenarios
from ..material import Material
from ..mesh import block_mesh
from . import data_path
from . import models


@dataclasses.dataclass
class Check:
    case: str
    reference: str
    error: float
    tolerance: float
    seconds: float = float("nan")

    @property
    def passed(self) -> bool:
        return bool(np.isfinite(self.error) and self.error <= self.tolerance)


def block_runs(phis, shape, t_end, dt, material, gauss_order=3, t_ramp=1.0):
    """(times (n+1,), lateral stretch (n_phi, n+1), Newton iterations (n_phi, n)) of the ANCF
    block for several peak voltages.

    One compilation serves every voltage (the voltage is a traced leaf of the loading).
    The runs are sequential: under vmap, Newton's refactor/keep branch would run both."""
    prob = scenarios.block(phi_max=phis[0], shape=shape, material=material, t_ramp=t_ramp, gauss_order=gauss_order)
    times = it.time_grid(t_end, dt)
    lams, iters = [], []
    for phi in phis:
        loading = it.Loading(voltages=(loads.RampHold(float(phi), t_ramp),))
        sol = it.simulate(prob.model, loading, times, prob.output_fn).check()
        lams.append(np.asarray(sol.outputs["lateral_stretch"]))
        iters.append(np.asarray(sol.iterations))
    return times, np.stack(lams), np.stack(iters)


def block_vs_reduced(phis=(8e3, 12e3, 16e3), shapes=((1, 1, 1), (2, 2, 2)), t_end=3.0, dt=1e-3, tol=1e-3):
    """ANCF block (Sec. 4 parameters) against the diffrax solution of the reduced model:
    max relative error of the lateral stretch over [0, t_end]."""
    mat = scenarios.block_material()
    rows = []
    for shape in shapes:
        tic = time.perf_counter()
        times, lam, _ = block_runs(phis, shape, t_end, dt, mat)
        secs = time.perf_counter() - tic
        for k, phi in enumerate(phis):
            ref = models.homogeneous_block_response(
                times, models.eq41(phi), 1e-3, 67e3, 15.0, 4e-11, [67e3], [5.0], [3000.0]
            )
            err = float(np.max(np.abs(lam[k] - ref) / ref))
            name = f"block {'x'.join(map(str, shape))} viscous, phi_m = {phi / 1e3:g} kV, 0-{t_end:g} s"
            rows.append(Check(name, "reduced model (diffrax)", err, tol, secs / len(phis)))
    return rows


def block_vs_closed_form(phis=(4e3, 8e3, 12e3, 16e3, 20e3), t_end=1.5, dt=1e-3, tol=1e-4):
    """Hyperelastic block after a 1 s ramp against the closed-form Gent equilibrium."""
    mat = scenarios.block_material(mu=[], K=[], Jm=[], eta=[])
    tic = time.perf_counter()
    times, lam, _ = block_runs(phis, (1, 1, 1), t_end, dt, mat)
    secs = time.perf_counter() - tic
    rows = []
    for k, phi in enumerate(phis):
        ref = models.gent_equibiaxial_stretch(phi, 1e-3, 67e3, 15.0, 4e-11)
        err = float(abs(lam[k, -1] - ref) / ref)
        rows.append(Check(f"block hyperelastic quasi-static, {phi / 1e3:g} kV", "closed-form Gent equilibrium", err, tol, secs / len(phis)))
    return rows


# ----------------------------------------------------------------------------- generalized alpha


def _vibrating_element():
    """One compressible hyperelastic element clamped on x = 0: a small vibrating problem."""
    m = block_mesh(1e-2, shape=(1, 1, 1))
    c = cs.Constraints(m.n_dofs).fix(cs.face_dofs(m.nodes("x0"), 0, [0, 1, 2]))
    mat = Material(mu_inf=1e4, K_inf=2e4, Jm_inf=100.0, eps=0.0, rho=1000.0)
    return mdl.build_model(m, mat, c, gauss_order=3), m


class _Energy(eqx.Module):
    """Output function: total (kinetic + free) energy and the coordinates q."""

    def __call__(self, model, loading, state):
        E = jnp.zeros(model.dV.shape + (3,))
        return {
            "energy": mdl.kinetic_energy(model, state.v) + mdl.free_energy_total(model, state.q, E, state.Cv, state.p),
            "q": state.q,
        }


def _free_vibration(model, v0, t_end, dt, rho_inf, pad_to=None):
    s0 = it.initial_state(model, v=v0)
    return it.simulate(model, it.Loading(), it.time_grid(t_end, dt), _Energy(), it.GeneralizedAlpha(rho_inf),
                       it.NewtonOptions(tol=1e-12, criterion="correction"), state0=s0, pad_to=pad_to).check()


def _lowest_mode_velocity(model, amplitude):
    """Initial velocity along the lowest eigenmode of (K, M) at the reference state, scaled
    so that the largest nodal speed is ``amplitude`` (m/s). Exciting one resolved mode keeps
    the unresolved high ANCF modes (damped differently at every dt) out of the comparison."""
    from scipy.linalg import eigh

    E = jnp.zeros(model.dV.shape + (3,))
    _, Ke, _ = mdl.element_tangents(model, model.q0, E, mdl.initial_viscous_state(model), 1.0)
    K = np.asarray(mdl.assemble_dense(model, Ke))
    M = np.asarray(mdl.assemble_dense(model, mdl.mass_elements(model)))
    w2, modes = eigh(K, M)
    v = np.asarray(mdl.expand(model, jnp.asarray(modes[:, 0])))
    pos = v.reshape(-1, 4, 3)[:, 0, :]
    return jnp.asarray(v * amplitude / np.max(np.abs(pos))), float(np.sqrt(w2[0]))


def generalized_alpha_order(dts=(4e-4, 2e-4, 1e-4), periods=2.0, tol=0.3):
    """Observed order of accuracy of q(t_end) against a dt/16 solution; expect 2.

    One hyperelastic element vibrating in its lowest mode (small amplitude)."""
    model, _ = _vibrating_element()
    v0, omega = _lowest_mode_velocity(model, 1e-3)
    t_end = periods * 2 * np.pi / omega
    tic = time.perf_counter()
    pad = int(np.ceil(t_end / (dts[-1] / 16))) + 1
    ref = _free_vibration(model, v0, t_end, dts[-1] / 16, 0.8, pad).outputs["q"][-1]
    errs = [float(jnp.max(jnp.abs(_free_vibration(model, v0, t_end, dt, 0.8, pad).outputs["q"][-1] - ref))) for dt in dts]
    orders = [np.log(errs[i] / errs[i + 1]) / np.log(dts[i] / dts[i + 1]) for i in range(len(dts) - 1)]
    order = float(orders[-1])
    return [Check(f"generalized-alpha order {order:.2f} (rho_inf 0.8; errors {', '.join(f'{e:.1e}' for e in errs)})",
                  "theory: 2", abs(order - 2.0), tol, time.perf_counter() - tic)]


def generalized_alpha_energy(n_steps=1000, dt=2e-4, tol=1e-3):
    """rho_inf = 1, no damping, no viscosity: relative energy drift of a free vibration."""
    model, mesh = _vibrating_element()
    v0, _ = _lowest_mode_velocity(model, 1e-2)
    tic = time.perf_counter()
    e = np.asarray(_free_vibration(model, v0, n_steps * dt, dt, 1.0).outputs["energy"])
    drift = float(np.max(np.abs(e - e[0])) / e[0])
    return [Check(f"energy conservation, rho_inf = 1, {n_steps} steps", "conservation law", drift, tol,
                  time.perf_counter() - tic)]


# ----------------------------------------------------------------------------- element


def element_vs_chrono(tol=1e-9):
    """Mass matrix of one ANCF element against Project Chrono's reference file (shipped in
    ``dejax/verification/data``; FileNotFoundError naming it when absent)."""
    from ..element import element_mass, element_reference_data, gauss_rule, NODE_CORNERS

    ref = np.loadtxt(data_path("chrono-ancf3843", "UT_ANCFBrick_3843_MassMatrix.txt"))
    P, W = gauss_rule(7)
    N, _, dV = element_reference_data(jnp.asarray(NODE_CORNERS * 0.5 + 0.5), jnp.broadcast_to(0.5 * jnp.eye(3), (8, 3, 3)), P, W)
    err = float(np.max(np.abs(np.asarray(element_mass(N, dV, 7850.0)) - ref)) / np.max(np.abs(ref)))
    return [Check("ANCF element mass matrix", "Project Chrono ANCF 3843", err, tol)]


def check_groups(quick: bool = False) -> list:
    """[(label, () -> list[Check])] of the verification, in the order they run."""
    return [
        ("element vs Project Chrono", element_vs_chrono),
        ("block vs closed-form Gent equilibrium",
         block_vs_closed_form if not quick else lambda: block_vs_closed_form(phis=(8e3, 16e3))),
        ("block vs reduced model (diffrax)", block_vs_reduced if not quick else
         lambda: block_vs_reduced(phis=(12e3,), shapes=((1, 1, 1),), t_end=1.5)),
        ("generalized-alpha order", generalized_alpha_order),
        ("generalized-alpha energy", generalized_alpha_energy),
    ]


def run_all(quick: bool = False, groups=None, progress=None) -> list[Check]:
    """Run the check groups (default ``check_groups(quick)``); ``progress(k, n, label, wall_s)``
    is called before group k (1-based) and with k = n + 1, label "done" at the end."""
    import time

    groups = check_groups(quick) if groups is None else groups
    rows, tic = [], time.perf_counter()
    for k, (label, run) in enumerate(groups, 1):
        if progress is not None:
            progress(k, len(groups), label, time.perf_counter() - tic)
        rows += run()
    if progress is not None:
        progress(len(groups) + 1, len(groups), "done", time.perf_counter() - tic)
    return rows


def stderr_progress(k: int, n: int, label: str, wall: float) -> None:
    """``run_all`` progress on stderr: ``[verify 2/5] label ... (12 s so far)``."""
    import sys

    text = (f"[verify] {n} groups done in {wall:.0f} s" if k > n else
            f"[verify {k}/{n}] {label} ... ({wall:.0f} s so far; each group compiles its simulations)")
    sys.stderr.write(text + "\n")
    sys.stderr.flush()


def format_table(rows: list[Check]) -> str:
    w = max(len(r.case) for r in rows)
    wr = max(len(r.reference) for r in rows)
    lines = [f"{'case':<{w}}  {'reference':<{wr}}  {'error':>9}  {'tolerance':>9}  result"]
    lines.append("-" * len(lines[0]))
    for r in rows:
        lines.append(f"{r.case:<{w}}  {r.reference:<{wr}}  {r.error:9.2e}  {r.tolerance:9.1e}  {'pass' if r.passed else 'FAIL'}")
    n_ok = sum(r.passed for r in rows)
    lines.append(f"{n_ok} passed, {len(rows) - n_ok} failed")
    return "\n".join(lines)


def main(quick: bool = False, json_path=None, quiet: bool = False) -> bool:
    rows = run_all(quick, progress=None if quiet else stderr_progress)
    print(format_table(rows))
    if json_path:
        Path(json_path).write_text(json.dumps([dict(dataclasses.asdict(r), passed=r.passed) for r in rows], indent=2))
    return all(r.passed for r in rows)
