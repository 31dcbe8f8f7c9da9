"""The posterior as two CSV files beside the stage netCDFs, for spreadsheets and R.

``posterior_draws.csv``: one row per draw of the network (all chains pooled, the rows
aligned across models), one column per calibrated parameter (``model.parameter``: a shared
parameter under each model that has it, with the same draws; in
declared units). ``posterior_summary.csv``: one row per calibrated parameter with the
report's posterior summary (mode, mean, sd, central 95 % interval, their Monte Carlo
standard errors, R-hat, ESS). Models left at their prior are in neither. Both are
written atomically (:func:`calnet.files.replacing`).
"""

from __future__ import annotations

import csv
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from calnet.files import make_folder, replacing

DRAWS_FILE, SUMMARY_FILE = "posterior_draws.csv", "posterior_summary.csv"
SUMMARY_COLUMNS = ("model", "parameter", "unit", "lower", "upper", "mode", "mean", "sd",
                   "q2.5", "q97.5", "mcse_mean", "mcse_sd", "mcse_q2.5", "mcse_q97.5", "rhat",
                   "ess_bulk", "ess_tail", "shared", "plugged", "prior")


def _write(path: Path, header: list[str], rows: Any) -> Path:
    with replacing(path) as tmp:
        with open(tmp, "w", newline="", encoding="utf-8") as fh:
            writer = csv.writer(fh)
            writer.writerow(header)
            writer.writerows(rows)
    return path


def write_posterior_csv(folder: str | Path, theta: Mapping[str, np.ndarray],
                        summary: Mapping[str, Any]) -> tuple[Path, Path]:
    """Write ``posterior_draws.csv`` and ``posterior_summary.csv`` to ``folder``.

    Parameters
    ----------
    folder : str or Path
        Usually ``<out>/posterior``, beside the netCDF files.
    theta : dict of model -> array, shape (n_draws, n_parameters)
        The network's parameter draws (``NetworkPosterior.theta``).
    summary : dict
        :func:`calnet.calibration.summary.posterior_summary`; its parameter order is the
        columns' order of ``theta``.

    Returns
    -------
    (Path, Path)
        The draws and the summary files.
    """
    folder = make_folder(folder)
    models = [m for m, s in summary.items() if s.get("parameters")]  # sampled parameters
    header = ["draw"] + [f"{m}.{p}" for m in models for p in summary[m]["parameters"]]
    columns = [np.asarray(theta[m], float) for m in models]
    n = columns[0].shape[0] if columns else 0
    table = np.column_stack([np.arange(n)] + columns) if columns else np.empty((0, 1))
    draws = _write(folder / DRAWS_FILE, header,
                   ([int(r[0])] + [float(x) for x in r[1:]] for r in table))
    rows = []
    for m in models:
        for p, r in summary[m]["parameters"].items():
            values = {"model": m, "parameter": p, **r}
            rows.append(["" if values.get(c) is None else values[c] for c in SUMMARY_COLUMNS])
    return draws, _write(folder / SUMMARY_FILE, list(SUMMARY_COLUMNS), rows)
