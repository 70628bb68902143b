"""Order of the viscous flow update in the finite-element model (issue 10, the BDF2 lever).

    python bench/flow_update_order.py

The block 1x1x1 (paper Sec. 4 material, one viscous unit, relaxation time 22 ms) under a
14 kV, 5 Hz sine voltage, quasi-static over 0.4 s, at dt = 8, 4, 2 ms with the backward
Euler (Eq. 39) and the BDF2 flow updates; the error is the largest relative deviation of
the lateral stretch from the reduced homogeneous model solved by diffrax
(``dejax.verification.models``, an independent derivation). Halving dt should divide the
error by 2 (backward Euler) and 4 (BDF2). Measured (2 cores, about 4 minutes):
backward Euler 3.9e-4, 2.0e-4, 1.03e-4; BDF2 9.1e-5, 2.4e-5, 6.0e-6.
"""
from __future__ import annotations

import numpy as np

from dejax import integrate as it
from dejax import loads, scenarios
from dejax.verification import models


def main():
    mat = scenarios.block_material()
    hist = loads.Sine(14e3, 5.0)
    p = scenarios.block(phi_max=14e3, voltage=hist, material=mat)
    for flow in ("backward-euler", "bdf2"):
        errs = []
        for dt in (8e-3, 4e-3, 2e-3):
            times = it.time_grid(0.4, dt)
            sol = it.simulate(p.model, p.loading, times, p.output_fn, it.QuasiStatic(flow_update=flow)).check()
            lam = np.asarray(sol.outputs["lateral_stretch"])
            ref = models.homogeneous_block_response(times, hist, 1e-3, 67e3, 15.0, 4e-11, [67e3], [5.0], [3000.0])
            errs.append(float(np.max(np.abs(lam - ref) / ref)))
        ratios = ", ".join(f"{errs[i] / errs[i + 1]:.2f}" for i in range(len(errs) - 1))
        print(f"{flow:>15}: errors {', '.join(f'{e:.2e}' for e in errs)} (ratios {ratios})")


if __name__ == "__main__":
    main()
