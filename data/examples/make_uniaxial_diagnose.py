"""Regenerate the traces of uniaxial_diagnose.toml: a SIMULATED uniaxial experiment for
`dejax diagnose` on the uniaxial scenario.

A VHB-like film (Gent + one viscous unit, the model of uniaxial_diagnose.toml) with a second,
slow viscous unit the model lacks (the ``creep`` effect of fitting.effects: mu 8 kPa,
tau 10 s), stretched 1 -> 2 -> 1 at a constant rate, 100 samples per trace, white noise of
0.1 kPa on the nominal stress:

    fit:      0.1 1/s  (uniaxial_diag_0.1.csv)
    fit:      0.03 1/s (uniaxial_diag_0.03.csv)
    holdout:  0.06 1/s (uniaxial_diag_0.06.csv)

Run from the repository root: python data/examples/make_uniaxial_diagnose.py (seconds).
"""
from pathlib import Path

import numpy as np

from fitting.forward import simulate_experiment

HERE = Path(__file__).resolve().parent
TRUTH = {"creep": {"mu": 8e3, "tau": 10.0}}  # Pa, s
SIGMA = 100.0  # noise on the stress (Pa)
PEAK = 2.0
RATES = [("uniaxial_diag_0.1", 0.1), ("uniaxial_diag_0.03", 0.03), ("uniaxial_diag_0.06", 0.06)]  # name, 1/s
SAMPLES = 100


def write(name, t, lam, stress):
    with open(HERE / f"{name}.csv", "w") as fh:
        fh.write("# SIMULATED uniaxial experiment (make_uniaxial_diagnose.py): dejax uniaxial 1x1x1, Gent + 1 unit "
                 "with an extra slow unit (8 kPa, 10 s), noise 0.1 kPa; not a measurement\n")
        fh.write("time_s,stretch,stress_kPa\n")
        for ti, li, si in zip(t, lam, stress):
            fh.write(f"{ti:.7f},{li:.8f},{si * 1e-3:.6f}\n")


def main():
    for name, rate in RATES:  # the stretch histories (triangles); zero stress until simulated
        t_peak = (PEAK - 1.0) / rate
        t = np.linspace(0.0, 2.0 * t_peak, SAMPLES + 1)
        write(name, t, 1.0 + rate * (t_peak - np.abs(t - t_peak)), np.zeros_like(t))
    traces, ys = simulate_experiment(HERE / "uniaxial_diagnose.toml", TRUTH, SIGMA, seed=3)
    for tr, y in zip(traces, ys):
        write(tr.name, np.asarray(tr.time), tr.channels["stretch"], y)


if __name__ == "__main__":
    main()
