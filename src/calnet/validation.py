"""Validation of a calibrated network on data: held-out test points, leave-one-out, and
naive baselines beside them (method.md sections 5 and 7)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from calnet.calibration.network import (
    NetworkPosterior,
    _plug,
    _sample,
    build_network_logdensity,
)
from calnet.chain import ChainPlan
from calnet.predict import metrics, predict
from calnet.spec import ExperimentalData, Network
from calnet.spec.models import SamplerSettings
from calnet.surrogates.network import Surrogates


def baselines(network: Network, train: ExperimentalData, test: ExperimentalData,
              *, seed: int = 0) -> dict[str, dict[str, float]]:
    """Metrics of two naive predictors of ``test``: the training mean, and a GP fitted
    directly to process inputs -> output on the training points."""
    from calnet.surrogates import fit_gp

    out = {"training_mean": metrics(test.y, np.full(len(test.y), train.y.mean()))}
    power = _power_law(train, test)
    if power is not None:
        out["power_law"] = power
    keys = train.input_keys
    lower = np.array([network.model(k.split(".")[0]).variable(k.split(".")[1]).lower
                      for k in keys])
    upper = np.array([network.model(k.split(".")[0]).variable(k.split(".")[1]).upper
                      for k in keys])
    try:
        gp = fit_gp(train.x, train.y, lower=lower, upper=upper, n_restarts=3, seed=seed,
                    name=f"{train.name} direct GP")
        mean, var = (np.asarray(a) for a in gp.predict(test.x, include_nugget=True))
        mean, var = (np.asarray(a) for a in gp.to_natural(mean, var))
        sd = np.sqrt(var)
        out["direct_gp"] = metrics(test.y, mean, mean - 1.96 * sd, mean + 1.96 * sd)
    except Exception as err:  # too few points for a GP is a result, not a failure
        out["direct_gp"] = {"error": str(err)}
    return out


def _power_law(train: ExperimentalData, test: ExperimentalData) -> dict | None:
    """``y = c prod_j x_j^b_j`` by least squares on the logs (only for positive data); the
    reference study's second naive baseline (method.md section 7)."""
    if (train.x <= 0).any() or (test.x <= 0).any() or (train.y <= 0).any():
        return None
    A = np.column_stack([np.ones(len(train.y)), np.log(train.x)])
    if len(train.y) <= A.shape[1]:
        return None
    coef, *_ = np.linalg.lstsq(A, np.log(train.y), rcond=None)
    pred = np.exp(np.column_stack([np.ones(len(test.y)), np.log(test.x)]) @ coef)
    return {**metrics(test.y, pred), "exponents": coef[1:].tolist()}


def leave_one_out(network: Network, surrogates: Surrogates, posterior: NetworkPosterior,
                  full: ExperimentalData, *, sampler: SamplerSettings, seed: int = 0,
                  progress=None) -> dict:
    """Re-calibrate the observing model without each point in turn and predict it.

    The upstream models keep their posterior (segmented view), so only the observing
    model's stage is repeated; equal shapes reuse one compiled sampler.
    """
    ds = network.dataset(full.name)
    model = ds.observed_model
    plan = ChainPlan.from_network(network)
    ancestors = [m for m in network.ancestors(model) if network.model(m).parameters]
    rng = np.random.default_rng(seed)
    upstream = _plug(posterior.theta, ancestors, posterior.plug if posterior.plug != "-"
                     else "posterior", network.settings.calibration.upstream_draws, rng)
    mean, lo, hi = np.empty(len(full.y)), np.empty(len(full.y)), np.empty(len(full.y))
    for i in range(len(full.y)):
        if progress:
            progress(i, len(full.y))
        keep = np.arange(len(full.y)) != i
        data_i = full.subset(keep)
        ld = build_network_logdensity(network, surrogates, free=(model,),
                                      datasets={full.name: data_i}, upstream=upstream,
                                      name=f"{model} LOO", plan=plan)
        idata = _sample(ld, sampler, seed + i, None)
        flat = {v: np.asarray(idata.posterior[v].values).reshape(
            (-1,) + idata.posterior[v].shape[2:]) for v in ld.sampled_vars}
        n = flat[ld.sampled_vars[0]].shape[0]
        theta = {m: v[rng.integers(0, v.shape[0], n)] for m, v in posterior.theta.items()}
        if f"theta_{model}" in flat:
            theta[model] = flat[f"theta_{model}"]
        hyper = {**posterior.hyper, full.name: {h: flat[f"{h}_{full.name}"]
                                                for h in ("ell", "sd2", "se2")}}
        post_i = replace(posterior, theta=theta, hyper=hyper,
                         data={**posterior.data, full.name: data_i})
        pred = predict(network, surrogates, post_i, full.name, full.x[i:i + 1], n_draws=100,
                       seed=seed)
        mean[i], lo[i], hi[i] = pred.mean[0], pred.lower[0], pred.upper[0]
    result = metrics(full.y, mean, lo, hi)
    naive = np.array([np.delete(full.y, i).mean() for i in range(len(full.y))])
    return {"calnet": result, "training_mean": metrics(full.y, naive),
            "mean": mean.tolist(), "lower95": lo.tolist(), "upper95": hi.tolist()}
