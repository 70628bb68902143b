"""Regenerate the traces of block_example.toml: a SIMULATED experiment, not a measurement.

The DE block of paper Sec. 4 (1 element, the paper's material) driven by a sine voltage
(paper Eq. 42) whose effective value lags the command by a first-order delay of
tau = 20 ms (the ``voltage_lag`` effect of fitting.effects, e.g. an amplifier with
limited bandwidth), plus white noise of 1e-4 on the lateral stretch. The CSVs record
the commanded voltage, as a lab would: `dejax diagnose` should name the lag.

    fit:      14 kV, 2 Hz, 2 cycles (block_14kV_2Hz.csv)
    holdout:  12 kV, 4 Hz, 2 cycles (block_12kV_4Hz.csv)

Run from the repository root: python data/examples/make_block_example.py (about a minute).
"""
from pathlib import Path

import numpy as np

from fitting import diagnose as dg

HERE = Path(__file__).resolve().parent
TRUTH = {"voltage_lag": {"tau": 0.02}}  # s
SIGMA = 1e-4  # noise on the stretch (-)
CONDITIONS = [("block_14kV_2Hz", "fit", 14e3, 2.0), ("block_12kV_4Hz", "holdout", 12e3, 4.0)]  # V, Hz


def main():
    fwd = dg.block_forward(pad_to=80)
    traces = dg.synthetic_traces(fwd, CONDITIONS, TRUTH, SIGMA, seed=0, n_cycles=2, samples_per_cycle=40)
    for tr in traces:
        volt = np.asarray(tr.voltage())
        with open(HERE / f"{tr.name}.csv", "w") as fh:
            fh.write("# SIMULATED block experiment (make_block_example.py): dejax block, paper material, "
                     "voltage lagging the command by tau = 20 ms, noise 1e-4; not a measurement\n")
            fh.write("time_s,stretch,voltage_kV\n")
            for t, y, v in zip(tr.t, tr.y, volt):
                fh.write(f"{t:.12g},{y:.9f},{v * 1e-3:.9g}\n")


if __name__ == "__main__":
    main()
