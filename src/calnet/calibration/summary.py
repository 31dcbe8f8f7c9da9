"""Per-model summary of a network posterior: the table calnet prints and reports."""

from __future__ import annotations

import numpy as np

from calnet.calibration.calibrate_network import NetworkPosterior
from calnet.calibration.diagnostics import import_arviz, kde_mode
from calnet.calibration.terms import parameter_keys
from calnet.spec import Network

__all__ = ["posterior_summary"]


def _where_sampled(post, key: str):
    """(stage, variable, selection) of the stage that sampled parameter ``key``."""
    for stage in post.stages:
        spec = stage.logdensity.spec
        for var, idx in spec.groups:
            for i in idx:
                if spec.params[i][0] == key:
                    coord = stage.logdensity.names[var][list(idx).index(i)]
                    return stage, var, {f"{var}_dim": coord}
    return None


def posterior_summary(network: Network, post: NetworkPosterior) -> dict:
    """Per model: range, mode (KDE), mean, sd, 95 % interval with the Monte Carlo standard
    error of each (ArviZ), R-hat, ESS, divergences."""
    az = import_arviz()
    cache: dict = {}

    def diag(stage):
        if id(stage) not in cache:
            p = stage.idata.posterior
            cache[id(stage)] = {
                "rhat": az.rhat(p), "ess_bulk": az.ess(p, method="bulk"),
                "ess_tail": az.ess(p, method="tail"), "mcse_mean": az.mcse(p, method="mean"),
                "mcse_sd": az.mcse(p, method="sd"),
                "mcse_q2.5": az.mcse(p, method="quantile", prob=0.025),
                "mcse_q97.5": az.mcse(p, method="quantile", prob=0.975)}
        return cache[id(stage)]

    out = {}
    for model, draws in post.theta.items():
        if model in post.prior_only:
            out[model] = {"prior_only": True}
            continue
        m = network.model(model)
        rows, stages = {}, []
        for j, (p, key) in enumerate(zip(m.parameters, parameter_keys(network, model),
                                         strict=True)):
            found = _where_sampled(post, key)
            x = draws[:, j]
            row = {"unit": p.unit, "lower": p.lower, "upper": p.upper, "mode": kde_mode(x),
                   "mean": float(x.mean()), "sd": float(x.std()),
                   "q2.5": float(np.percentile(x, 2.5)),
                   "q97.5": float(np.percentile(x, 97.5))}
            if found is None:  # held at a plugged value or prior draws in this model
                row["plugged"] = True
            else:
                stage, var, sel = found
                if stage not in stages:
                    stages.append(stage)
                d = diag(stage)
                row.update({k: float(d[k][var].sel(sel)) for k in (
                    "mcse_mean", "mcse_sd", "mcse_q2.5", "mcse_q97.5")})
                row.update({"rhat": float(d["rhat"][var].sel(sel)),
                            "ess_bulk": float(d["ess_bulk"][var].sel(sel)),
                            "ess_tail": float(d["ess_tail"][var].sel(sel))})
                if "." not in key:
                    row["shared"] = True
            rows[p.name] = row
        if not stages:
            out[model] = {"prior_only": True}
            continue
        div = sum(int(np.asarray(s.idata.sample_stats["diverging"]).sum()) for s in stages)
        all_rhat = max(float(diag(s)["rhat"][v].max()) for s in stages
                       for v in s.idata.posterior.data_vars)
        all_ess = min(float(diag(s)["ess_bulk"][v].min()) for s in stages
                      for v in s.idata.posterior.data_vars)
        out[model] = {"parameters": rows, "divergences": div, "max_rhat": all_rhat,
                      "min_ess_bulk": all_ess,
                      "stage": " ; ".join("+".join(s.models) for s in stages),
                      "datasets": sorted({d for s in stages for d in s.datasets})}
    return out
