"""Mesh + material + constraints -> residual, tangent and energies (paper Eqs. 21-30).

The discrete model is a ``Model`` pytree: per-Gauss-point reference data
(shape-function gradients ``G`` = A_e^T dNdxi Jinv kept in their factors, volumes
``dV``, unit-potential gradients),
element mass matrices, the material and the prescribed-motion directions are
traced arrays (differentiable in geometry and material); integer topology and
the constraint split live in a static ``Structure``.

Element force and tangent use the free energy only as a function of F
(F = e^T G is linear in the element coordinates e):

    f_e[a, i] = sum_g dV_g G_g[a, j] P_g[i, j],        P = d psi / d F
    K_e[a i, b k] = sum_g dV_g G_g[a, j] D_g[i j k l] G_g[b, l],  D = dP/dF

with D the consistent tangent (viscous update included, see
``material.stress_tangent_and_update``).
"""
from __future__ import annotations

import dataclasses
import functools
import weakref

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from . import element as el
from .constraints import Constraints
from .material import (Material, backward_euler_flow_step, bdf2_flow_step, bulk_modulus, free_energy, min_gent_margin,
                       mixed_free_energy, mixed_stress_and_update, mixed_tangent_and_update, stress_and_update,
                       stress_tangent_update_and_flow_tangent, mullins_factor)
from .mesh import Mesh, Static, content_key, reference_coordinates


@dataclasses.dataclass(frozen=True, eq=False)
class Structure:
    """Static (integer) description of a discrete model."""

    conn: np.ndarray  # (n_el, 8)
    slots: np.ndarray  # (n_el, 32) global slot index 4 node + k
    edofs: np.ndarray  # (n_el, 96) global coordinate index
    free: np.ndarray  # (n_free,) one representative coordinate per reduced unknown
    col: np.ndarray  # (n_dofs,) reduced unknown of each coordinate, -1 if constrained
    constrained: np.ndarray  # (n_constrained,)
    n_dofs: int
    gauss_order: int
    is_position: np.ndarray  # (n_free,) bool: the reduced unknown is a position (else a gradient component)
    node_sets: dict
    volumetric: str = "mixed"  # "mixed" (linear pressure), "mixed-constant", "displacement" (penalty only)
    incompressible: bool = False  # K = inf (mixed forms only): exact volume constraints per element
    pressure_basis: np.ndarray | None = None  # (n_gp, n_p) pressure shape functions at the Gauss points

    @property
    def mixed(self) -> bool:
        return self.volumetric != "displacement"

    @property
    def n_pressure(self) -> int:
        """Pressure unknowns per element: 4 (1, xi, eta, zeta), 1 (constant) or 0."""
        return 0 if self.pressure_basis is None else int(self.pressure_basis.shape[1])

    @property
    def n_free(self) -> int:
        return int(self.free.size)

    @property
    def n_nodes(self) -> int:
        return self.n_dofs // 12


class Model(eqx.Module):
    """Discrete DEA model: see the module docstring. Build with ``build_model``."""

    q0: jax.Array  # (n_dofs,) reference coordinates
    N: jax.Array  # (n_el, n_gp, 32)
    # G = dN/dX (n_el, n_gp, 32, 3) in its factors G = A_e^T dNdxi Jinv (element.element_reference_factors)
    dNdxi: jax.Array  # (n_gp, 32, 3) parametric shape gradients at the Gauss points (every element's)
    dXdxi: jax.Array  # (n_el, 8, 3, 3) nodal map derivatives dX/dxi (m): the slot transform A_e
    Jinv: jax.Array  # (n_el, n_gp, 3, 3) dxi/dX at the Gauss points (1/m)
    dV: jax.Array  # (n_el, n_gp)
    field_dirs: jax.Array  # (n_channels, n_el, n_gp, 3) Grad of unit potential (1/m)
    mass_e: jax.Array  # (n_el, 32, 32) compact element mass (kg)
    material: Material
    damping: jax.Array  # c_d (1/s): C_d = c_d M
    gravity: jax.Array  # (3,) m/s^2
    dead_load: jax.Array  # (n_dofs,) constant external generalized force (N), e.g. face_traction_load
    prescribed_dirs: jax.Array  # (n_motion_channels, n_constrained)
    _structure: Static = eqx.field(static=True)

    @property
    def structure(self) -> Structure:
        return self._structure.value

    @property
    def n_gauss(self) -> int:
        return int(self.dV.shape[1])


def build_model(
    mesh: Mesh,
    material: Material,
    constraints: Constraints | None = None,
    gauss_order: int = 3,
    damping: float = 0.0,
    gravity=(0.0, 0.0, 0.0),
    volumetric: str = "mixed",
) -> Model:
    """Assemble a ``Model`` (differentiable in mesh arrays and material).

    volumetric: "mixed" (default): a pressure field linear in the element's natural
      coordinates (p = p0 + p1 xi + p2 eta + p3 zeta, four unknowns per element) kept as its
      own Newton unknown (perturbed Lagrangian ``material.mixed_free_energy``) and condensed
      element by element, so the global system stays in the element coordinates; allows
      K = inf. "mixed-constant": one constant pressure per element (mean dilatation: too
      soft in bending with one element through a thickness). "displacement": the paper's
      pointwise penalty K/2 (J - 1)^2 (locks, and converges poorly for K/mu >~ 1e3 on the
      ANCF element without a line search; kept for the Chrono element checks).
    """
    if volumetric not in ("mixed", "mixed-constant", "displacement"):
        raise ValueError(f"volumetric must be 'mixed', 'mixed-constant' or 'displacement', got {volumetric!r}")
    incompressible = False
    try:
        incompressible = bool(np.isinf(np.asarray(bulk_modulus(material))))
    except jax.errors.TracerArrayConversionError:
        pass
    if incompressible and volumetric == "displacement":
        raise ValueError("K = inf (exact incompressibility) needs a mixed volumetric form, not 'displacement'")
    if constraints is None:
        constraints = Constraints(mesh.n_dofs)
    if constraints.n_dofs != mesh.n_dofs:
        raise ValueError(f"constraints are for {constraints.n_dofs} coordinates, mesh has {mesh.n_dofs}")
    N, dNdxi, Jinv, dV, field_dirs, mass_e, q0 = _reference_arrays(mesh.X, jnp.asarray(mesh.conn), mesh.dXdxi,
                                                                   mesh.potential, material.rho, int(gauss_order))
    try:
        dv = np.asarray(dV)
        if np.any(dv <= 0):
            e = int(np.argmin(dv.min(axis=1)))
            raise ValueError(f"element {e} has a non-positive reference volume Jacobian: check its orientation")
    except jax.errors.TracerArrayConversionError:
        pass  # a traced mesh (geometry derivatives): no orientation check possible here
    conn = mesh.conn
    slots = (4 * conn[:, :, None] + np.arange(4)).reshape(len(conn), 32)
    edofs = (3 * slots[:, :, None] + np.arange(3)).reshape(len(conn), 96)
    col, constrained, dirs, free = constraints.split()
    q0_np = None
    try:
        q0_np = np.asarray(q0)
    except jax.errors.TracerArrayConversionError:
        pass
    if q0_np is not None:
        for group in constraints.ties:
            if np.ptp(q0_np[group]) > 1e-12 * max(1.0, np.max(np.abs(q0_np[group]))):
                raise ValueError(f"tied coordinates {group[:4]}... have different reference values")
    points, _ = el.gauss_rule(int(gauss_order))
    basis = {"mixed": np.concatenate([np.ones((points.shape[0], 1)), points], axis=1),
             "mixed-constant": np.ones((points.shape[0], 1)), "displacement": None}[volumetric]
    structure = Structure(conn=conn, slots=slots, edofs=edofs, free=free, col=col, constrained=constrained,
                          n_dofs=mesh.n_dofs, gauss_order=int(gauss_order), is_position=(free % 12) < 3,
                          node_sets=dict(mesh.node_sets), volumetric=volumetric, incompressible=incompressible,
                          pressure_basis=basis)
    return Model(q0=q0, N=N, dNdxi=dNdxi, dXdxi=jnp.asarray(mesh.dXdxi), Jinv=Jinv, dV=dV, field_dirs=field_dirs,
                 mass_e=mass_e,
                 material=material, damping=jnp.asarray(damping, dtype=float), gravity=jnp.asarray(gravity, dtype=float),
                 dead_load=jnp.zeros(mesh.n_dofs), prescribed_dirs=jnp.asarray(dirs), _structure=Static(structure))


@functools.partial(jax.jit, static_argnames=("gauss_order",))
def _reference_arrays(X, conn, dXdxi, potential, rho, gauss_order: int):
    """The model's reference arrays of a mesh (X (n_nodes, 3), conn (n_el, 8), dXdxi,
    potential (n_ch, n_nodes, 4)), compiled as one program per mesh size (eager, each
    operation would be compiled on its own): N, dNdxi, Jinv, dV
    (``element.mesh_reference_factors``), field_dirs (n_ch, n_el, n_gp, 3), mass_e (n_el, 32,
    32) and q0 (n_dofs,)."""
    N, dNdxi, Jinv, dV = el.mesh_reference_factors(X, conn, dXdxi, gauss_order)
    pot = potential[:, conn, :]  # (n_ch, n_el, 8, 4)
    pot = pot.reshape(pot.shape[0], pot.shape[1], 32)
    field_dirs = jax.vmap(lambda u: _gradients_of(u[..., None], dXdxi, dNdxi, Jinv)[..., 0, :])(pot)
    # the mass integrand is of degree 6 per direction: 4 points are exact (a lower
    # stiffness rule would leave the mass matrix rank deficient)
    Nm, dVm = (N, dV) if gauss_order >= 4 else el.mesh_reference_data(X, conn, dXdxi, 4)[::2]
    mass_e = jax.vmap(el.element_mass, in_axes=(0, 0, None))(Nm, dVm, rho)
    return N, dNdxi, Jinv, dV, field_dirs, mass_e, reference_coordinates(X)


def dof_scale(model: Model) -> jax.Array:
    """(n_free,) length scale of each reduced unknown: the mean element size (cube root of
    the mean element volume, m) for positions, 1 for gradient components. Computed from
    the model's volumes, so it is right for a traced (differentiated) mesh as well; a scale
    weights norms only and carries no derivative."""
    ell = jnp.cbrt(jnp.sum(model.dV) / model.dV.shape[0])
    return jnp.where(jnp.asarray(model.structure.is_position), jax.lax.stop_gradient(ell), 1.0)


# ----------------------------------------------------------------------------- kinematics


def full_coordinates(model: Model, z: jax.Array, u: jax.Array) -> jax.Array:
    """q = q_p(t) + T z: free values z (n_free,), motion amplitudes u (n_motion,) -> q (n_dofs,)."""
    s = model.structure
    qc = model.q0[s.constrained] + u @ model.prescribed_dirs
    return expand(model, z).at[s.constrained].set(qc)


def expand(model: Model, z: jax.Array) -> jax.Array:
    """T z: reduced vector (n_free,) -> coordinates (n_dofs,), zero on constrained ones."""
    col = model.structure.col
    return jnp.where(jnp.asarray(col >= 0), z[np.maximum(col, 0)], 0.0)


def reduce(model: Model, r: jax.Array) -> jax.Array:
    """T^T r: coordinate vector (n_dofs,) -> reduced vector (n_free,) (tied entries summed)."""
    return assembly(model.structure).reduce_entries(r)


def element_coordinates(model: Model, q: jax.Array) -> jax.Array:
    """(n_el, 32, 3) element coordinates from the global vector q (n_dofs,)."""
    return q.reshape(-1, 3)[model.structure.slots]


def scatter_slots(model: Model, fe: jax.Array) -> jax.Array:
    """Sum element slot vectors (n_el, 32, 3) into a global vector (n_dofs,)."""
    return assembly(model.structure).slot_entries(fe.reshape(-1, 3)).reshape(-1)


def deformation_gradients(model: Model, q: jax.Array) -> jax.Array:
    """(n_el, n_gp, 3, 3) F at every Gauss point (Eq. 36)."""
    return _gradients_of(element_coordinates(model, q), model.dXdxi, model.dNdxi, model.Jinv)


# G = A_e^T dNdxi Jinv in its factors: the contractions over the 32 slots run on the
# parametric gradients dNdxi, the same in every element (one matrix product for the whole
# mesh, with the element and tangent-lane axes side by side), and the geometry enters
# through 3 x 3 products per point and node (a derivative with respect to h, L or r
# perturbs these alone, not 96 numbers per point). Against the per-element G (2 cores,
# alternated runs of `dejax bench --cases R1,G1 --max-steps 200` and `--cases R2
# --max-steps 100`): G1 26.4/27.1 -> 23.8/23.6 s, R2 130.6/120.7 -> 100.1/103.3 s
# projected; the residual of R2 (`python bench/profile_step.py --mesh 12x20x4`) 32-34 ->
# 26-28 ms.


def _gradients_of(qe, dXdxi, dNdxi, Jinv):
    """(n_el, n_gp, c, 3) gradients d(qe^T N)/dX at the points of element coordinates qe
    (n_el, 32, c): F for c = 3 (Eq. 36)."""
    Fxi = jnp.einsum("eai,gak->egik", el.parametric_slots(qe, dXdxi), dNdxi)  # d/dxi
    return jnp.einsum("egik,egkj->egij", Fxi, Jinv)


def nominal_field(model: Model, phi: jax.Array) -> jax.Array:
    """(n_el, n_gp, 3) nominal field E = -sum_c phi_c Grad(unit potential_c) (V/m)."""
    return -jnp.einsum("c,cegi->egi", jnp.asarray(phi, dtype=float), model.field_dirs)


def gauss_point_positions(model: Model, q: jax.Array) -> jax.Array:
    """(n_el, n_gp, 3) positions of the Gauss points for coordinates q."""
    return jnp.einsum("eai,ega->egi", element_coordinates(model, q), model.N)


# ----------------------------------------------------------------------------- forces


def initial_viscous_state(model: Model) -> jax.Array:
    """(n_el, n_gp, n_units, 3, 3) Cv = I (material at rest)."""
    n_el, n_gp = model.dV.shape
    return jnp.broadcast_to(jnp.eye(3), (n_el, n_gp, model.material.n_units, 3, 3))


def over_points(fn, in_axes):
    """vmap a point function over elements and Gauss points as one batch.

    ``in_axes`` as jax.vmap's: 0 for arguments (pytrees) whose leaves lead with (n_el,
    n_gp), None for shared ones. The two leading axes are merged before one vmap and split
    after it: one batching level fewer than vmap(vmap(fn)) when JAX traces the program (the
    material law under jacfwd is most of a simulation's tracing), the same operations for
    XLA."""
    lead_arg = in_axes.index(0)

    def mapped(*args):
        lead = jax.tree.leaves(args[lead_arg])[0].shape[:2]
        merge = lambda x: x.reshape((lead[0] * lead[1],) + x.shape[2:])  # noqa: E731 (explicit: n_units may be 0)
        flat = [a if ax is None else jax.tree.map(merge, a) for a, ax in zip(args, in_axes)]
        out = jax.vmap(fn, in_axes=in_axes)(*flat)
        return jax.tree.map(lambda y: y.reshape(lead + y.shape[1:]), out)

    return mapped


def flow_step(model: Model, state, h, method: str = "bdf2"):
    """Per-point FlowStep of the step of size h (s) from ``state`` (an integrate.State).

    "bdf2" with the state's history (Cv_prev, h_prev) where it has one, else backward
    Euler (Eq. 39). Leaves (n_el, n_gp, n_units, ...)."""
    if method == "bdf2" and state.Cv_prev is not None and state.h_prev is not None:
        return _over_points_jit(bdf2_flow_step, (0, 0, None, None))(state.Cv, state.Cv_prev, h, state.h_prev)
    return _over_points_jit(backward_euler_flow_step, (0, None))(state.Cv, h)


@functools.lru_cache(maxsize=None)
def _over_points_jit(fn, in_axes):
    """``over_points(fn, in_axes)`` jitted, one per module-level point law: a later program
    with the same number of points (another output, scan length, solver or step size)
    reuses its traced and batched form (vmap's batching is redone for every batch size)."""
    return jax.jit(over_points(fn, in_axes))


def _per_point(fn):
    """``over_points`` for fn(F, E, Cv_old, dt, mat, wmax)."""
    return _over_points_jit(fn, (0, 0, 0, None, None, 0))


def _per_point_mixed(fn):
    """``over_points`` for fn(F, E, Cv_old, dt, p, mat, wmax) (p per point)."""
    return _over_points_jit(fn, (0, 0, 0, None, 0, None, 0))


def initial_history(model: Model) -> jax.Array:
    """(n_el, n_gp) Mullins history wmax = 0 (J/m^3): the material has seen no energy."""
    return jnp.zeros(model.dV.shape)


def _history(model: Model, wmax):
    return initial_history(model) if wmax is None else wmax


def _mullins(model: Model, F, wmax):
    """(eta, wmax_new), each (n_el, n_gp): ``material.mullins_factor`` at every point."""
    return _over_points_jit(mullins_factor, (0, 0, None))(F, _history(model, wmax), model.material)


def _softening(model: Model, F, wmax):
    """(n_el, n_gp) Mullins factor eta at the deformation gradients F against the history wmax."""
    return _mullins(model, F, wmax)[0]


def mullins_history(model: Model, q, wmax_old=None) -> jax.Array:
    """(n_el, n_gp) wmax_new = max(wmax_old, W(F(q))), W the equilibrium Gent energy
    (``material.mullins_factor``): the history after a converged step."""
    return _mullins(model, deformation_gradients(model, q), wmax_old)[1]


def initial_pressure(model: Model) -> jax.Array:
    """(n_el, n_p) element pressure unknowns at rest (Pa): zero (n_p = 0 in the displacement form)."""
    return jnp.zeros((model.dV.shape[0], model.structure.n_pressure))


def _basis(model: Model):
    return jnp.asarray(model.structure.pressure_basis)


def pressure_at_points(model: Model, p) -> jax.Array:
    """(n_el, n_gp) pressure (Pa) at the Gauss points from the element unknowns p (n_el, n_p)."""
    p = initial_pressure(model) if p is None else p
    return jnp.einsum("ek,gk->eg", p, _basis(model))


def pressure_mass(model: Model) -> jax.Array:
    """(n_el, n_p, n_p) int N_k N_l dV (m^3) of the pressure shape functions."""
    return jnp.einsum("eg,gk,gl->ekl", model.dV, _basis(model), _basis(model))


def _nodal(model: Model, P):
    """(n_el, 32, 3) element force vectors sum_g dV_g G_g P_g^T from stresses (n_el, n_gp, 3, 3)."""
    return _nodal_of(model.dNdxi, model.dV, model.dXdxi, model.Jinv, P)


def _nodal_of(dNdxi, dV, dXdxi, Jinv, P):
    """``_nodal`` from G's factors (``_gradients_of``); P (n_el, n_gp, c, 3) -> (n_el, 32, c)."""
    S = jnp.einsum("eg,egij,egkj->egik", dV, P, Jinv)  # dV P Jinv^T
    return el.cartesian_slots(jnp.einsum("egik,gak->eai", S, dNdxi), dXdxi)


def element_forces(model: Model, q, E, Cv_old, dt, p=None, wmax=None):
    """Element force vectors, pressure residuals and the viscous state at the end of a step.

    Args:
      q: (n_dofs,) coordinates; E: (n_el, n_gp, 3) nominal field (V/m); Cv_old:
      (n_el, n_gp, n_units, 3, 3) at the step's start; dt: step (s); p: (n_el, n_p)
      element pressure unknowns (Pa, mixed form; None = 0); wmax: (n_el, n_gp) Mullins
      history at the step's start (J/m^3; None = 0).
    Returns:
      fe (n_el, 32, 3) in N (N m for gradient slots), g (n_el, n_p) = int N_k (J - 1 - p/K)
      dV in m^3 (None in the displacement form), Cv_new like Cv_old.
    """
    F = deformation_gradients(model, q)
    mixed = model.structure.mixed
    pts, N = (pressure_at_points(model, p), _basis(model)) if mixed else (None, None)
    body = functools.partial(_element_forces_of, model.material, N, model.dNdxi, dt)
    return over_element_chunks(body, model.dV, model.dXdxi, model.Jinv, F, E, Cv_old, pts, _history(model, wmax))


def _element_forces_of(material, N, dNdxi, dt, dV, dXdxi, Jinv, F, E, Cv_old, p, wmax):
    """``element_forces`` of a set of elements from their per-point data (as
    ``_element_system_of``)."""
    if p is None:
        P, Cv_new = _per_point(stress_and_update)(F, E, Cv_old, dt, material, wmax)
        return _nodal_of(dNdxi, dV, dXdxi, Jinv, P), None, Cv_new
    P, r_p, Cv_new = _per_point_mixed(mixed_stress_and_update)(F, E, Cv_old, dt, p, material, wmax)
    return _nodal_of(dNdxi, dV, dXdxi, Jinv, P), jnp.einsum("eg,gk,eg->ek", dV, N, r_p), Cv_new


def internal_force(model: Model, q, E, Cv_old, dt, p=None, wmax=None):
    """Internal force (n_dofs,) in N and the viscous state it implies at the end of a step
    (arguments as ``element_forces``)."""
    fe, _, Cv_new = element_forces(model, q, E, Cv_old, dt, p, wmax)
    return scatter_slots(model, fe), Cv_new


def internal_force_at(model: Model, q, E, Cv, p=None, wmax=None):
    """(n_dofs,) internal force with the viscous state Cv held fixed (no update); wmax: the
    Mullins history (n_el, n_gp) the state's softening is measured against (None = 0)."""
    F = deformation_gradients(model, q)
    mat = model.material
    soft = _softening(model, F, wmax)
    if model.structure.mixed:
        P = _over_points_jit(_mixed_stress_at, (0, 0, 0, 0, None, 0))(F, E, Cv, pressure_at_points(model, p), mat, soft)
    else:
        P = _over_points_jit(_stress_at, (0, 0, 0, None, 0))(F, E, Cv, mat, soft)
    return scatter_slots(model, _nodal(model, P))


def _stress_at(F, E, Cv, mat, soft):
    """P = d psi / dF (Pa) at one point, the viscous state Cv and the Mullins factor held."""
    return jax.grad(free_energy)(F, E, Cv, mat, True, soft)


def _mixed_stress_at(F, E, Cv, p, mat, soft):
    """``_stress_at`` of the mixed form at the point's pressure p (Pa)."""
    return jax.grad(mixed_free_energy)(F, E, Cv, p, mat, soft)


def _energy_at(F, E, Cv, mat, soft):
    """psi (J/m^3) at one point, penalty bulk terms included."""
    return free_energy(F, E, Cv, mat, True, soft)


class ElementSystem(eqx.Module):
    """Element equations at one iterate (mixed form: u and the element pressure unknowns).

    fe (n_el, 32, 3) forces; Ke (n_el, 96, 96) = d fe / d e; g (n_el, n_p) pressure
    residuals (m^3); kup (n_el, n_p, 96) = d fe / d p = d g / d e; kpp (n_el, n_p, n_p) =
    d g / d p (m^3/Pa: -int N N^T dV / K; 0 for K = inf); g, kup, kpp are None in the
    displacement form. Cv_new: the viscous state implied by this iterate; Cv_F (n_el, n_gp,
    3, 3, n_units, 3, 3) = d Cv_new / d F_kl at fixed step data (``flow_tangent``).
    """

    fe: jax.Array
    Ke: jax.Array
    g: jax.Array | None
    kup: jax.Array | None
    kpp: jax.Array | None
    Cv_new: jax.Array
    Cv_F: jax.Array


def element_system(model: Model, q, E, Cv_old, dt, p=None, wmax=None, mass_coefficient=None) -> ElementSystem:
    """Element forces and consistent tangents (arguments as ``element_forces``);
    ``mass_coefficient`` c (1/s^2): Ke = K + c M_e, the iteration matrix of a time step
    (None: K alone)."""
    F = deformation_gradients(model, q)
    mixed = model.structure.mixed
    pts, N = (pressure_at_points(model, p), _basis(model)) if mixed else (None, None)
    body = functools.partial(_element_system_of, model.material, N, model.dNdxi, dt, mass_coefficient)
    return over_element_chunks(body, model.dV, model.dXdxi, model.Jinv, F, E, Cv_old, pts, _history(model, wmax),
                               model.mass_e)


def _element_system_of(material, N, dNdxi, dt, c, dV, dXdxi, Jinv, F, E, Cv_old, p, wmax, mass_e) -> ElementSystem:
    """``element_system`` of a set of elements from their per-point data (leading axis n_el):
    dV (n_el, n_gp), dXdxi (n_el, 8, 3, 3) and Jinv (n_el, n_gp, 3, 3) (G's factors with the
    shared dNdxi (n_gp, 32, 3)), F, E, Cv_old, p (None in the displacement form), wmax,
    mass_e (n_el, 32, 32); N (n_gp, n_p) the pressure basis (shared); c the mass
    coefficient (None: none)."""
    n_el = F.shape[0]
    nodal = functools.partial(_nodal_of, dNdxi, dXdxi=dXdxi, Jinv=Jinv)

    def stiffness(D):
        G = el.gradients_from_factors(dNdxi, Jinv, dXdxi)  # (n_el, n_gp, 32, 3)
        K = jnp.einsum("eg,egaj,egklij,egbl->eaibk", dV, G, D, G).reshape(n_el, 96, 96)  # D[k, l, i, j]
        return K if c is None else K + c * _full_mass(mass_e)

    if p is None:
        P, D, Cv_new, Cv_F = _per_point(stress_tangent_update_and_flow_tangent)(F, E, Cv_old, dt, material, wmax)
        return ElementSystem(nodal(dV=dV, P=P), stiffness(D), None, None, None, Cv_new, Cv_F)
    P, r_p, D, P_p, r_pp, Cv_new, Cv_F = _per_point_mixed(mixed_tangent_and_update)(F, E, Cv_old, dt, p, material, wmax)
    Ke = stiffness(D)
    # d fe / d p_k: the forces of the stress dP/dp weighted by the pressure basis N_k
    kup = jax.vmap(lambda Nk: nodal(dV=dV * Nk, P=P_p), out_axes=1)(N.T).reshape(n_el, N.shape[1], 96)
    g = jnp.einsum("eg,gk,eg->ek", dV, N, r_p)
    kpp = jnp.einsum("eg,gk,gl,eg->ekl", dV, N, N, r_pp)
    return ElementSystem(nodal(dV=dV, P=P), Ke, g, kup, kpp, Cv_new, Cv_F)


CHUNK_ELEMENTS = 16
"""Elements per chunk of ``over_element_chunks`` (a divisor of n_el between half and twice
this where there is one)."""
CHUNK_FROM = 128
"""Meshes of at least this many elements are evaluated in chunks on the CPU."""


def over_element_chunks(fn, *args):
    """fn(*args) for per-element arguments (pytrees whose leaves have a leading n_el axis;
    None allowed) and outputs: on the CPU, for meshes of at least ``CHUNK_FROM``
    elements, about ``CHUNK_ELEMENTS`` elements at a time (``lax.map``; fn sees a chunk
    as a mesh of that many elements), so that each chunk's per-point intermediates stay
    in cache. Measured on the paper's tube 12x20x4 (960 elements, 2 cores): the stiffness
    einsum 219 -> 64 ms, the material tangent 239 -> 171 ms; on the tube 4x8x1 (32
    elements) chunks gained nothing (the material tangent lost: 3.7 -> 5.7 ms), and on a
    GPU a chunk loop would serialize the launches."""
    n_el = jax.tree_util.tree_leaves(args)[0].shape[0]
    if n_el < CHUNK_FROM or jax.default_backend() != "cpu":
        return fn(*args)
    c = _chunk_size(n_el, CHUNK_ELEMENTS)
    full = n_el // c * c
    tm = jax.tree_util.tree_map
    # explicit shapes: a -1 in a reshape fails on the empty viscous arrays of n_units = 0
    out = jax.lax.map(lambda a: fn(*a), tm(lambda x: x[:full].reshape((full // c, c) + x.shape[1:]), args))
    out = tm(lambda y: y.reshape((full,) + y.shape[2:]), out)
    if full == n_el:
        return out
    rest = fn(*tm(lambda x: x[full:], args))
    return tm(lambda y, z: jnp.concatenate([y, z]), out, rest)


def _chunk_size(n_el: int, target: int) -> int:
    """The divisor of n_el nearest ``target`` between half and twice it (no remainder to
    evaluate and concatenate), else ``target``."""
    divisors = [d for d in range(max(1, target // 2), 2 * target + 1) if n_el % d == 0]
    return min(divisors, key=lambda d: abs(d - target)) if divisors else target


def flow_tangent(model: Model, Cv_F, dq):
    """(n_el, n_gp, n_units, 3, 3) change of the step's Cv_new for a coordinate change dq
    (n_dofs,) at fixed step data: d Cv_new / d F : dF(dq), F being linear in q (Eq. 36)."""
    return jnp.einsum("egkluij,egkl->eguij", Cv_F, deformation_gradients(model, dq))


AUGMENTED_BULK = 1e4
"""K = inf: the condensed Newton matrix uses K = AUGMENTED_BULK x (mu_inf + sum mu_s) in
place of the missing pressure stiffness (the residual keeps the volume constraints exact;
the iterates then approach them at a rate of about 1 / AUGMENTED_BULK per iteration)."""


def newton_kpp(model: Model, kpp):
    """(n_el, n_p, n_p) pressure block used to condense the Newton matrix: kpp itself for
    a finite bulk modulus, -int N N^T dV / K_aug for K = inf (see AUGMENTED_BULK)."""
    if not model.structure.incompressible:
        return kpp
    mat = model.material
    return -pressure_mass(model) / (AUGMENTED_BULK * (mat.mu_inf + jnp.sum(mat.mu)))


def condense(Ke, kup, kpp):
    """Static condensation of the element pressures: Ke - kup^T kpp^-1 kup (n_el, 96, 96);
    by chunks of elements on large meshes (``over_element_chunks``: the paper's tube 46 ->
    29 ms, against 19 ms for a plain copy of Ke)."""
    return over_element_chunks(_condense_of, Ke, kup, kpp)


def _condense_of(Ke, kup, kpp):
    return Ke - jnp.einsum("eka,ekb->eab", kup, jnp.linalg.solve(kpp, kup))


class CondensedSystem(eqx.Module):
    """The mixed form's Newton matrix with the element pressures condensed, and the element
    equations it was made with: Kc = Ke - kup^T kpp^-1 kup (n_el, 96, 96), kup (n_el, n_p,
    96), kpp = ``newton_kpp`` (n_el, n_p, n_p), and at the same iterate the forces fe (n_el,
    32, 3), volume residuals g (n_el, n_p) and Cv_new (as ``ElementSystem``'s)."""

    Kc: jax.Array
    kup: jax.Array
    kpp: jax.Array
    fe: jax.Array
    g: jax.Array
    Cv_new: jax.Array


def condensed_system(model: Model, q, E, Cv_old, dt, p, wmax=None, mass_coefficient=None) -> CondensedSystem:
    """``CondensedSystem`` of the mixed form at (q, p) (arguments as ``element_system``).
    Kc is ``condense`` of ``element_system``'s matrices, but each chunk of elements
    (``over_element_chunks``) is condensed as it is made, so the uncondensed matrices of
    the whole mesh are never stored (70 MB on the paper's tube, written, zero-initialized
    and copied by the chunk loop)."""
    F = deformation_gradients(model, q)
    body = functools.partial(_condensed_system_of, model.material, _basis(model), model.dNdxi, dt, mass_coefficient)
    return over_element_chunks(body, model.dV, model.dXdxi, model.Jinv, F, E, Cv_old, pressure_at_points(model, p),
                               _history(model, wmax), model.mass_e, newton_kpp(model, None))


def _condensed_system_of(material, N, dNdxi, dt, c, dV, dXdxi, Jinv, F, E, Cv_old, p, wmax, mass_e, kpp_newton):
    """``condensed_system`` of a set of elements (``_element_system_of``'s arguments, and
    ``newton_kpp``'s block where K = inf, else None)."""
    s = _element_system_of(material, N, dNdxi, dt, c, dV, dXdxi, Jinv, F, E, Cv_old, p, wmax, mass_e)
    kpp = s.kpp if kpp_newton is None else kpp_newton
    return CondensedSystem(_condense_of(s.Ke, s.kup, kpp), s.kup, kpp, s.fe, s.g, s.Cv_new)


def pressure_force(kup, kpp, g):
    """(n_el, 96) kup^T kpp^-1 g: what condensation subtracts from the element forces."""
    return jnp.einsum("eka,ek->ea", kup, jnp.linalg.solve(kpp, g[..., None])[..., 0])


def pressure_correction(model: Model, g, kup, kpp, dq):
    """(n_el, n_p) pressure correction dp = -kpp^-1 (g + kup dq_e) for a coordinate change dq (n_dofs,)."""
    dqe = element_coordinates(model, dq).reshape(kup.shape[0], 96)
    return -jnp.linalg.solve(kpp, (g + jnp.einsum("eka,ea->ek", kup, dqe))[..., None])[..., 0]


def element_tangents(model: Model, q, E, Cv_old, dt, p=None, wmax=None):
    """Element force vectors and consistent tangents: fe (n_el, 32, 3), Ke (n_el, 96, 96),
    Cv_new. In the mixed form Ke is the tangent with the element pressures condensed
    (exact for finite K)."""
    sys = element_system(model, q, E, Cv_old, dt, p, wmax)
    if not model.structure.mixed:
        return sys.fe, sys.Ke, sys.Cv_new
    return sys.fe, condense(sys.Ke, sys.kup, newton_kpp(model, sys.kpp)), sys.Cv_new


def mass_apply(model: Model, x: jax.Array) -> jax.Array:
    """M x for x (n_dofs,): element-wise (Mc_e (x) I3) products, summed."""
    xe = element_coordinates(model, x)
    return scatter_slots(model, jnp.einsum("eab,ebi->eai", model.mass_e, xe))


def mass_elements(model: Model) -> jax.Array:
    """(n_el, 96, 96) full element mass matrices Mc_e (x) I3."""
    return _full_mass(model.mass_e)


def _full_mass(mass_e):
    """(n_el, 96, 96) Mc_e (x) I3 from compact element masses (n_el, 32, 32)."""
    return jnp.einsum("eab,ij->eaibj", mass_e, jnp.eye(3)).reshape(-1, 96, 96)


def external_force(model: Model) -> jax.Array:
    """(n_dofs,) constant external generalized force: gravity int rho N g dV = M (1 (x) g)
    summed over position slots, plus ``model.dead_load``.

    Uses the exact mass matrix: the position shape functions sum to 1 and the
    gradient functions to 0 within an element, so int rho N dV = Mc @ [1 on position slots]."""
    ones = jnp.zeros((model.mass_e.shape[0], 8, 4)).at[:, :, 0].set(1.0).reshape(-1, 32)
    fe = jnp.einsum("eab,eb,i->eai", model.mass_e, ones, model.gravity)
    return scatter_slots(model, fe) + model.dead_load


# the six faces of the 8-node element: (axis, side) -> its four corner nodes (element.NODE_CORNERS)
_FACES = {(k, sd): tuple(int(i) for i in np.flatnonzero(el.NODE_CORNERS[:, k] == sd)) for k in range(3) for sd in (-1, 1)}


def face_traction_load(mesh, node_set: str, traction, order: int = 3) -> jax.Array:
    """(n_dofs,) consistent generalized force of a uniform dead nominal traction (Pa, (3,))
    on every element face whose four corner nodes lie in ``mesh.nodes(node_set)``."""
    on = np.zeros(mesh.n_nodes, dtype=bool)
    on[mesh.nodes(node_set)] = True
    conn = np.asarray(mesh.conn)
    faces = {}  # (axis, side) -> the elements with that face in the node set
    for e, nodes in enumerate(conn):
        for face, corners in _FACES.items():
            if on[nodes[list(corners)]].all():
                faces.setdefault(face, []).append(e)
    if not faces:
        raise ValueError(f"no element face lies in node set {node_set!r}")
    f = jnp.zeros(mesh.n_dofs)
    for (axis, side), elems in faces.items():
        xi, w, tangents = el.face_rule(axis, side, order)
        f = f + _faces_load(mesh.X, mesh.dXdxi, conn[elems], np.asarray(elems), jnp.asarray(traction, dtype=float),
                            xi, w, tangents)
    return f


@jax.jit
def _faces_load(X, dXdxi, conn, elems, traction, xi, weights, tangents):
    """(n_dofs,) ``element.face_load_at`` of one face rule on the elements ``elems`` (their
    nodes ``conn``), scattered onto the mesh's coordinates: one compiled program for every
    face (of a number of elements) rather than an eager operation per Gauss point."""
    fe = jax.vmap(lambda Xe, De: el.face_load_at(Xe, De, xi, weights, tangents, traction))(X[conn], dXdxi[elems])
    f = jnp.zeros((X.shape[0], 4, 3)).at[conn].add(fe.reshape(-1, 8, 4, 3))
    return f.reshape(-1)


GATHER_WIDTH = 8
"""Contributions gathered per target (``_GatherPlan``): 8 elements share a node of a
hexahedral mesh; targets with more (tied coordinates) add their surplus by a scatter."""


class _GatherPlan:
    """How a scatter-add ``out[target[s]] += values[s]`` (target < 0: dropped) runs as a
    gather: ``index`` (n_targets, m): the first m = min(max count, GATHER_WIDTH) sources of
    every target in increasing order, padded with ``pad`` (a zero appended to the
    sources), summed per row; the rest (``extra_source`` -> ``extra_target``: sources of
    targets with more than m, e.g. a tied coordinate shared by a whole face) by a
    scatter-add. XLA:CPU runs a scatter-add as a loop of one update per source entry
    (25-30 ns each), a gather as a vectorized loop."""

    def __init__(self, target: np.ndarray, n_targets: int, pad: int):
        src = np.flatnonzero(target >= 0)
        order = np.argsort(target[src], kind="stable")
        src, t = src[order], target[src[order]]
        counts = np.bincount(t, minlength=n_targets)
        m = max(min(int(counts.max(initial=0)), GATHER_WIDTH), 1)
        rank = np.arange(src.size) - np.concatenate([[0], np.cumsum(counts)[:-1]])[t]
        first = rank < m
        itype = np.int32 if pad < 2**31 else np.int64
        self.index = np.full((n_targets, m), pad, dtype=itype)
        self.index[t[first], rank[first]] = src[first]
        self.extra_source, self.extra_target = src[~first].astype(itype), t[~first].astype(itype)

    def restricted(self, targets: np.ndarray) -> "_GatherPlan":
        """The plan of the sums of ``targets`` (increasing target numbers) alone, numbered
        0, 1, ... in that order."""
        plan = object.__new__(_GatherPlan)
        plan.index = self.index[targets]
        number = np.full(self.index.shape[0], -1, dtype=self.index.dtype)
        number[targets] = np.arange(targets.size)
        kept = number[self.extra_target] >= 0
        plan.extra_source, plan.extra_target = self.extra_source[kept], number[self.extra_target[kept]]
        return plan

    def __call__(self, values: jax.Array) -> jax.Array:
        """(n_targets,) + values.shape[1:]: the sums over the leading axis of ``values``."""
        padded = jnp.concatenate([values, jnp.zeros((1,) + values.shape[1:], values.dtype)])
        out = jnp.sum(padded[self.index], axis=1)
        if self.extra_source.size:
            out = out.at[self.extra_target].add(values[self.extra_source])
        return out


class Assembly:
    """Sparsity pattern of the reduced matrix T^T K T and the gathers that assemble it
    (numpy, built once per structure: ``assembly(structure)``).

    rows, cols (nnz,): the entries in column-major (CSC) order; indptr (n_free + 1,);
    entries: the sum of the positions in ``Ke.reshape(-1)`` (n_el * 96 * 96) that make up
    every entry (a ``_GatherPlan``); dense_index (nnz,): the entry's row-major position in
    the dense (n_free, n_free) matrix; upper, upper_entries: the entries with row >= column
    and their gather (a symmetric matrix's upper triangle, what MKL Pardiso's Cholesky
    reads). Gathering element matrix entries and summing them costs 1.1 ms on the tube
    4x8x1 (720 unknowns) where the scatter-add of the element matrices took 7-10 ms."""

    def __init__(self, structure: Structure):
        e = structure.col[structure.edofs]  # (n_el, 96) reduced index, -1 constrained
        n, n_el = structure.n_free, e.shape[0]
        r = np.broadcast_to(e[:, :, None], (n_el, 96, 96)).reshape(-1)
        c = np.broadcast_to(e[:, None, :], (n_el, 96, 96)).reshape(-1)
        kept = (r >= 0) & (c >= 0)  # constrained rows and columns dropped
        uniq, inverse = np.unique(c[kept].astype(np.int64) * n + r[kept], return_inverse=True)
        slot = np.full(r.shape, -1, dtype=np.int64)  # entry of each element matrix entry
        slot[kept] = inverse.reshape(-1)
        self.n = n
        self.nnz = int(uniq.size)
        self.rows = (uniq % n).astype(np.int32)
        self.cols = (uniq // n).astype(np.int32)
        self.indptr = np.searchsorted(self.cols, np.arange(n + 1)).astype(np.int32)
        self.entries = _GatherPlan(slot, self.nnz, n_el * 96 * 96)
        self.dense_index = (self.rows.astype(np.int64) * n + self.cols).astype(np.int32 if n * n < 2**31 else np.int64)
        # T^T r and the sum of element slot vectors, by gathers as well
        self.reduce_entries = _GatherPlan(structure.col, n, structure.n_dofs)
        self.slot_entries = _GatherPlan(structure.slots.reshape(-1), structure.n_dofs // 3, structure.slots.size)

    @functools.cached_property
    def upper(self) -> np.ndarray:
        """(nnz_upper,) positions in the CSC order of the entries with row >= column: column
        j's rows i >= j, which for a symmetric matrix are the upper triangle's row j as CSR
        (what MKL Pardiso reads of a symmetric matrix)."""
        return np.flatnonzero(self.rows >= self.cols)

    @functools.cached_property
    def upper_entries(self) -> _GatherPlan:
        """The gather of ``upper``'s entries alone from the element matrices (``entries``
        restricted to them: half the work)."""
        return self.entries.restricted(self.upper)


_ASSEMBLIES: dict = {}
_ASSEMBLY_OF = weakref.WeakKeyDictionary()  # structure object -> its Assembly (no hashing of arrays per call)


def assembly(structure: Structure) -> Assembly:
    """The structure's ``Assembly``, built once per distinct connectivity and constraint split."""
    a = _ASSEMBLY_OF.get(structure)
    if a is None:
        key = content_key((structure.edofs, structure.col, structure.slots))
        a = _ASSEMBLIES.get(key)
        if a is None:
            a = _ASSEMBLIES[key] = Assembly(structure)
        _ASSEMBLY_OF[structure] = a
    return a


def assemble_values(model: Model, Ke: jax.Array) -> jax.Array:
    """(nnz,) entries of T^T K T in ``assembly(model.structure)``'s (CSC) order, from the
    element matrices Ke (n_el, 96, 96)."""
    return assembly(model.structure).entries(Ke.reshape(-1))


def assemble_upper(model: Model, Ke: jax.Array) -> jax.Array:
    """(nnz_upper,) entries of T^T K T in ``assembly(model.structure).upper`` (a symmetric
    matrix's upper triangle as CSR), from the element matrices Ke (n_el, 96, 96)."""
    return assembly(model.structure).upper_entries(Ke.reshape(-1))


def assemble_dense(model: Model, Ke: jax.Array) -> jax.Array:
    """Dense T^T K T (n_free, n_free) from element matrices (n_el, 96, 96)."""
    a = assembly(model.structure)
    v = assemble_values(model, Ke)
    return jnp.zeros(a.n * a.n, Ke.dtype).at[a.dense_index].set(v, unique_indices=True).reshape(a.n, a.n)


# ----------------------------------------------------------------------------- energies


def free_energy_total(model: Model, q, E, Cv, p=None, wmax=None) -> jax.Array:
    """Total free energy sum_g dV psi (J), electrostatic part included (mixed form: the
    perturbed-Lagrangian energy at the element pressures p, None = 0; with Mullins softening
    the pseudo-energy eta W of the history wmax, None = 0)."""
    F = deformation_gradients(model, q)
    mat = model.material
    soft = _softening(model, F, wmax)
    if model.structure.mixed:
        pg = pressure_at_points(model, p)
        psi = _over_points_jit(mixed_free_energy, (0, 0, 0, 0, None, 0))(F, E, Cv, pg, mat, soft)
    else:
        psi = _over_points_jit(_energy_at, (0, 0, 0, None, 0))(F, E, Cv, mat, soft)
    return jnp.sum(model.dV * psi)


def kinetic_energy(model: Model, v) -> jax.Array:
    """1/2 v^T M v (J)."""
    return 0.5 * v @ mass_apply(model, v)


def gent_margins(model: Model, q, Cv) -> jax.Array:
    """(n_el, n_gp) smallest Gent margin H at each Gauss point (<= 0: limit reached)."""
    F = deformation_gradients(model, q)
    return _over_points_jit(min_gent_margin, (0, 0, None))(F, Cv, model.material)
