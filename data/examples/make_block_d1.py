"""Regenerate the traces of block_d1.toml (the D1 case of `dejax bench`): a SIMULATED experiment.

The DE block of paper Sec. 4 (1 element, the paper's material) driven by sine voltages
(paper Eq. 42), with an extra fast viscous unit the model of block_d1.toml does not
have (the ``hysteresis`` effect of fitting.effects: mu = 20 kPa, tau = 20 ms), plus white
noise of 1e-4 on the lateral stretch, sampled every 0.5 ms (the simulation's step):

    fit:      16 kV, 2 Hz, 2 s (block_d1_16kV_2Hz.csv, 4001 samples)
    fit:      16 kV, 8 Hz, 1 s (block_d1_16kV_8Hz.csv, 2001 samples)
    holdout:  12 kV, 20 Hz, 0.6 s (block_d1_12kV_20Hz.csv, 1201 samples)

Run from the repository root: python data/examples/make_block_d1.py (about a minute).
"""
from pathlib import Path

import numpy as np

from fitting import diagnose as dg
from fitting.forward import simulated_responses
from fitting.traces import Trace

HERE = Path(__file__).resolve().parent
TRUTH = {"hysteresis": {"mu": 2e4, "tau": 0.02}}  # Pa, s
SIGMA = 1e-4  # noise on the stretch (-)
DT = 5e-4  # s
CONDITIONS = [("block_d1_16kV_2Hz", 16e3, 2.0, 2.0), ("block_d1_16kV_8Hz", 16e3, 8.0, 1.0),
              ("block_d1_12kV_20Hz", 12e3, 20.0, 0.6)]  # name, V, Hz, s


def main():
    n_max = max(int(round(T / DT)) for *_, T in CONDITIONS)
    fwd = dg.block_forward(pad_to=n_max)
    traces = []
    for name, phi, f, T in CONDITIONS:
        t = np.linspace(0.0, T, int(round(T / DT)) + 1)
        traces.append(Trace(t, {"stretch": np.zeros_like(t)}, name=name,
                            loading={"kind": "sine", "phi_max": phi, "freq": f}, response="stretch"))
    for tr, y in zip(traces, simulated_responses(fwd, traces, TRUTH, SIGMA, seed=1)):
        name, t = tr.name, np.asarray(tr.time)
        volt = np.asarray(tr.voltage())
        with open(HERE / f"{name}.csv", "w") as fh:
            fh.write("# SIMULATED block experiment (make_block_d1.py): dejax block, paper material, an extra fast "
                     "viscous unit (mu 20 kPa, tau 20 ms), noise 1e-4; not a measurement\n")
            fh.write("time_s,stretch,voltage_kV\n")
            for ti, yi, vi in zip(t, y, volt):
                fh.write(f"{ti:.6f},{yi:.8f},{vi * 1e-3:.8g}\n")


if __name__ == "__main__":
    main()
