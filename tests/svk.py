"""Test-only St. Venant-Kirchhoff material (the one of Chrono's ANCF 3843 unit test).

Used by ``tests/test_element.py`` to reproduce Project Chrono's reference data
(``shared/reference/chrono-ancf3843/README.md``). Nothing here is part of dejax.

Conventions (Chrono README, "Kinematics, material, damping"):

* Green-Lagrange strain ``E = (F^T F - I) / 2``; Voigt vector
  ``epsilon = [E11, E22, E33, 2 E23, 2 E13, 2 E12]`` (engineering shears, order
  23, 13, 12).
* Energy density ``psi = epsilon^T D epsilon / 2`` with the isotropic 6x6 ``D``:
  normal block ``l + 2m`` on the diagonal and ``l`` off it, shear block ``m`` on
  the diagonal, no coupling. This equals the tensor form
  ``psi = l/2 tr(E)^2 + m tr(E^2)`` (checked in the tests).
* Kelvin-Voigt damping with one coefficient ``alpha`` (s): second
  Piola-Kirchhoff stress ``S = D (epsilon + alpha * epsilon_dot)``, where
  ``epsilon_dot`` is the Voigt form of ``sym(F^T F_dot)`` (diagonal
  ``F_k . F_dot_k``, shears ``F_j . F_dot_k + F_dot_j . F_k``).

The damping stress derives from the Rayleigh pseudo-potential
``phi(F, F_dot) = alpha/2 epsilon_dot^T D epsilon_dot`` (``epsilon_dot`` is
linear in ``F_dot`` with derivative ``d epsilon / d F``), so damped generalized
forces can also be obtained by automatic differentiation:
``Q = -dU/de - dPhi/de_dot``.
"""
from __future__ import annotations

import jax.numpy as jnp

# Voigt index pairs in Chrono's order: 11, 22, 33, 23, 13, 12.
VOIGT_PAIRS = ((0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1))


def lame(E_young, nu):
    """Lame constants ``(l, m)`` from Young's modulus (Pa) and Poisson's ratio."""
    l = E_young * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))
    m = E_young / (2.0 * (1.0 + nu))
    return l, m


def voigt_D(l, m):
    """(6, 6) isotropic elasticity matrix in Chrono's Voigt order (engineering shears)."""
    D = jnp.zeros((6, 6))
    D = D.at[:3, :3].set(l)
    D = D.at[jnp.arange(3), jnp.arange(3)].add(2.0 * m)
    D = D.at[jnp.arange(3, 6), jnp.arange(3, 6)].set(m)
    return D


def green_lagrange(F):
    """Green-Lagrange strain ``(F^T F - I) / 2`` of a (3, 3) deformation gradient."""
    return 0.5 * (F.T @ F - jnp.eye(3))


def voigt_strain(Et):
    """Voigt vector ``[E11, E22, E33, 2 E23, 2 E13, 2 E12]`` of a symmetric (3, 3) strain."""
    return jnp.stack(
        [Et[0, 0], Et[1, 1], Et[2, 2], 2.0 * Et[1, 2], 2.0 * Et[0, 2], 2.0 * Et[0, 1]]
    )


def voigt_strain_rate(F, Fdot):
    """Voigt strain rate of Chrono: diag ``F_k . Fdot_k``, shears ``F_j . Fdot_k + Fdot_j . F_k``.

    ``F_k`` is column k of F. Equals ``voigt_strain(sym(F^T Fdot))``.
    """
    Edot = 0.5 * (F.T @ Fdot + Fdot.T @ F)
    return voigt_strain(Edot)


def voigt_to_tensor(s):
    """Symmetric (3, 3) stress tensor from a Voigt stress vector (no factor 2 on shears)."""
    return jnp.array(
        [
            [s[0], s[5], s[4]],
            [s[5], s[1], s[3]],
            [s[4], s[3], s[2]],
        ]
    )


def psi_svk_voigt(F, l, m):
    """SVK energy density (J/m^3) in Chrono's Voigt form ``epsilon^T D epsilon / 2``."""
    eps = voigt_strain(green_lagrange(F))
    return 0.5 * eps @ voigt_D(l, m) @ eps


def psi_svk(F, l, m):
    """SVK energy density (J/m^3) in tensor form ``l/2 tr(E)^2 + m tr(E^2)``."""
    Et = green_lagrange(F)
    return 0.5 * l * jnp.trace(Et) ** 2 + m * jnp.sum(Et * Et)


def rayleigh_density(F, Fdot, l, m, alpha):
    """Kelvin-Voigt pseudo-potential ``alpha/2 epsilon_dot^T D epsilon_dot`` (W/m^3).

    Its derivative with respect to ``Fdot`` is the damping part of the first
    Piola-Kirchhoff stress, ``F S_damp`` with ``S_damp = alpha D epsilon_dot``.
    """
    ed = voigt_strain_rate(F, Fdot)
    return 0.5 * alpha * ed @ voigt_D(l, m) @ ed


def pk2_damped(F, Fdot, l, m, alpha):
    """Second Piola-Kirchhoff stress ``S = D (epsilon + alpha epsilon_dot)`` as a (3, 3) tensor."""
    eps = voigt_strain(green_lagrange(F))
    ed = voigt_strain_rate(F, Fdot)
    return voigt_to_tensor(voigt_D(l, m) @ (eps + alpha * ed))
