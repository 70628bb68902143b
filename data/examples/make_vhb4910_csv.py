"""Convert Hossain et al. (2012) VHB 4910 curves (data/vhb4910-hossain2012, MIT,
digitized by the vCANN project, K. Abdolazizi) into CSV traces for
vhb4910_uniaxial.toml (peak 1.5) and vhb4910_diagnose.toml (peaks 2 and 3): time
reconstructed from the constant stretch rate (fitting.datasets.reconstruct_time),
stretch (-), nominal stress (kPa).

Run: python data/examples/make_vhb4910_csv.py
"""
from pathlib import Path

import numpy as np

from fitting.datasets import load_hossain2012

HERE = Path(__file__).resolve().parent

for peak, rate in [(1.5, 0.05), (1.5, 0.01), (1.5, 0.03), (2.0, 0.01), (2.0, 0.03), (2.0, 0.05), (3.0, 0.01),
                   (3.0, 0.05)]:
    c = load_hossain2012(peak, rate)
    path = HERE / f"vhb4910_{peak:g}_{rate:g}.csv"
    with open(path, "w") as f:
        f.write(f"# VHB 4910 uniaxial loading-unloading, peak stretch {peak:g}, rate {rate:g} 1/s.\n")
        f.write("# Source: Hossain, Vu, Steinmann, Comput. Mater. Sci. 59 (2012), digitized by the vCANN project\n")
        f.write("# (MIT licence, data/vhb4910-hossain2012/LICENSE); converted by make_vhb4910_csv.py.\n")
        f.write("# time_s is reconstructed from the constant stretch rate (not measured).\n")
        f.write("time_s,stretch,stress_kPa\n")
        for t, l, s in zip(c.time, c.stretch, c.stress):
            f.write(f"{t:.6g},{l:.6g},{s / 1e3:.6g}\n")
    print("wrote", path)
