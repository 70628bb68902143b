"""Root cause of the uniaxial Newton failure (issue 9): which factor makes or breaks it.

One element, Gent mu = 15 kPa, Jm = 60, K/mu = 1e4, the paper's pointwise penalty, stretch
1 -> 3 at 0.05 1/s with dt = 1 s, full Newton, no cut-back; each line flips one factor
(scheme, convergence test, line search). Run: python bench/root_cause_factors.py
"""
import numpy as np, jax
jax.config.update("jax_enable_x64", True)
from dejax import scenarios, loads, integrate as it
from dejax.material import Material
mat = Material(mu_inf=15e3, K_inf=1.5e8, Jm_inf=60.0, eps=4e-11, rho=1000.0)
p = scenarios.uniaxial(loads.PiecewiseLinear([0, 40.0], [1.0, 3.0]), mat, volumetric="displacement")
times = it.time_grid(40.0, 1.0)
cases = {
  "old: GA(0), correction 1e-9, no LS": (it.GeneralizedAlpha(0.0), it.NewtonOptions(reuse=False, tol=1e-9, criterion="correction", line_search=False, max_iter=40)),
  "QS, correction 1e-9, no LS": (it.QuasiStatic(), it.NewtonOptions(reuse=False, tol=1e-9, criterion="correction", line_search=False, max_iter=40)),
  "GA(0), residual 1e-6, no LS": (it.GeneralizedAlpha(0.0), it.NewtonOptions(reuse=False, line_search=False, max_iter=40)),
  "GA(0), correction 1e-9, LS": (it.GeneralizedAlpha(0.0), it.NewtonOptions(reuse=False, tol=1e-9, criterion="correction", line_search=True, max_iter=40)),
}
for name, (sch, nw) in cases.items():
    sol = it.simulate(p.model, p.loading, times, p.output_fn, sch, nw, control=None)
    its = np.asarray(sol.iterations)
    print(f"{name}: ok={sol.ok} fail_t={sol.fail_time} its={its[:8]}")
