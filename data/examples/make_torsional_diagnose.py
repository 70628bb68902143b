"""Regenerate the traces of torsional_diagnose.toml: a SIMULATED torsional experiment for
`dejax diagnose` on the torsional scenario.

The pre-twisted strip of paper Sec. 5 (h = 1 mm, 60 x 10 x 1 mm, one turn, 6 x 2 x 2
elements, the viscous material of Sec. 5) driven by sine voltages (paper Eq. 42 form,
0 to 8 kV), with an extra fast viscous unit the model of torsional_diagnose.toml lacks (the
``hysteresis`` effect of fitting.effects: mu 20 kPa, tau 20 ms), plus white noise of 0.05 deg
on the twist, 40 samples per cycle:

    fit:      2 Hz, 2 cycles (torsional_diag_2Hz.csv)
    fit:      5 Hz, 2 cycles (torsional_diag_5Hz.csv)
    holdout:  3.5 Hz, 2 cycles (torsional_diag_3.5Hz.csv)

Run from the repository root: python data/examples/make_torsional_diagnose.py (a minute or two).
"""
from pathlib import Path

import numpy as np

from fitting.forward import simulate_experiment

HERE = Path(__file__).resolve().parent
TRUTH = {"hysteresis": {"mu": 20e3, "tau": 0.02}}  # Pa, s
SIGMA = np.deg2rad(0.05)  # noise on the twist (rad)
PHI = 8e3  # V
CONDITIONS = [("torsional_diag_2Hz", 2.0, 2), ("torsional_diag_5Hz", 5.0, 2), ("torsional_diag_3.5Hz", 3.5, 2)]
SAMPLES_PER_CYCLE = 40


def write(name, t, angle, volt):
    with open(HERE / f"{name}.csv", "w") as fh:
        fh.write("# SIMULATED torsional experiment (make_torsional_diagnose.py): dejax strip 6x2x2, Sec. 5 viscous "
                 "material with an extra fast unit (20 kPa, 20 ms), noise 0.05 deg; not a measurement\n")
        fh.write("time_s,twist_deg,voltage_kV\n")
        for ti, ai, vi in zip(t, angle, volt):
            fh.write(f"{ti:.7f},{np.rad2deg(ai):.7f},{vi * 1e-3:.8g}\n")


def main():
    for name, f, n in CONDITIONS:  # the voltage histories; zero twist until simulated
        t = np.linspace(0.0, n / f, n * SAMPLES_PER_CYCLE + 1)
        write(name, t, np.zeros_like(t), 0.5 * PHI * (1.0 + np.sin(2 * np.pi * f * t - np.pi / 2)))
    traces, ys = simulate_experiment(HERE / "torsional_diagnose.toml", TRUTH, SIGMA, seed=4)
    for tr, y in zip(traces, ys):
        write(tr.name, np.asarray(tr.time), y, np.asarray(tr.voltage()))


if __name__ == "__main__":
    main()
