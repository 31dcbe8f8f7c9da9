"""The sensitivity of a calibrated network: Sobol indices of the calibrated chain and
predictive maps over each data set's process box (method.md section 6); ``calnet run``
computes it in its validation stage, beside the leave-one-out.

For every data set: first-order and total Sobol indices of the posterior predictive mean
over its process inputs (SALib, :mod:`calnet.sensitivity`), their spread over posterior
draws, and, for two process inputs, the predictive mean (and the probability of the
spec's criterion) on a grid. The result is a frozen :class:`Exploration` per data set;
the report draws and writes it.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from calnet.calibration.calibrate_network import NetworkPosterior
from calnet.calibration.terms import draw_index
from calnet.parallel import map_threads
from calnet.predict import mean_function, predict
from calnet.sensitivity import SobolResult, SobolSpread, sobol_indices, sobol_spread
from calnet.spec import ExperimentalData, Network
from calnet.surrogates.fit_network import Surrogates

GRID = 30  # points along each axis of a predictive map


@dataclass(frozen=True)
class ProcessMap:
    """Posterior predictive over a grid of two process inputs.

    Attributes
    ----------
    names : (str, str)
        The two inputs (the data set's process inputs, in order).
    axis0, axis1 : ndarray, shape (GRID,)
        Grid values of each input, physical units.
    mean : ndarray, shape (GRID, GRID)
        Predictive mean, natural scale; ``mean[i, j]`` at ``(axis0[j], axis1[i])``.
    probability : ndarray, shape (GRID, GRID), or None
        Posterior predictive probability that the output meets ``criterion``.
    criterion : (float, float) or None
        ``(lower, upper)`` of the spec's criterion for the data set.
    log : (bool, bool)
        Whether each input has ``scale: log``: its grid is even in ``ln x`` then, and
        its axis logarithmic.
    """

    names: tuple[str, str]
    axis0: np.ndarray
    axis1: np.ndarray
    mean: np.ndarray
    probability: np.ndarray | None = None
    criterion: tuple[float, float] | None = None
    log: tuple[bool, bool] = (False, False)

    def to_dict(self) -> dict[str, Any]:
        out = {"inputs": list(self.names), self.names[0]: self.axis0.tolist(),
               self.names[1]: self.axis1.tolist(), "mean": self.mean.tolist()}
        if self.probability is not None and self.criterion is not None:
            out.update(criterion={"lower": self.criterion[0], "upper": self.criterion[1]},
                       probability=self.probability.tolist())
        return out


@dataclass(frozen=True)
class Exploration:
    """Sobol indices of one data set's predictive mean and its map.

    Attributes
    ----------
    dataset : str
    indices : SobolResult
        Indices of the posterior predictive mean (over 50 draws) on ``box``.
    over_draws : SobolSpread
        Total indices of single posterior draws' means: their spread.
    box : ndarray, shape (n_inputs, 2)
        The process box: the data's range of each input, widened by 2 %.
    map : ProcessMap or None
        For two process inputs.
    """

    dataset: str
    indices: SobolResult
    over_draws: SobolSpread
    box: np.ndarray
    map: ProcessMap | None = None

    def to_dict(self) -> dict[str, Any]:
        """The ``sensitivity`` entry of metrics.json (the map is under ``maps``)."""
        return {"indices": self.indices.to_dict(), "over_draws": self.over_draws.to_dict(),
                "box": self.box.tolist()}


def process_box(data: ExperimentalData, network: Network | None = None) -> np.ndarray:
    """Bounds (n_inputs, 2) of a data set's process inputs over its data (the working
    region), widened by 2 % of the span on each side (of the log span for an input
    declared ``scale: log``) and kept within the inputs' declared bounds (``network``).
    An input that the data never vary takes its declared bounds: a box of zero width
    would give indices of nothing."""
    lo, hi = data.x.min(axis=0), data.x.max(axis=0)
    inputs = ([network.model(m).variable(v) for m, v in (k.split(".", 1)
                                                          for k in data.input_keys)]
              if network is not None else [None] * len(lo))
    box = np.empty((len(lo), 2))
    for j, var in enumerate(inputs):
        if var is not None and hi[j] == lo[j]:
            box[j] = var.lower, var.upper
            continue
        log = var is not None and getattr(var, "scale", "linear") == "log" and lo[j] > 0
        a, b = (np.log(lo[j]), np.log(hi[j])) if log else (lo[j], hi[j])
        span = b - a if b > a else abs(b) * 0.1 + 1e-9
        a, b = a - 0.02 * span, b + 0.02 * span
        a, b = (np.exp(a), np.exp(b)) if log else (a, b)
        if var is not None and max(a, var.lower) < min(b, var.upper):
            a, b = max(a, var.lower), min(b, var.upper)
        box[j] = a, b
    return box


def explore_dataset(network: Network, surrogates: Surrogates, posterior: NetworkPosterior,
                    data: ExperimentalData, *, seed: int = 0, quick: bool = False,
                    progress: Callable[[str], None] | None = None) -> Exploration:
    """Sobol indices, their spread over draws and (two process inputs) the predictive
    map of one data set (``quick``: fewer Sobol base points and draws)."""
    note = progress or (lambda _: None)
    name = data.name
    n_base = 128 if quick else 512
    total = posterior.n_draws
    note(f"Sobol {name}")
    box = process_box(data, network)
    names = [k.split(".")[1] for k in data.input_keys]
    # uniform over the box in each input's own scale: ln x for an input of scale: log
    logs = np.array([getattr(network.model(m).variable(v), "scale", "linear") == "log"
                     for m, v in (k.split(".", 1) for k in data.input_keys)], dtype=bool)
    design_box = np.where(logs[:, None], np.log(np.where(logs[:, None], box, 1.0)), box)

    def physical(f):
        return lambda z: f(np.where(logs, np.exp(np.where(logs, z, 0.0)), z))

    mean_of = mean_function(network, surrogates, posterior, name, draw_index(total, 50))
    res = sobol_indices(physical(mean_of), design_box, names=names, n_base=n_base,
                        n_bootstrap=100, seed=seed)
    per_draw = mean_function(network, surrogates, posterior, name,
                             draw_index(total, 3 if quick else 20), per_draw=True)
    spread = sobol_spread(physical(per_draw), design_box, names=names, n_base=n_base // 2,
                          seed=seed)
    if data.x.shape[1] != 2:
        return Exploration(name, res, spread, box)
    note(f"map {name}")
    # even in each input's own scale, as the Sobol design
    g0, g1 = (np.geomspace(box[j, 0], box[j, 1], GRID) if logs[j] else
              np.linspace(box[j, 0], box[j, 1], GRID) for j in range(2))
    mesh = np.array(np.meshgrid(g0, g1)).reshape(2, -1).T
    crit = network.settings.criteria.get(name)
    within = (crit.lower, crit.upper) if crit else None
    pred = predict(network, surrogates, posterior, name, mesh, n_draws=60, seed=seed,
                   n_samples=10, within=within, warn_outside=False)
    prob = None if pred.prob is None else pred.prob.reshape(GRID, GRID)
    grid = ProcessMap((names[0], names[1]), g0, g1, pred.mean.reshape(GRID, GRID), prob,
                      within if prob is not None else None, (bool(logs[0]), bool(logs[1])))
    return Exploration(name, res, spread, box, grid)


def explore(network: Network, surrogates: Surrogates, posterior: NetworkPosterior,
            data: Mapping[str, ExperimentalData], *, seed: int = 0, quick: bool = False,
            progress: Callable[[str], None] | None = None) -> dict[str, Exploration]:
    """:func:`explore_dataset` for every data set, side by side (one thread per core: XLA
    compiles each program on one core), in the order of ``data``."""
    order = list(data)
    done = map_threads(lambda n: explore_dataset(network, surrogates, posterior, data[n],
                                                 seed=seed, quick=quick, progress=progress),
                       order)
    return dict(zip(order, done, strict=True))


__all__ = ["GRID", "Exploration", "ProcessMap", "explore", "explore_dataset", "process_box"]
