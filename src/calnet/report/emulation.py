"""The report's pieces for outputs predicted through the chain (``settings.predict``):
a figure of each output along its process inputs with 95 % bands, a section and a
headline table. They render :class:`calnet.emulation.OutputSlices`; nothing is computed."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from calnet.report.figures import TRAIN_COLOR, _figure, _save, with_unit
from calnet.report.html import Section, Table, fmt


def slices_figure(slices: Mapping[str, Any], path: str | Path, unit: str,
                  input_units: Mapping[str, str]) -> Path:
    """One panel per process input: the predicted output (mean and central 95 % band)
    along it, the other inputs at the middle of their bounds.

    Parameters
    ----------
    slices : dict
        :meth:`calnet.emulation.OutputSlices.to_dict`.
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
    keys = list(slices["inputs"])
    fig = _figure(4.2 * len(keys) + 0.6, 3.6)
    axes = fig.subplots(1, len(keys), squeeze=False)[0]
    for ax, key in zip(axes, keys, strict=True):
        s = slices["slices"][key]
        x = np.asarray(s["x"], float)
        ax.fill_between(x, s["lower95"], s["upper95"], color=TRAIN_COLOR, alpha=0.25, lw=0,
                        label="95 % band")
        ax.plot(x, s["mean"], color=TRAIN_COLOR, lw=1.5, label="mean")
        ax.set(xlabel=with_unit(key.split(".", 1)[1], input_units.get(key)),
               ylabel=with_unit(slices["output"], unit))
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle(f"{slices['output']}: predicted through the chain")
    return _save(fig, path)


def caption(output: str, slices: Mapping[str, Any]) -> str:
    others = len(slices["inputs"]) > 1
    return (f"{output} predicted through the chain from the surrogates alone (Monte Carlo "
            "through the linked GPs: the surrogates' uncertainty is carried along the links), "
            "mean and central 95 % band of the simulator's output"
            + (", along each process input with the others at the middle of their bounds."
               if others else "."))


def _rows(predicted: Mapping[str, Any], units: Mapping[str, str]) -> list[list[Any]]:
    rows = []
    for key, s in predicted.items():
        for inp, sl in s["slices"].items():
            mean = np.asarray(sl["mean"], float)
            width = np.asarray(sl["upper95"], float) - np.asarray(sl["lower95"], float)
            rows.append([key, inp.split(".", 1)[1], f"[{fmt(mean.min())}, {fmt(mean.max())}]",
                         fmt(float(width.mean())), fmt(float(width.max())),
                         units.get(key, "")])
    return rows


HEADER = ["output", "along", "predicted mean (range)", "mean 95% band width",
          "widest band", "unit"]


def emulation_section(predicted: Mapping[str, Any], units: Mapping[str, str],
                      figures: list[tuple[Path, str]]) -> Section:
    """The report section of the outputs predicted through the chain."""
    shares = [[key, src, fmt(v)] for key, s in predicted.items()
              for src, v in s["variance_shares"].items()]
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


def headline_table(predicted: Mapping[str, Any], units: Mapping[str, str]) -> Table:
    """The headline's table of predicted outputs (empty rows without any)."""
    return Table("Predicted outputs (95 % band of the simulator output)", HEADER,
                 _rows(predicted, units))
