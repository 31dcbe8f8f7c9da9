"""Compare ``calnet run``'s prediction of y with the chain's exact answer.

Usage (from the repository root, after ``calnet run examples/chain3 --out out/chain3``)::

    python examples/chain3/compare.py out/chain3/metrics.json

Prints the NRMSE of the predicted mean (RMSE / range of the exact y) and the share of the
grid where the 95 % band holds the exact y.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from chain3_sims import composite  # noqa: E402


def main(path: str) -> None:
    s = json.loads(Path(path).read_text())["predicted_outputs"]["M3.y"]["slices"]["M1.x"]
    x, mean = np.array(s["x"]), np.array(s["mean"])
    lo, hi = np.array(s["lower95"]), np.array(s["upper95"])
    y = composite(x)
    nrmse = np.sqrt(np.mean((mean - y) ** 2)) / np.ptp(y)
    inside = np.mean((lo <= y) & (y <= hi))
    print(f"{len(x)} points: NRMSE {100 * nrmse:.1f} %, 95 % band holds the exact y at "
          f"{100 * inside:.0f} % of them, mean band width {np.mean(hi - lo):.3f}")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "out/chain3/metrics.json")
