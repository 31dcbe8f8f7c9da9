"""Write the synthetic data sets from the true parameters (run once; output committed)."""

import csv
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).parent
sys.path.insert(0, str(HERE))
from synth_sims import TRUE, hardness, micro, thermal  # noqa: E402

rng = np.random.default_rng(11)


def chain(P, v):
    t = thermal({"P": P, "v": v, "a": TRUE["a"]})
    lam = micro({"G": t["G"], "S": v, "b": TRUE["b"]})["lam"]
    return t["W"], lam, hardness({"lam": lam, "c": TRUE["c"]})["H"]


for name, n, col, noise in [("width", 16, 0, 1.0), ("pdas", 10, 1, 0.003), ("hard", 8, 2, 1.0)]:
    P, v = rng.uniform(90, 240, n), rng.uniform(0.25, 1.9, n)
    with open(HERE / f"{name}.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        label = {"width": "W", "pdas": "lam", "hard": "H"}[name]
        w.writerow(["id", "P", "v", label, "split"])
        for i in range(n):
            y = chain(P[i], v[i])[col] + noise * rng.standard_normal()
            w.writerow([i + 1, round(P[i], 2), round(v[i], 4), round(y, 5),
                        "test" if i >= n - 2 else "train"])
