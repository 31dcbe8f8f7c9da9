"""The G0 envelope of the melt_pool campaign at the experimental settings.

Derives bounds for the solidification input ``G`` (K/m) from the shipped melt_pool runs:
for every experimental (P, v) in ``examples/ninb/data/*.csv``, take the ``--k`` ok runs
nearest in (P, v) (each coordinate scaled to its design range; the runs' theta are spread
over the whole parameter box by the Latin hypercube), and record the min and max of their
G0. The envelope is the min and max over all settings; the suggested bounds widen it by
the factor ``--margin`` on each side (log scale) and round outward to two significant
figures. Usage, from the repository root::

    .venv/bin/python benchmarks/campaign/g_envelope.py
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np
import pandas as pd

from calnet.campaign import load_runs
from calnet.spec import load_spec

ROOT = Path(__file__).resolve().parents[2]


def _round(x: float, up: bool) -> float:
    scale = 10.0 ** (math.floor(math.log10(x)) - 1)
    return (math.ceil if up else math.floor)(x / scale) * scale


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spec", default=str(ROOT / "examples" / "ninb"))
    parser.add_argument("--k", type=int, default=15)
    parser.add_argument("--margin", type=float, default=1.5)
    args = parser.parse_args()
    network = load_spec(args.spec, read_data=False)
    table = load_runs(network, "melt_pool")
    model = network.model("melt_pool")
    cols = [table.columns.index("P"), table.columns.index("v")]
    span = np.array([[model.variable(n).lower, model.variable(n).upper] for n in ("P", "v")])
    runs_pv = (table.X[:, cols] - span[:, 0]) / (span[:, 1] - span[:, 0])
    g0 = table.Y["G0"]
    settings = pd.concat([pd.read_csv(p)[["power_W", "speed_m_per_s"]]
                          for p in sorted(network.path("data").glob("*.csv"))])
    lows, highs = [], []
    for P, v in settings.drop_duplicates().to_numpy():
        point = (np.array([P, v]) - span[:, 0]) / (span[:, 1] - span[:, 0])
        near = np.argsort(np.linalg.norm(runs_pv - point, axis=1))[:args.k]
        lows.append(g0[near].min())
        highs.append(g0[near].max())
    lo, hi = min(lows), max(highs)
    print(f"ok melt_pool runs: {table.n_ok} of {table.n_total} ({table.status_counts})")
    print(f"experimental settings: {len(lows)}; k = {args.k} nearest runs in scaled (P, v)")
    print(f"G0 envelope: [{lo:.4g}, {hi:.4g}] K/m; all runs: [{g0.min():.4g}, {g0.max():.4g}]")
    print(f"suggested G bounds (margin x{args.margin}): "
          f"[{_round(lo / args.margin, False):.3g}, {_round(hi * args.margin, True):.3g}]")
    g = network.model("solidification").variable("G")
    print(f"current G bounds: [{g.lower:.3g}, {g.upper:.3g}]")


if __name__ == "__main__":
    main()
