"""The paper's material tables: the block (Sec. 4), Table 2 (rolled tube, Sec. 6) and the
torsional strip (Sec. 5), each with keyword overrides."""
from __future__ import annotations

from ..material import Material


def block_material(**overrides) -> Material:
    """Paper Sec. 4 block: mu_inf = mu_1 = 67 kPa, K = 6.7 GPa, eta_1 = 3000 Pa s, Jm_1 = 5,
    Jm_inf = 15, rho = 1.1 g/cm^3, eps = 4e-11 F/m."""
    p = dict(mu_inf=67e3, K_inf=6.7e9, Jm_inf=15.0, eps=4e-11, rho=1100.0, mu=[67e3], K=[6.7e9], Jm=[5.0], eta=[3000.0])
    p.update(overrides)
    return Material(**p)


TABLE2 = {
    # model: (mu_inf, [mu_s], [eta_s]) in Pa and Pa s (paper Table 2)
    "hyperelastic": (72e3, [], []),
    "I": (81e3, [80e3], [400.0]),
    "II": (78e3, [30e3, 80e3], [300.0, 200.0]),
    "III": (75e3, [10e3, 40e3, 80e3], [5000.0, 300.0, 100.0]),
    "IV": (72e3, [10e3, 10e3, 80e3, 80e3], [5000.0, 2000.0, 300.0, 100.0]),
}


def rolled_material(model: str = "IV", **overrides) -> Material:
    """Paper Sec. 6 / Table 2 material: K_inf = 3 GPa, Jm_inf = 15, K_s = 7.5 GPa, Jm_s = 5,
    rho = 1.5 g/cm^3, eps = 3.4e-11 F/m; mu and eta of the named model (I..IV, or
    "hyperelastic" = Model IV's mu_inf without viscous units)."""
    if model not in TABLE2:
        raise ValueError(f"unknown material model {model!r}; choose from {sorted(TABLE2)}")
    mu_inf, mu, eta = TABLE2[model]
    n = len(mu)
    p = dict(mu_inf=mu_inf, K_inf=3e9, Jm_inf=15.0, eps=3.4e-11, rho=1500.0, mu=mu, K=[7.5e9] * n, Jm=[5.0] * n, eta=eta)
    p.update(overrides)
    return Material(**p)


def torsional_material(viscous: bool = False, **overrides) -> Material:
    """Paper Sec. 5: rho = 1.5 g/cm^3, eps = 3.4e-11, mu_inf = 12 kPa, K_inf = 5 GPa, Jm_inf = 15;
    viscous case adds mu_1 = 80 kPa, K_1 = 7.5 GPa, Jm_1 = 5, eta_1 = 400 Pa s."""
    p = dict(mu_inf=12e3, K_inf=5e9, Jm_inf=15.0, eps=3.4e-11, rho=1500.0)
    if viscous:
        p.update(mu=[80e3], K=[7.5e9], Jm=[5.0], eta=[400.0])
    p.update(overrides)
    return Material(**p)
