"""Regenerate the traces of tube_diagnose.toml: a SIMULATED rolled-tube experiment for
`dejax diagnose` on the rolled scenario.

The rolled DEA of paper Sec. 6 (h = r = 2 mm, L = 8 mm, 2 x 6 x 1 elements, Model I of
Table 2) driven by sine voltages (paper Eq. 42) through an amplifier with a first-order lag
the model of tube_diagnose.toml does not have (the ``voltage_lag`` effect of fitting.effects,
tau = 4 ms), plus white noise of 0.1 um on x_P, 40 samples per cycle:

    fit:      25 kV, 10 Hz, 2 cycles (tube_diag_25kV_10Hz.csv)
    fit:      25 kV, 30 Hz, 3 cycles (tube_diag_25kV_30Hz.csv)
    holdout:  20 kV, 20 Hz, 2 cycles (tube_diag_20kV_20Hz.csv)

Run from the repository root: python data/examples/make_tube_diagnose.py (a minute or two).
"""
from pathlib import Path

import numpy as np

from fitting.forward import simulate_experiment

HERE = Path(__file__).resolve().parent
TRUTH = {"voltage_lag": {"tau": 0.004}}  # s
SIGMA = 1e-7  # noise on x_P (m)
CONDITIONS = [("tube_diag_25kV_10Hz", 25e3, 10.0, 2), ("tube_diag_25kV_30Hz", 25e3, 30.0, 3),
              ("tube_diag_20kV_20Hz", 20e3, 20.0, 2)]  # name, V, Hz, cycles
SAMPLES_PER_CYCLE = 40


def write(name, t, y, volt):
    with open(HERE / f"{name}.csv", "w") as fh:
        fh.write("# SIMULATED rolled-tube experiment (make_tube_diagnose.py): dejax tube 2x6x1, Model I, an amplifier "
                 "lag of 4 ms, noise 0.1 um; not a measurement\n")
        fh.write("time_s,x_um,voltage_kV\n")
        for ti, yi, vi in zip(t, y, volt):
            fh.write(f"{ti:.7f},{yi * 1e6:.6f},{vi * 1e-3:.8g}\n")


def main():
    # placeholder files (zeros) so that the experiment loads; then the simulated traces
    for name, phi, f, n in CONDITIONS:
        t = np.linspace(0.0, n / f, n * SAMPLES_PER_CYCLE + 1)
        write(name, t, np.zeros_like(t), 0.5 * phi * (1.0 + np.sin(2 * np.pi * f * t - np.pi / 2)))
    traces, ys = simulate_experiment(HERE / "tube_diagnose.toml", TRUTH, SIGMA, seed=2)
    for tr, y in zip(traces, ys):
        write(tr.name, np.asarray(tr.time), y, np.asarray(tr.voltage()))


if __name__ == "__main__":
    main()
