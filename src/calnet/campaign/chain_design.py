"""Chain-aware designs: a downstream model is sampled where its parents' outputs land.

The rule (docs/campaigns.md, "Chain-aware designs"):

1. Fit a quick GP (:func:`calnet.surrogates.fit_gp`) to every output that feeds a link
   into the model or into one of its ancestors, on the finished ``ok`` runs of that
   output's model (its store beside this model's store, else its default store).
2. Push a seeded Latin hypercube of ``CLOUD`` points over the free inputs of the model
   and its ancestors and over the ancestors' parameter boxes (the support of their
   priors) through the chain with the GP means (:class:`calnet.chain.ChainPlan`): the
   cloud of the model's linked-input values.
3. Widen the cloud: clip it to the model's bounds, map it to the unit cube (logs where
   declared) and move every point by a uniform offset of up to ``MARGIN`` (10 %) of the
   cloud's range in each column, clipped to the unit cube.
4. Pick the new points' linked inputs from the widened cloud by greedy maximin (the
   candidate farthest from every point chosen so far, the first one nearest the cloud's
   centre); the model's other inputs and its parameters by a Latin hypercube.

When a parent has fewer than 2 ``ok`` runs the design falls back to a Latin hypercube,
with a :class:`~calnet.errors.CampaignWarning` saying so.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
from scipy.stats import qmc

from calnet.campaign.design import (
    Design,
    augment,
    design_rng,
    from_unit,
    latin_hypercube,
    to_unit,
)
from calnet.campaign.table import load_runs
from calnet.errors import CampaignError, CampaignWarning, SurrogateError
from calnet.spec.models import Model
from calnet.spec.network import Network

MARGIN = 0.1
CLOUD = 4096


class _NoRuns(Exception):
    """A parent's runs cannot say where its outputs land."""


def chain_points(network: Network, model: Model, old: Design, extra: int, *, seed: int,
                 store: Path, margin: float = MARGIN,
                 cloud: int = CLOUD) -> tuple[Design, bool]:
    """``old`` plus ``extra`` chain-aware points (see the module docstring), and whether
    they are chain-aware (False: a parent had no runs to tell where its outputs land, and
    the points are a Latin hypercube, or maximin points beside ``old``, with a warning).

    Parameters
    ----------
    network : Network
    model : Model
        A model with linked inputs.
    old : Design
        Points already planned (kept first, unmoved); they count in the maximin.
    extra : int
        Points to add.
    seed : int
        Fixes the GP fits, the cloud, the widening and the Latin hypercube.
    store : Path
        This model's store; the parents' stores are looked for beside it first.
    margin : float
        Widening, as a fraction of the cloud's range per linked input.
    cloud : int
        Size of the Latin hypercube pushed through the chain.

    Returns
    -------
    Design, bool
        ``len(old) + extra`` points; whether the new ones are chain-aware.
    """
    linked = np.array([network.link_into(model.name, v.name) is not None
                       for v in (*model.inputs, *model.parameters)])
    try:
        gps = parent_surrogates(network, model, store, seed=seed)
    except _NoRuns as why:
        warnings.warn(f"{model.name}: {why}; its design is a Latin hypercube instead (run the "
                      "parents first: `calnet campaign SPEC` runs every model, parents first)",
                      CampaignWarning, stacklevel=4)
        if len(old) == 0:
            return latin_hypercube(model, extra, seed=seed), False
        return augment(old, extra, seed=seed, model_name=model.name), False
    rng = design_rng(seed, f"{model.name}:chain", len(old) + extra)
    values = linked_cloud(network, model, gps, cloud, rng)
    lo, hi = old.lower[linked], old.upper[linked]
    log = old.log[linked] if old.log is not None else None
    _warn_outside(model, linked, values, lo, hi)
    unit = to_unit(np.clip(values, lo, hi), lo, hi, log)
    span = np.maximum(unit.max(axis=0) - unit.min(axis=0), 1e-6)
    cand = np.clip(unit + rng.uniform(-margin, margin, unit.shape) * span, 0.0, 1.0)
    picked = greedy_maximin(cand, old.unit[:, linked], extra, start=unit.mean(axis=0))
    new = np.empty((extra, len(linked)))
    new[:, linked] = picked
    if (~linked).any():
        new[:, ~linked] = qmc.LatinHypercube(d=int((~linked).sum()), rng=rng).random(extra)
    return Design(old.columns, old.lower, old.upper, np.vstack([old.unit, new]), old.log), True


def greedy_maximin(cand: np.ndarray, base: np.ndarray, n: int, *,
                   start: np.ndarray) -> np.ndarray:
    """Choose ``n`` rows of ``cand`` (m, k) one at a time, each the farthest (Euclidean)
    from ``base`` (b, k) and the rows already chosen; with an empty ``base`` the first is
    the row nearest ``start`` (k,). Returns shape ``(n, k)``."""
    if len(base):
        dist = np.min(((cand[:, None, :] - base[None, :, :]) ** 2).sum(-1), axis=1)
    else:
        dist = -((cand - start) ** 2).sum(-1)  # argmax: the candidate nearest start
    chosen = []
    for _ in range(n):
        j = int(np.argmax(dist))
        chosen.append(cand[j])
        near = ((cand - cand[j]) ** 2).sum(-1)
        dist = near if not len(base) and len(chosen) == 1 else np.minimum(dist, near)
        dist[j] = -np.inf
    return np.asarray(chosen).reshape(n, cand.shape[1])


def parent_surrogates(network: Network, model: Model, store: Path, *, seed: int) -> dict:
    """A quick GP (``"model.output" -> FittedGP``) of every output feeding a link into
    ``model`` or its ancestors, fitted on its model's ``ok`` runs."""
    from calnet.surrogates.fit import fit_gp  # jax, only for chain-aware designs
    from calnet.surrogates.space import gp_bounds, gp_space

    upstream = {*network.ancestors(model.name), model.name}
    gps = {}
    for link in network.links:
        src = network.model(link.source_model)
        if link.target_model not in upstream or link.source_var not in src.output_names:
            continue
        if link.source in gps:
            continue
        try:
            runs = load_runs(network, src.name, store=_store_of(network, src.name, store))
        except CampaignError as err:
            raise _NoRuns(f"no runs of its parent '{src.name}' ({err})") from None
        x, y = gp_space(src, runs.X), runs.Y[link.source_var]
        ok = np.isfinite(y) & np.isfinite(x).all(axis=1)
        if ok.sum() < 2:
            raise _NoRuns(f"its parent '{src.name}' has {int(ok.sum())} ok runs of "
                          f"'{link.source_var}', fewer than 2")
        lower, upper = gp_bounds(src)
        try:
            gps[link.source] = fit_gp(x[ok], y[ok], lower=lower, upper=upper,
                                      transform=src.output(link.source_var).transform,
                                      n_restarts=2, seed=seed, name=link.source)
        except SurrogateError as err:
            raise _NoRuns(f"no GP of '{link.source}' could be fitted ({err})") from None
    return gps


def _warn_outside(model: Model, linked: np.ndarray, values: np.ndarray, lower: np.ndarray,
                  upper: np.ndarray) -> None:
    """A warning when much of the cloud lies outside the model's bounds (it is clipped)."""
    names = [v.name for v, on in zip((*model.inputs, *model.parameters), linked,
                                     strict=True) if on]
    for j, name in enumerate(names):
        share = float(np.mean((values[:, j] < lower[j]) | (values[:, j] > upper[j])))
        if share > 0.1:
            warnings.warn(f"{model.name}: {share:.0%} of the values its input '{name}' takes "
                          f"from upstream lie outside its bounds [{lower[j]:g}, {upper[j]:g}] "
                          f"(by the upstream GPs' means, from {values[:, j].min():.4g} to "
                          f"{values[:, j].max():.4g}); the design is clipped to the bounds: "
                          "widen them to cover the chain if the upstream simulators reach "
                          "such values (with few upstream runs their GPs can overshoot)",
                          CampaignWarning, stacklevel=5)


def linked_cloud(network: Network, model: Model, gps: dict, n: int,
                 rng: np.random.Generator) -> np.ndarray:
    """Values of ``model``'s linked inputs, shape ``(n, n_linked)`` in declared units,
    at a Latin hypercube over the upstream free inputs and parameter boxes, propagated
    with the GP means."""
    from calnet.chain import ChainPlan  # jax, only for chain-aware designs

    free = [network.model(m).variable(v) for m, v in network.process_inputs(model.name)]
    keys = [f"{m}.{v}" for m, v in network.process_inputs(model.name)]
    params = [(m, p) for m in network.ancestors(model.name)
              for p in network.model(m).parameters]
    boxes = [*free, *(p for _, p in params)]
    lower = np.array([v.lower for v in boxes], dtype=float)
    upper = np.array([v.upper for v in boxes], dtype=float)
    log = np.array([getattr(v, "scale", "linear") == "log" for v in boxes])
    z = from_unit(qmc.LatinHypercube(d=len(boxes), rng=rng).random(n), lower, upper, log)
    xp = {k: z[:, j] for j, k in enumerate(keys)}
    thetas = {}
    for j, (m, _) in enumerate(params, start=len(keys)):
        thetas.setdefault(m, []).append(z[:, j])
    thetas = {m: np.column_stack(cols) for m, cols in thetas.items()}
    for m in network.ancestors(model.name):
        thetas.setdefault(m, np.zeros((n, 0)))
    x = np.asarray(ChainPlan.from_network(network).inputs(gps, model.name, xp, thetas))
    linked = [j for j, v in enumerate(model.inputs)
              if network.link_into(model.name, v.name) is not None]
    return x[:, linked]


def _store_of(network: Network, name: str, store: Path) -> Path:
    """A parent's store: beside this model's store when there is one, else its default."""
    beside = store.parent / f"{name}.sqlite"
    return beside if beside.is_file() else network.path(Path("campaigns") / f"{name}.sqlite")
