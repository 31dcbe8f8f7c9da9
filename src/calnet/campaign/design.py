"""Space-filling designs over a model's ``(x, theta)`` box (method.md section 2).

A campaign samples each model once on a Latin hypercube over its control inputs and
calibration parameters. The design depends only on ``(seed, model name, runs)``: the
same triple gives the same points on any machine, and seed 0 is a seed. A finished
design can be *augmented* with more points that fill the gaps it leaves, without moving
(and so without repeating) the points already simulated.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np
from scipy.stats import qmc

from calnet.errors import CampaignError
from calnet.spec.models import Model


@dataclass(frozen=True)
class Design:
    """Points of a campaign design.

    Attributes
    ----------
    columns : tuple of str
        Input names then parameter names, in declaration order.
    lower, upper : ndarray, shape (n_columns,)
        Bounds of the box, in the variables' declared units.
    unit : ndarray, shape (n_runs, n_columns)
        Points in the unit cube.
    log : ndarray of bool, shape (n_columns,)
        Columns declared ``scale: log``: the unit cube maps to ``ln x`` for them.
    """

    columns: tuple[str, ...]
    lower: np.ndarray
    upper: np.ndarray
    unit: np.ndarray
    log: np.ndarray | None = None

    @property
    def points(self) -> np.ndarray:
        """Points in declared units, shape ``(n_runs, n_columns)``."""
        return from_unit(self.unit, self.lower, self.upper, self.log)

    def __len__(self) -> int:
        return len(self.unit)

    def row(self, i: int) -> dict[str, float]:
        """Run ``i`` as ``{name: value}`` (plain floats)."""
        return {c: float(v) for c, v in zip(self.columns, self.points[i], strict=True)}


def from_unit(unit: np.ndarray, lower: np.ndarray, upper: np.ndarray,
              log: np.ndarray | None = None) -> np.ndarray:
    """Map unit-cube points to the box; log-scale columns are uniform in ``ln x``."""
    x = lower + unit * (upper - lower)
    if log is not None and log.any():
        lo, hi = np.log(lower[log]), np.log(upper[log])
        x[..., log] = np.exp(lo + unit[..., log] * (hi - lo))
    return x


def to_unit(x: np.ndarray, lower: np.ndarray, upper: np.ndarray,
            log: np.ndarray | None = None) -> np.ndarray:
    """Inverse of :func:`from_unit`."""
    u = (x - lower) / (upper - lower)
    if log is not None and log.any():
        lo, hi = np.log(lower[log]), np.log(upper[log])
        u[..., log] = (np.log(x[..., log]) - lo) / (hi - lo)
    return u


def design_columns(model: Model) -> tuple[str, ...]:
    """Input names then parameter names of ``model``, in declaration order."""
    return model.input_names + model.parameter_names


def model_box(model: Model) -> tuple[np.ndarray, np.ndarray]:
    """``(lower, upper)`` bounds of ``model``'s design box, each shape ``(n_columns,)``."""
    variables = (*model.inputs, *model.parameters)
    return (np.array([v.lower for v in variables], dtype=float),
            np.array([v.upper for v in variables], dtype=float))


def log_columns(model: Model) -> np.ndarray:
    """Which design columns are declared ``scale: log``, shape ``(n_columns,)``."""
    return np.array([getattr(v, "scale", "linear") == "log"
                     for v in (*model.inputs, *model.parameters)], dtype=bool)


def design_rng(seed: int, model_name: str, runs: int) -> np.random.Generator:
    """The generator of one design: a function of ``(seed, model name, runs)`` only."""
    if seed < 0:
        raise CampaignError(f"seed must be >= 0, got {seed}; pass a non-negative integer")
    digest = hashlib.sha256(model_name.encode()).digest()
    words = [int.from_bytes(digest[i:i + 4], "little") for i in range(0, 16, 4)]
    return np.random.default_rng(np.random.SeedSequence([seed, runs, *words]))


def latin_hypercube(model: Model, runs: int, *, seed: int) -> Design:
    """Latin hypercube of ``runs`` points over ``model``'s box, optimised for space filling.

    Parameters
    ----------
    model : Model
        Its inputs and parameters (declaration order) are the columns.
    runs : int
        Number of points (reference: 238 thermal runs, 100 microstructure runs).
    seed : int
        Seed of the design; the points depend only on ``(seed, model.name, runs)``.

    Returns
    -------
    Design
        ``unit`` has shape ``(runs, n_inputs + n_parameters)``; the centred discrepancy
        is minimised by random coordinate swaps (``scipy.stats.qmc``, ``random-cd``).
        Inputs declared ``scale: log`` are stratified in ``ln x``.

    Examples
    --------
    >>> from calnet.spec import Model, Input, Output, SimulatorRef
    >>> m = Model(name="m", simulator=SimulatorRef(kind="python", target="a:f"),
    ...           inputs=[Input(name="x", lower=0, upper=2)], outputs=[Output(name="y")])
    >>> d = latin_hypercube(m, 4, seed=0)
    >>> d.points.shape, bool(((d.points >= 0) & (d.points <= 2)).all())
    ((4, 1), True)
    """
    if runs < 1:
        raise CampaignError(f"a campaign needs at least 1 run, got {runs}; raise --runs")
    lower, upper = model_box(model)
    rng = design_rng(seed, model.name, runs)
    sampler = qmc.LatinHypercube(d=len(lower), optimization="random-cd", rng=rng)
    return Design(design_columns(model), lower, upper, sampler.random(runs), log_columns(model))


def qmc_design(model: Model, runs: int, *, kind: str, seed: int) -> Design:
    """A scrambled low-discrepancy design (``sobol`` or ``halton``) of ``runs`` points.

    Parameters
    ----------
    model : Model
    runs : int
    kind : {"sobol", "halton"}
        ``scipy.stats.qmc.Sobol`` or ``scipy.stats.qmc.Halton``, scrambled with a
        generator fixed by ``(seed, model.name, runs)``. A Sobol design of ``runs`` points
        is the first ``runs`` points of the scrambled sequence of the next power of 2.
    seed : int

    Returns
    -------
    Design
        ``unit`` has shape ``(runs, n_inputs + n_parameters)``.

    Examples
    --------
    >>> from calnet.spec import Model, Input, Output, SimulatorRef
    >>> m = Model(name="m", simulator=SimulatorRef(kind="python", target="a:f"),
    ...           inputs=[Input(name="x", lower=0, upper=2)], outputs=[Output(name="y")])
    >>> qmc_design(m, 5, kind="sobol", seed=0).points.shape
    (5, 1)
    """
    if runs < 1:
        raise CampaignError(f"a campaign needs at least 1 run, got {runs}; raise --runs")
    lower, upper = model_box(model)
    rng = design_rng(seed, model.name, runs)
    if kind == "sobol":
        unit = qmc.Sobol(d=len(lower), rng=rng).random_base2(int(np.ceil(np.log2(runs))))
    elif kind == "halton":
        unit = qmc.Halton(d=len(lower), rng=rng).random(runs)
    else:
        raise CampaignError(f"unknown quasi-random design '{kind}'; use sobol or halton")
    return Design(design_columns(model), lower, upper, unit[:runs], log_columns(model))


def augment(design: Design, extra: int, *, seed: int, model_name: str,
            candidates_per_point: int = 30) -> Design:
    """Add ``extra`` points to ``design`` without moving its existing points.

    New points are chosen greedily, one at a time, from a candidate Latin hypercube as
    the candidate farthest (Euclidean, unit cube) from every point chosen so far (a
    maximin augmentation), so they fill the gaps the existing design leaves.

    Parameters
    ----------
    design : Design
        The existing design; its points stay first, in order.
    extra : int
        Number of points to add.
    seed, model_name : int, str
        Together with the new total size they fix the candidates.
    candidates_per_point : int
        Candidate pool size per new point.

    Returns
    -------
    Design
        ``len(design) + extra`` points.
    """
    if extra <= 0:
        return design
    total = len(design) + extra
    rng = design_rng(seed, model_name, total)
    n_cand = max(candidates_per_point * extra, 64)
    cand = qmc.LatinHypercube(d=design.unit.shape[1], rng=rng).random(n_cand)
    chosen = list(design.unit)
    if chosen:
        base = np.asarray(chosen)
        dist = np.min(((cand[:, None, :] - base[None, :, :]) ** 2).sum(-1), axis=1)
    else:
        dist = np.full(n_cand, np.inf)
    for _ in range(extra):
        j = int(np.argmax(dist))
        chosen.append(cand[j])
        dist = np.minimum(dist, ((cand - cand[j]) ** 2).sum(-1))
        dist[j] = -1.0
    return Design(design.columns, design.lower, design.upper, np.asarray(chosen), design.log)
