"""Validation of a calibrated network on data: held-out test points, leave-one-out, and
naive baselines beside them (method.md sections 5 and 7)."""

from __future__ import annotations

import numpy as np

from calnet.calibration.network import (
    NetworkPosterior,
    StageResult,
    _sample,
    build_koh,
    data_scale,
    parameter_keys,
    with_stage,
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

    The other models' parameters are held at their posterior means (a segmented view),
    so only the observing model's stage is repeated; every fold has the same shapes and
    priors (the full data set's scale), so one compiled sampler serves all of them.
    """
    ds = network.dataset(full.name)
    model = ds.observed_model
    plan = ChainPlan.from_network(network)
    own = parameter_keys(network, model)
    fixed = {}
    for m, draws in posterior.theta.items():
        for j, k in enumerate(parameter_keys(network, m)):
            if k not in own:
                fixed[k] = float(np.mean(draws[:, j]))
    scales = {full.name: data_scale(network, full)}
    mean, lo, hi = np.empty(len(full.y)), np.empty(len(full.y)), np.empty(len(full.y))
    for i in range(len(full.y)):
        if progress:
            progress(i, len(full.y))
        data_i = full.subset(np.arange(len(full.y)) != i)
        ld = build_koh(network, surrogates, free=own, datasets={full.name: data_i},
                       fixed=fixed, name=f"{model} LOO", plan=plan, scales=scales,
                       emulator_variance=network.settings.calibration.emulator_variance)
        idata = _sample(ld, sampler, seed + i)
        stage = StageResult((model,), (full.name,), idata, ld)
        post_i = with_stage(posterior, stage, {full.name: data_i})
        pred = predict(network, surrogates, post_i, full.name, full.x[i:i + 1], n_draws=100,
                       seed=seed, noise_var=_noise_var(network, full, i))
        mean[i], lo[i], hi[i] = pred.mean[0], pred.lower[0], pred.upper[0]
    result = metrics(full.y, mean, lo, hi)
    naive = np.array([np.delete(full.y, i).mean() for i in range(len(full.y))])
    return {"calnet": result, "training_mean": metrics(full.y, naive),
            "mean": mean.tolist(), "lower95": lo.tolist(), "upper95": hi.tolist()}


def _noise_var(network: Network, data: ExperimentalData, i: int):
    from calnet.calibration.network import known_noise_var

    var = known_noise_var(network, data)
    return None if var is None else var[i:i + 1]
