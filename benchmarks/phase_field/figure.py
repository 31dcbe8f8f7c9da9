"""Picture of a steady cell array: solid fraction and liquid concentration at the end of
a default-resolution run (0.3 m/s, 1e7 K/m, worked-check parameters), with the band of
rows on which the cells are counted (red lines).

    PYTHONPATH=src nice -n 10 python benchmarks/phase_field/figure.py [OUT.png]
"""

from __future__ import annotations

import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from calnet.simulators import phase_field  # noqa: E402
from calnet.simulators.phase_field.model import CONSTANTS  # noqa: E402
from calnet.simulators.phase_field.outputs import BAND  # noqa: E402
from calnet.simulators.phase_field.solver import run  # noqa: E402


def main(out: str) -> None:
    S, G = 0.3, 1e7
    p = phase_field.parameters({"S": S, "G": G, "sigma": 2e-6, "M": 7.5, "p_int": 15000.0})
    opts = phase_field.PhaseFieldOptions()
    rec = run(p, opts)
    f = rec.fields
    mix = f["phi"] * f["xs"] + (1 - f["phi"]) * f["xl"]
    extent = (0, opts.nx * opts.dx * 1e6, f["y"][0] * 1e6, f["y"][-1] * 1e6)
    fig, axes = plt.subplots(1, 2, figsize=(9, 2.6), constrained_layout=True)
    for ax, field, label, cmap in ((axes[0], f["phi"], "solid fraction", "Greys_r"),
                                   (axes[1], mix * 100, "Nb (at%)", "viridis")):
        im = ax.imshow(field, origin="lower", extent=extent, cmap=cmap, aspect="equal")
        ax.set_xlabel("x (um)")
        fig.colorbar(im, ax=ax, label=label, shrink=0.8)
    axes[0].set_ylabel("y, lab frame (um)")
    last = rec.history[-1]
    fig.suptitle(f"S {S:g} m/s, G {G:g} K/m: {rec.status} after {rec.steps} steps, "
                 f"{last.cells} cells, lambda {last.spacing * 1e6:.3f} um "
                 f"(tip-height mode {last.mode})", fontsize=9)
    # the band of rows the cells are counted on (outputs.cell_count)
    lo, hi = (last.tip - b * CONSTANTS.eta for b in BAND)
    for y in (lo, hi):
        axes[0].axhline(y * 1e6, color="tab:red", lw=0.6)
    fig.savefig(out, dpi=110)
    print(out, rec.status, rec.steps, f"{rec.wall_seconds:.0f} s", f"{last.cells} cells",
          f"lambda {last.spacing * 1e6:.3f} um, tip-height mode {last.mode}")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "benchmarks/phase_field/cells.png")
