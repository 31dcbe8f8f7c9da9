"""The report's pieces for outputs predicted through the chain (``settings.predict``):
a figure of each output along its process inputs with 95 % bands, a section and a
headline table. They render :class:`calnet.emulation.OutputSlices`; nothing is computed."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from calnet.report.figures import TRAIN_COLOR, _figure, _save, unit_text, with_unit
from calnet.report.html import Section, Table, fmt

if TYPE_CHECKING:
    from calnet.emulation import OutputSlices


def slices_figure(slices: OutputSlices, path: str | Path, unit: str,
                  input_units: Mapping[str, str]) -> Path:
    """One panel per process input: the predicted output (mean and central 95 % band)
    along it, the other inputs at the middle of their bounds.

    Parameters
    ----------
    slices : OutputSlices
        The output along each process input.
    path : str or Path
        Destination PNG.
    unit : str
        The output's unit.
    input_units : dict
        ``model.input`` -> unit, for the axes.

    Returns
    -------
    Path
    """
    keys = list(slices.input_keys)
    fig = _figure(4.2 * len(keys) + 0.6, 3.6)
    axes = fig.subplots(1, len(keys), squeeze=False)[0]
    for j, (ax, key) in enumerate(zip(axes, keys, strict=True)):
        x = np.asarray(slices.grids[j], float)
        ax.fill_between(x, slices.lower[j], slices.upper[j], color=TRAIN_COLOR, alpha=0.25,
                        lw=0, label="95 % band")
        ax.plot(x, slices.mean[j], color=TRAIN_COLOR, lw=1.5, label="mean")
        ax.set(xlabel=with_unit(key.split(".", 1)[1], input_units.get(key)),
               ylabel=with_unit(slices.output, unit))
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle(f"{slices.output}: predicted through the chain")
    return _save(fig, path)


def caption(output: str, slices: OutputSlices) -> str:
    others = len(slices.input_keys) > 1
    return (f"{output} predicted through the chain from the surrogates alone (Monte Carlo "
            "through the linked GPs: the surrogates' uncertainty is carried along the links), "
            "mean and central 95 % band of the simulator's output"
            + (", along each process input with the others at the middle of their bounds."
               if others else "."))


def _rows(predicted: Mapping[str, OutputSlices],
          units: Mapping[str, str]) -> list[list[Any]]:
    rows = []
    for key, s in predicted.items():
        for j, inp in enumerate(s.input_keys):
            mean = np.asarray(s.mean[j], float)
            width = np.asarray(s.upper[j], float) - np.asarray(s.lower[j], float)
            rows.append([key, inp.split(".", 1)[1], f"[{fmt(mean.min())}, {fmt(mean.max())}]",
                         fmt(float(width.mean())), fmt(float(width.max())),
                         unit_text(units.get(key))])
    return rows


HEADER = ["output", "along", "predicted mean (range)", "mean 95% band width",
          "widest band", "unit"]


def emulation_section(predicted: Mapping[str, OutputSlices], units: Mapping[str, str],
                      figures: list[tuple[Path, str]]) -> Section:
    """The report section of the outputs predicted through the chain."""
    shares = [[key, src, fmt(v)] for key, s in predicted.items()
              for src, v in s.shares.items()]
    return Section("Predicted outputs (through the chain)", paragraphs=[
        "Outputs listed under settings.predict, predicted at process settings by Monte Carlo "
        "through the linked surrogates: each sample draws the parameters (where there are "
        "any), every upstream output from its GP at the inputs the earlier draws gave, "
        "then the output from its own GP. The band is the simulator output's, without "
        "measurement noise or model discrepancy."],
        tables=[Table("Predicted outputs along each process input (others at the middle "
                      "of their bounds)", HEADER, _rows(predicted, units)),
                Table("Uncertainty budget (share of the predictive variance, averaged "
                      "over the points)", ["output", "source", "share"], shares)],
        figures=figures)


def headline_table(predicted: Mapping[str, OutputSlices], units: Mapping[str, str]) -> Table:
    """The headline's table of predicted outputs (empty rows without any)."""
    return Table("Predicted outputs (95 % band of the simulator output)", HEADER,
                 _rows(predicted, units))
