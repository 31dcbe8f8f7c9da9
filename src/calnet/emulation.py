"""Prediction of any output through the chain from the surrogates (emulation).

An output requested in ``settings.predict`` (or any output with a surrogate) is predicted
at process settings by Monte Carlo through the linked GPs: each sample draws the
parameters from the posterior (its prior where nothing was calibrated; none for a network
without parameters), then walks the chain in topological order, drawing every linked
output from its GP's predictive at the inputs the earlier draws gave, and finally draws
the output from its own GP. For one setting the GPs' predictives are independent given
their inputs, so the samples follow the exact pointwise distribution of the linked-GP
composite. This is the simulator's output, not a measurement: no discrepancy, no noise.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from calnet._jax import FEW_CALLS
from calnet.calibration.calibrate_network import NetworkPosterior
from calnet.calibration.terms import draw_index, links_into
from calnet.chain import ChainPlan
from calnet.errors import CalnetError, UnknownName
from calnet.predict import (
    Prediction,
    as_settings,
    check_settings,
    point_normals,
    warn_not_finite,
)
from calnet.spec import Network
from calnet.surrogates.fit_network import Surrogates


@partial(jax.jit, static_argnums=(0, 1, 2), compiler_options=FEW_CALLS)
def _over_samples(plan: ChainPlan, model: str, key: str, gps, xp, thetas, eps, on):
    """Modelled mean and variance (S, n) of GP ``key`` per sample row: parameters
    ``thetas`` (model -> (S, p)), each linked output drawn with ``eps`` (link -> (S, n))
    times ``on`` (link -> 1.0, or 0.0 for its predictive mean): one compiled program for
    every choice of links."""

    def one(th, ep):
        _, mean, var = plan.output(gps, model, key, xp, th, {k: ep[k] * on[k] for k in ep})
        return mean, var
    return jax.vmap(one)(thetas, eps)


def _thetas(network: Network, posterior: NetworkPosterior, plan: ChainPlan,
            models: tuple[str, ...], n: int) -> dict:
    """Parameter rows (n, p) per model: posterior draws spread over ``n`` samples."""
    idx = np.resize(draw_index(posterior.n_draws, n), n)
    out = {}
    for m in plan.models:
        p = network.model(m.name).parameters
        if not p:
            out[m.name] = jnp.zeros((n, 0))
        elif m.name in posterior.theta:
            out[m.name] = jnp.asarray(posterior.theta[m.name][idx])
        elif m.name in models:
            raise CalnetError(f"the posterior has no draws of the parameters of '{m.name}'; "
                              "calibrate again (calnet calibrate SPEC or calnet run SPEC)")
        else:  # not on the output's path: never evaluated
            out[m.name] = jnp.zeros((n, len(p)))
    return out


def predict_output(network: Network, surrogates: Surrogates, posterior: NetworkPosterior,
                   output: str, x: np.ndarray, *, n_samples: int = 2000,
                   seed: int = 0, warn_outside: bool = True) -> Prediction:
    """Predictive distribution of the simulator output ``output`` through the chain.

    Parameters
    ----------
    output : str
        ``model.output`` with a fitted surrogate (observed, linked or requested in
        ``settings.predict``).
    x : array (n, k)
        Process inputs, columns in the order of ``network.process_inputs(model)``.
        A 1-D array is n points of a target with one process input.
    posterior : NetworkPosterior
        Parameter draws; an empty posterior (a network without parameters) is fine.
    n_samples : int
        Monte Carlo samples per point; the mean's error is about sd / sqrt(n_samples).
    seed : int
        Seeds each point's GP draws (:func:`calnet.predict.point_normals`): a point's
        prediction depends on the seed and the point, not on the other rows of ``x``.
    warn_outside : bool
        Warn where a setting lies outside its input's bounds. A setting that is not a
        finite number is an error either way.

    Returns
    -------
    Prediction
        ``dataset`` is None; ``mean``, ``lower``, ``upper`` (n,) and ``samples``
        (n_samples, n) in the output's units; ``budget`` splits the variance on the
        modelled scale (``ln y`` for ``transform: log``) into ``parameters``,
        ``emulator <link>`` for each upstream surrogate and ``emulator <output>``.

    Examples
    --------
    >>> pred = predict_output(net, sur, post, "M3.y", np.array([[0.2], [0.8]]))  # doctest: +SKIP
    """
    model, _, name = output.partition(".")
    if name not in network.model(model).output_names:  # UnknownName for a model too
        raise UnknownName(f"'{output}' is not an output of the network; '{model}' has "
                          f"{list(network.model(model).output_names)}")
    if output not in surrogates:
        raise CalnetError(f"no surrogate for '{output}'; list it under settings.predict in "
                          "the spec and fit the surrogates again (calnet surrogates SPEC or "
                          "calnet run SPEC)")
    keys = tuple(network.process_input_keys(model))
    x = as_settings(network, output, x)
    check_settings(network, surrogates, posterior, output, x, f"predict {output}",
                   warn_outside)
    plan = ChainPlan.from_network(network)
    links = links_into(plan, model)
    gps = {k: s.gp for k, s in surrogates.items.items()}
    thetas = _thetas(network, posterior, plan, (*network.ancestors(model), model), n_samples)
    xp = {k: jnp.asarray(x[:, j]) for j, k in enumerate(keys)}
    eps = {k: jnp.asarray(point_normals(seed, x, f"emulator {k}", (n_samples,)))
           for k in links}

    def run(eps_on):
        on = {k: jnp.asarray(float(k in eps_on)) for k in links}
        return (np.asarray(a) for a in _over_samples(plan, model, output, gps, xp, thetas,
                                                     eps, on))

    mean0, _ = run(())
    mean_all, var_all = run(links)
    path = (*network.ancestors(model), model)
    budget = ({"parameters": mean0.var(axis=0)}
              if any(network.model(m).parameters for m in path) else {})
    for k in links:  # each upstream surrogate's share, one at a time
        mean_k, _ = run((k,))
        budget[f"emulator {k}"] = np.mean((mean_k - mean0) ** 2, axis=0)
    budget[f"emulator {output}"] = var_all.mean(axis=0)
    z = point_normals(seed, x, f"emulator {output}", (n_samples,))
    samples = mean_all + np.sqrt(np.maximum(var_all, 0.0)) * z
    if surrogates[output].transform == "log":
        samples = np.exp(samples)
    lo, hi = np.percentile(samples, [2.5, 97.5], axis=0)
    warn_not_finite(output, samples)
    return Prediction(None, output, keys, x, samples.mean(axis=0), lo, hi, budget, None,
                      samples)


@dataclass(frozen=True)
class OutputSlices:
    """An output predicted along each process input, the others at the middle of their
    bounds (what ``calnet run`` reports for ``settings.predict``).

    Attributes
    ----------
    output : str
        ``model.output``.
    input_keys : tuple of str
        ``model.input`` of each process input.
    grids, mean, lower, upper : tuple of ndarray (n,), one per input
        The input's values and the predictive mean and central 95 % band there, in the
        output's units.
    centre : ndarray (k,)
        Where the other inputs are held (the middle of their bounds; of ``ln x`` for a
        ``scale: log`` input).
    shares : dict of str -> float
        Average share of each source in the predictive variance over every slice point.
    """

    output: str
    input_keys: tuple[str, ...]
    grids: tuple[np.ndarray, ...]
    mean: tuple[np.ndarray, ...]
    lower: tuple[np.ndarray, ...]
    upper: tuple[np.ndarray, ...]
    centre: np.ndarray
    shares: dict[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {"output": self.output, "inputs": list(self.input_keys),
                "centre": self.centre.tolist(), "variance_shares": self.shares,
                "slices": {k: {"x": g.tolist(), "mean": m.tolist(), "lower95": lo.tolist(),
                               "upper95": hi.tolist()}
                           for k, g, m, lo, hi in zip(self.input_keys, self.grids, self.mean,
                                                      self.lower, self.upper, strict=True)}}


def _axis(var, n: int) -> tuple[np.ndarray, float]:
    """``n`` values over a variable's bounds (log-spaced for ``scale: log``) and its middle."""
    if getattr(var, "scale", "linear") == "log":
        lo, hi = np.log(var.lower), np.log(var.upper)
        return np.exp(np.linspace(lo, hi, n)), float(np.exp((lo + hi) / 2))
    return np.linspace(var.lower, var.upper, n), (var.lower + var.upper) / 2


def output_slices(network: Network, surrogates: Surrogates, posterior: NetworkPosterior,
                  output: str, *, n: int = 51, n_samples: int = 1000,
                  seed: int = 0) -> OutputSlices:
    """:func:`predict_output` of ``output`` along each process input over its bounds
    (``n`` points), the other inputs at the middle of theirs; one call for every slice."""
    model = output.split(".")[0]
    pairs = network.process_inputs(model)
    axes = [_axis(network.model(m).variable(i), n) for m, i in pairs]
    centre = np.array([c for _, c in axes])
    blocks = []
    for j, (grid, _) in enumerate(axes):
        block = np.tile(centre, (n, 1))
        block[:, j] = grid
        blocks.append(block)
    pred = predict_output(network, surrogates, posterior, output, np.vstack(blocks),
                          n_samples=n_samples, seed=seed)
    cut = [slice(j * n, (j + 1) * n) for j in range(len(pairs))]
    return OutputSlices(output, pred.input_keys, tuple(g for g, _ in axes),
                        tuple(pred.mean[c] for c in cut), tuple(pred.lower[c] for c in cut),
                        tuple(pred.upper[c] for c in cut), centre, pred.shares())
