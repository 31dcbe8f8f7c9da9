"""Per-model summary of a network posterior: the table calnet prints and reports, and
the calibration stage's result (:func:`calibration_result`) that the report renders."""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from calnet._jax import FEW_CALLS, device_array
from calnet.calibration.calibrate_network import NetworkPosterior
from calnet.calibration.diagnostics import ESS_MIN, RHAT_MAX, import_arviz, kde_mode, summarize
from calnet.calibration.priors import parameter_prior
from calnet.calibration.terms import modelled, no_spread, parameter_keys
from calnet.results import CalibrationResult, PriorPanel
from calnet.spec import Network
from calnet.spec.models import DEFAULT_SCALE, SamplerSettings

__all__ = ["posterior_summary", "data_set_summary", "prior_panels", "calibration_result"]


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
        """R-hat, ESS and the error of the mean from the calibration's own diagnostics
        (computed once, where the stage was sampled: the sampler's, also for draws moved
        by upstream draws); the other Monte Carlo errors here."""
        if id(stage) not in cache:
            p = stage.idata.posterior
            cache[id(stage)] = {
                "summary": stage.diagnostics or summarize(stage.idata, hdi_probs=(),
                                                          warn=False),
                # draws moved by upstream draws (segmented): the error of their own mean
                "mcse_mean": az.mcse(p, method="mean") if stage.moved_by else None,
                "mcse_sd": az.mcse(p, method="sd"),
                "mcse_q2.5": az.mcse(p, method="quantile", prob=0.025),
                "mcse_q97.5": az.mcse(p, method="quantile", prob=0.975)}
        return cache[id(stage)]

    def divergences(stage) -> int:
        return int(np.asarray(stage.idata.sample_stats["diverging"]).sum())

    def sampled_in(stages) -> dict:
        """The diagnostics, stages and data sets of the stages that sampled a model (a
        shared parameter can be sampled in another model's stage): over all of them, and
        per stage under ``stages``."""
        out = {"divergences": sum(divergences(s) for s in stages),
               "max_rhat": max(diag(s)["summary"].max_r_hat for s in stages),
               "min_ess_bulk": min(diag(s)["summary"].min_ess_bulk for s in stages),
               "stage": " and ".join("+".join(s.models) for s in stages),
               "datasets": sorted({d for s in stages for d in s.datasets}),
               "stages": {"+".join(s.models): {
                   "datasets": sorted(s.datasets), "divergences": divergences(s),
                   "max_rhat": diag(s)["summary"].max_r_hat,
                   "min_ess_bulk": diag(s)["summary"].min_ess_bulk} for s in stages}}
        moved_by = sorted({k for s in stages for k in s.moved_by})
        if moved_by:
            out["moved_by"] = moved_by
        return out

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
            if found is None:  # held at a plugged value, or at its prior (no data)
                plugs = post.plugged.get(model)
                if plugs is not None and np.isfinite(plugs[j]):
                    row["plugged"] = True
                else:
                    row["prior"] = True
            else:
                stage, var, sel = found
                if stage not in stages:
                    stages.append(stage)
                d = diag(stage)
                (coord,) = sel.values()
                scalar = d["summary"][f"{var}[{coord}]"]
                row["mcse_mean"] = (scalar.mcse_mean if d["mcse_mean"] is None
                                    else float(d["mcse_mean"][var].sel(sel)))
                row.update({k: float(d[k][var].sel(sel)) for k in (
                    "mcse_sd", "mcse_q2.5", "mcse_q97.5")})
                row.update({"rhat": scalar.r_hat, "ess_bulk": scalar.ess_bulk,
                            "ess_tail": scalar.ess_tail})
                if "." not in key:
                    row["shared"] = True
            rows[p.name] = row
        if not stages:
            out[model] = {"prior_only": True}
            continue
        out[model] = {"parameters": rows, **sampled_in(stages)}
    for stage in post.stages:  # a model without parameters whose data's hyperparameters
        for model in stage.models:  # (discrepancy, unknown noise) were sampled
            if model not in out or out[model].get("prior_only"):
                out[model] = {"parameters": {}, **sampled_in([stage])}
    return out


def _interval(x: np.ndarray) -> dict:
    return {"mean": float(x.mean()), "q2.5": float(np.percentile(x, 2.5)),
            "q97.5": float(np.percentile(x, 97.5))}


def data_set_summary(network: Network, post: NetworkPosterior) -> dict:
    """Per data set, how its noise and discrepancy came out: the noise sd (known, or its
    posterior mean and 95 % interval), the discrepancy sd and length scales (posterior,
    or ``None`` without a discrepancy), in the output's units on its modelled scale
    (``ln y`` for ``transform: log``), with ``unit`` saying which, and ``priors``: the
    spec's noise and discrepancy terms and their priors in words (the defaults too)."""
    draws: dict[str, np.ndarray] = {}
    coords: dict[str, list[str]] = {}  # the length scales' inputs
    for stage in post.stages:
        for var, arr in stage.idata.posterior.data_vars.items():
            if var.startswith(("se2_", "sd2_", "ell_")):
                values = np.asarray(arr.values)
                draws[var] = values.reshape((-1,) + values.shape[2:])
            if var.startswith("ell_"):
                coords[var] = [str(c) for c in arr[arr.dims[-1]].values]
    out = {}
    for ds in network.data:
        if ds.name not in post.data:
            continue
        var = network.observed(ds)
        log = var.transform == "log"
        scale = ("the simulation runs' sd: the observations have no spread"
                 if no_spread(modelled(network, post.data[ds.name])) else DEFAULT_SCALE)
        row: dict = {"unit": f"ln({var.unit})" if log else var.unit,
                     "scale": "log" if log else "linear",
                     "priors": f"{ds.noise.text(var.unit, log, scale)}; "
                               f"{ds.discrepancy.text(scale)}"}
        if f"se2_{ds.name}" in draws:
            row["noise_sd"] = _interval(np.sqrt(draws[f"se2_{ds.name}"]))
        else:
            # a known sd is given in the output's own unit, also for a log output
            row["noise_sd"] = {"known": ds.noise.sd if ds.noise.sd is not None
                               else f"column {ds.noise.sd_column}", "unit": var.unit}
        if f"sd2_{ds.name}" in draws:
            row["discrepancy_sd"] = _interval(np.sqrt(draws[f"sd2_{ds.name}"]))
            ell = draws[f"ell_{ds.name}"]
            row["length_scales"] = {c: _interval(ell[:, j])
                                    for j, c in enumerate(coords[f"ell_{ds.name}"])}
        else:
            row["discrepancy_sd"] = None
        out[ds.name] = row
    return out


@partial(jax.jit, static_argnums=0, compiler_options=FEW_CALLS)
def _densities(priors: tuple, xs):
    """Density of each prior on its row of ``xs`` (k, m): one small program for a model's
    panels, where evaluating the priors op by op would compile every operation apart."""
    return jnp.stack([jnp.exp(p.log_prob(x)) for p, x in zip(priors, xs, strict=True)])


def prior_panels(network: Network, post: NetworkPosterior, model: str,
                 summary: dict) -> tuple[PriorPanel, ...]:
    """Prior density (on 200 points over the range) and posterior draws of each parameter
    of ``model``; ``summary`` is the model's entry of :func:`posterior_summary`."""
    params = network.model(model).parameters
    if not params:
        return ()
    xs = np.stack([np.linspace(p.lower, p.upper, 200) for p in params])
    ys = np.asarray(_densities(tuple(parameter_prior(p) for p in params), device_array(xs)))
    return tuple(PriorPanel(p.name, p.unit, p.lower, p.upper, xs[j], ys[j],
                            post.theta[model][:, j], summary["parameters"][p.name]["mode"])
                 for j, p in enumerate(params))


def calibration_result(network: Network, post: NetworkPosterior, *,
                       sampler: SamplerSettings | None = None) -> CalibrationResult:
    """The calibration as the report and ``metrics.json`` take it: the posterior summary
    per model, the prior panels of every model with a posterior, the notes, the
    surrogate checks and the convergence limits.

    Parameters
    ----------
    network : Network
    post : NetworkPosterior
        From :func:`calnet.calibration.calibrate_network.calibrate`.
    sampler : SamplerSettings, optional
        The sampler used (default: the spec's).

    Returns
    -------
    CalibrationResult
    """
    summary = posterior_summary(network, post)
    panels = {model: prior_panels(network, post, model, s) for model, s in summary.items()
              if s.get("parameters")}
    sampler = sampler or network.settings.sampler
    return CalibrationResult(
        mode=post.mode, plug=post.plug, calibrated=post.calibrated, models=summary,
        theta=post.theta, panels=panels, sampler=sampler.model_dump(), notes=tuple(post.notes),
        info=tuple(post.info),
        surrogate_check={c.dataset: c.to_dict() for c in post.checks},
        datasets=data_set_summary(network, post) if post.calibrated else {},
        rhat_max=RHAT_MAX, ess_min=ESS_MIN)
