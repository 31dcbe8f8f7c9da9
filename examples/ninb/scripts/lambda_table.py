"""Table of lambda over the PDAS settings: M1 then M2, run directly (no surrogates).

Runs the built-in melt_pool at each (P, v) of data/ninb_pdas.csv, feeds G0 and v (S0 = v
at the tail) into solidification, and prints a Markdown table with the measured PDAS
beside it. Parameters: the middle of their bounds, or with ``--metrics out/ninb/metrics.json``
the posterior modes of a ``calnet run``. One M1 run takes 5-90 s (``--time-limit``
2 minutes by default).

    .venv/bin/python examples/ninb/scripts/lambda_table.py [--metrics FILE] > lambda.md
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
import time
from pathlib import Path

from calnet.simulators.registry import builtin_info

HERE = Path(__file__).resolve().parents[1]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--metrics", help="metrics.json of a calnet run (posterior modes)")
    parser.add_argument("--time-limit", type=float, default=120.0,
                        help="wall-clock seconds an M1 run may take (default 120)")
    args = parser.parse_args()
    m1, m2 = builtin_info("melt_pool"), builtin_info("solidification")
    theta1, theta2 = m1.defaults(), m2.defaults()
    where = "every parameter at the middle of its bounds"
    if args.metrics:
        models = json.loads(Path(args.metrics).read_text())["calibration"]["models"]
        theta1.update({k: r["mode"] for k, r in models["melt_pool"]["parameters"].items()})
        theta2.update({k: r["mode"] for k, r in models["solidification"]["parameters"].items()})
        where = f"parameters at the posterior modes of {args.metrics}"
    rows = list(csv.DictReader((HERE / "data/ninb_pdas.csv").open()))
    print(f"melt_pool {m1.version}, solidification {m2.version}; {where}.\n")
    print("| sample | split | P (W) | v (m/s) | M1 status | G0 (K/m) | lambda (um) | k_V | "
          "planar | PDAS measured (um) | ratio |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        P, v = float(r["power_W"]), float(r["speed_m_per_s"])
        t0 = time.perf_counter()
        res1 = m1.simulate({**theta1, "P": P, "v": v}, time_limit=args.time_limit)
        wall = time.perf_counter() - t0
        if res1.status != "ok":
            print(f"| {r['sample']} | {r['split']} | {P:g} | {v:g} | {res1.status} | - | - | - "
                  f"| - | {float(r['pdas_um']):.3f} | - |")
            continue
        G0 = res1.outputs["G0"]
        res2 = m2.simulate({**theta2, "S": v, "G": G0})
        lam, kv = res2.outputs["lambda"], res2.outputs["k_V"]
        planar = "yes" if res2.outputs.get("planar") else "no"
        meas = float(r["pdas_um"])
        print(f"| {r['sample']} | {r['split']} | {P:g} | {v:g} | ok ({wall:.0f} s) | "
              f"{G0:.3g} | {lam:.3f} | {kv:.3f} | {planar} | {meas:.3f} | {lam / meas:.2f} |")
        sys.stdout.flush()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
