"""Share of planar fronts flagged by M2 over seeded Latin-hypercube sweeps.

Boxes: the reference bounds (method.md section 1) and a wider box, S 0.04-2.4 m/s and
G 1e5-5e7 K/m, standing for what an M1 campaign may produce; parameters always over their
reference bounds. The two planar reasons can overlap. Same design as
tests/simulators/test_solidification.py (n 4096, seed 0).

Usage::

    python benchmarks/solidification/planar_share.py
"""

from __future__ import annotations

import numpy as np
from scipy.stats import qmc

from calnet.simulators import solidification as m2

NAMES = m2.INPUTS + m2.PARAMETERS
BOXES = {
    "reference": dict(m2.BOUNDS),
    "wide (S 0.04-2.4 m/s, G 1e5-5e7 K/m)": {**m2.BOUNDS, "S": (0.04, 2.4), "G": (1e5, 5e7)},
}


def sweep(box: dict[str, tuple[float, float]], variant: str, n: int = 4096,
          seed: int = 0) -> dict[str, np.ndarray]:
    unit = qmc.LatinHypercube(d=len(NAMES), seed=seed).random(n)
    x = qmc.scale(unit, [box[k][0] for k in NAMES], [box[k][1] for k in NAMES])
    return m2.simulate_batch(**{k: x[:, i] for i, k in enumerate(NAMES)}, variant=variant)


def main() -> None:
    print("| variant | box | planar | V >= V_a | kinetic floor "
          "| NaN | lambda range, cellular (um) |")
    print("|---|---|---:|---:|---:|---:|---|")
    for variant in m2.VARIANTS:
        for name, box in BOXES.items():
            out = sweep(box, variant)
            p = out["planar"]
            nan = sum(int(np.isnan(a).sum()) for a in out.values())
            lam = out["lambda"][~p]
            print(f"| {variant} | {name} | {p.mean():.2%} | {out['planar_absolute'].mean():.2%} "
                  f"| {out['planar_kinetic'].mean():.2%} | {nan} | "
                  f"{lam.min():.3f}-{lam.max():.3f} |")


if __name__ == "__main__":
    main()
