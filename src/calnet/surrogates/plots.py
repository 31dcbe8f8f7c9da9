"""Parity plot of cross-validated surrogate predictions with 95 % error bars.

matplotlib is imported only when a plot is drawn, and through the object-oriented API
with the Agg canvas: no pyplot, no global backend switch, safe on headless machines.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from calnet.files import make_folder, replacing
from calnet.surrogates.cv import CVResult


def parity_plot(
    cv: CVResult,
    path: str | Path,
    *,
    title: str | None = None,
    units: str = "",
    dpi: int = 150,
) -> Path:
    """Draw observed vs out-of-fold predicted outputs with 95 % intervals, save to ``path``.

    Like figure 8 of the reference study: one point per simulator run, vertical bars for
    the 95 % predictive interval, the line ``y = yhat``, and the MAPE, RMSE and coverage
    in the legend.

    Parameters
    ----------
    cv : CVResult
        From :func:`calnet.surrogates.cross_validate`.
    path : str or Path
        Output file; the format follows the suffix (``.png``, ``.pdf``, ``.svg``).
    title : str, optional
        Defaults to ``"<name>: <k>-fold CV"`` (``", GP on ln"`` added for a log GP,
        whose axes are logarithmic where its values span more than a decade).
    units : str
        Appended to the axis labels, e.g. ``"um"``.
    dpi : int, default 150

    Returns
    -------
    Path
        The file written.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    path = Path(path)
    make_folder(path.parent)
    fig = Figure(figsize=(4.5, 4.5))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    yerr = np.vstack([cv.mean - cv.lower95, cv.upper95 - cv.mean])
    mape = f"MAPE {cv.mape:.2f} %, " if cv.mape is not None else ""
    label = (f"{mape}RMSE {cv.rmse:.3g}\n"
             f"95 % coverage {100 * cv.coverage95:.0f} % (n = {cv.n})")
    ax.errorbar(cv.y, cv.mean, yerr=yerr, fmt="o", ms=3, lw=0.8, capsize=2,
                color="C0", ecolor="C0", alpha=0.8, label=label)
    finite = np.concatenate([cv.y, cv.lower95, cv.upper95])
    finite = finite[np.isfinite(finite)]
    lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
    logs = cv.transform == "log" and lo > 0 and hi > 10 * lo  # a log GP over decades
    if logs:
        ax.set(xscale="log", yscale="log")
        ends = (lo / 1.2, hi * 1.2)
    else:
        pad = 0.03 * (hi - lo if hi > lo else 1.0)
        ends = (lo - pad, hi + pad)
    ax.plot(ends, ends, "k--", lw=0.8, label="y = ŷ")
    ax.set_xlim(*ends)
    ax.set_ylim(*ends)
    ax.set_aspect("equal")
    name = cv.name or "output"
    suffix = f" ({units})" if units and units != "1" else ""
    ax.set_xlabel(f"simulated {name}{suffix}")
    ax.set_ylabel(f"GP prediction {name}{suffix}")
    gp = ", GP on ln" if cv.transform == "log" else ""
    ax.set_title(title if title is not None else f"{name}: {cv.k}-fold CV{gp}")
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    with replacing(path) as tmp:
        fig.savefig(tmp, dpi=dpi)
    return path


def parity_plots(network, surrogates, folder: str | Path) -> dict[str, Path]:
    """:func:`parity_plot` of every cross-validated surrogate, ``folder/cv_<model.output>.png``
    with the output's unit: ``{model.output: path}``."""
    return {key: parity_plot(s.cv, Path(folder) / f"cv_{key}.png",
                             units=network.model(s.model).output(s.output).unit)
            for key, s in surrogates.items.items() if s.cv is not None}
