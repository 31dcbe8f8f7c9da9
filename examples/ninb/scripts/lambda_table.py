"""Before-calibration table: M1 then M2 at every PDAS setting, all parameters mid-range.

Runs the built-in melt_pool at each (P, v) of data/ninb_pdas.csv with the middle of every
thermal parameter's bounds, feeds G0 and v (S0 = v at the tail) into solidification with
its mid-range parameters, and prints a Markdown table (measured PDAS beside it). One M1
run takes 5-70 s; the whole table a few minutes on one core.

    .venv/bin/python examples/ninb/scripts/lambda_table.py > /tmp/lambda.md
"""

from __future__ import annotations

import csv
import sys
import time
from pathlib import Path

from calnet.simulators.registry import builtin_info

HERE = Path(__file__).resolve().parents[1]


def main() -> int:
    m1, m2 = builtin_info("melt_pool"), builtin_info("solidification")
    rows = list(csv.DictReader((HERE / "data/ninb_pdas.csv").open()))
    print(f"melt_pool {m1.version}, solidification {m2.version}; every parameter at the "
          "middle of its bounds.\n")
    print("| sample | split | P (W) | v (m/s) | M1 status | G0 (K/m) | lambda (um) | k_V | "
          "planar | PDAS measured (um) | ratio |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        P, v = float(r["power_W"]), float(r["speed_m_per_s"])
        t0 = time.perf_counter()
        res1 = m1.simulate({**m1.defaults(), "P": P, "v": v}, time_limit=120)
        wall = time.perf_counter() - t0
        if res1.status != "ok":
            print(f"| {r['sample']} | {r['split']} | {P:g} | {v:g} | {res1.status} | - | - | - "
                  f"| - | {float(r['pdas_um']):.3f} | - |")
            continue
        G0 = res1.outputs["G0"]
        res2 = m2.simulate({**m2.defaults(), "S": v, "G": G0})
        lam, kv = res2.outputs["lambda"], res2.outputs["k_V"]
        planar = "yes" if res2.outputs.get("planar") else "no"
        meas = float(r["pdas_um"])
        print(f"| {r['sample']} | {r['split']} | {P:g} | {v:g} | ok ({wall:.0f} s) | "
              f"{G0:.3g} | {lam:.3f} | {kv:.3f} | {planar} | {meas:.3f} | {lam / meas:.2f} |")
        sys.stdout.flush()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
