"""Regenerate the synthetic example traces of tube_example.toml.

PLACEHOLDER DATA: these traces are NOT measurements and NOT simulations. They
are closed-form curves with the qualitative features of the paper's rolled-DEA
response (a lagging periodic displacement whose mean creeps upward), made
only so that the experiment file format can be exercised and tested. They are
to be replaced by traces simulated with dejax (`dejax run`).

    x(t) = X0 (1 + c (1 - exp(-t / tau))) (1 - cos(2 pi f t - delta)) / 2
    phi(t) = phi_max / 2 (1 + sin(2 pi f t + 1.5 pi))        (paper Eq. 42)

Run from anywhere: python data/examples/make_synthetic.py
"""
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
X0, C, TAU, DELTA, PHI_MAX = 0.1e-3, 0.1, 0.1, 0.3, 25e3  # m, -, s, rad, V
HEADER = ("# SYNTHETIC placeholder trace (closed form, see make_synthetic.py), not a measurement;\n"
          "# to be replaced by a dejax simulation. f = {f} Hz, phi_max = 25 kV.\n")


def response(t, f):
    return X0 * (1 + C * (1 - np.exp(-t / TAU))) * 0.5 * (1 - np.cos(2 * np.pi * f * t - DELTA))


def main():
    # fit trace: 30 Hz, 5 cycles, 50 samples per cycle; time in s, displacement in mm
    f = 30.0
    t = np.arange(5 * 50 + 1) / (50 * f)
    with open(HERE / "trace_30Hz.csv", "w") as fh:
        fh.write(HEADER.format(f=f))
        fh.write("time_s,displacement_mm\n")
        for ti, xi in zip(t, response(t, f)):
            fh.write(f"{ti:.12g},{xi * 1e3:.9g}\n")
    # holdout trace: 10 Hz, 3 cycles, 50 samples per cycle; time in ms, displacement in um, voltage in kV
    f = 10.0
    t = np.arange(3 * 50 + 1) / (50 * f)
    phi = 0.5 * PHI_MAX * (1 + np.sin(2 * np.pi * f * t + 1.5 * np.pi))
    with open(HERE / "trace_10Hz.csv", "w") as fh:
        fh.write(HEADER.format(f=f))
        fh.write("t_ms,x_um,U_kV\n")
        for ti, xi, vi in zip(t, response(t, f), phi):
            fh.write(f"{ti * 1e3:.12g},{xi * 1e6:.9g},{vi * 1e-3:.9g}\n")


if __name__ == "__main__":
    main()
