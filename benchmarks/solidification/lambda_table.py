"""Print M2's spacing, k_V and planar flag at the 11 PDAS settings, beside the measurements.

S = v (identity link, method.md section 1). G is not computed from M1 here: it is set to
two stated values, 1e7 K/m (reference design space) and 4e6 K/m (a prototype M1's G0 at
150 W, 0.5 m/s, physics.md M2). Parameters default to the physics.md worked check
(sigma 2e-6 J/cm^2, M 7.5 cm^4/(J s), p_int 15000 cm^3/(J s)); k_V and planar do not
depend on G.

Usage::

    python benchmarks/solidification/lambda_table.py [--data PATH] [--variant A|B]
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np

from calnet.simulators import solidification as m2

DEFAULT_DATA = Path(__file__).resolve().parents[2] / "examples" / "ninb" / "data" / "ninb_pdas.csv"
G_VALUES = (1e7, 4e6)  # K/m
PARAMS = {"sigma": 2e-6, "M": 7.5, "p_int": 15000.0}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    parser.add_argument("--variant", choices=m2.VARIANTS, default="A")
    args = parser.parse_args()
    with args.data.open(newline="") as f:
        rows = list(csv.DictReader(f))
    v = np.array([float(r["speed_m_per_s"]) for r in rows])
    out = {G: m2.simulate_batch(v, G, **PARAMS, variant=args.variant) for G in G_VALUES}
    print(f"M2 variant {args.variant}, S = v, parameters {PARAMS}\n")
    print("| sample | split | P (W) | v (m/s) | measured PDAS (um) | lambda, G 1e7 K/m (um) "
          "| lambda, G 4e6 K/m (um) | k_V | planar |")
    print("|---:|---|---:|---:|---:|---:|---:|---:|---|")
    first = out[G_VALUES[0]]
    for i, r in enumerate(rows):
        planar = "yes" if first["planar"][i] else "no"
        print(f"| {r['sample']} | {r['split']} | {r['power_W']} | {v[i]:.3f} | "
              f"{float(r['pdas_um']):.3f} | {out[1e7]['lambda'][i]:.3f} | "
              f"{out[4e6]['lambda'][i]:.3f} | {first['k_V'][i]:.3f} | {planar} |")


if __name__ == "__main__":
    main()
