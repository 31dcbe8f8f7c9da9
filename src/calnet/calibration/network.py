"""Calibration of a network, segmented or joint (method.md section 4).

``calibrate(network, surrogates)`` walks the models in topological order. *Segmented*:
each model with data is calibrated on its own data sets with the upstream parameters
plugged in (their posterior mode, or draws of their posterior); a model without data
keeps its prior. *Joint*: one posterior over every model's parameters and every data
set's discrepancy and noise.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import jax.numpy as jnp
import numpy as np

from calnet.calibration.diagnostics import kde_mode, summarize
from calnet.calibration.network_density import (
    NetworkKOHSpec,
    NetworkLogDensity,
    TermSpec,
    standardise,
)
from calnet.calibration.priors import Beta, InverseGamma, LogNormal, TruncatedNormal, Uniform
from calnet.chain import ChainPlan
from calnet.errors import CalibrationError, CalibrationWarning
from calnet.spec import ExperimentalData, Network, read_all
from calnet.spec.models import SamplerSettings
from calnet.surrogates.network import Surrogates


def theta_prior(param):
    """calnet prior object of a spec :class:`~calnet.spec.Parameter`."""
    p = param.prior
    if p.dist == "beta":
        return Beta(param.lower, param.upper, p.a, p.b)
    if p.dist == "uniform":
        return Uniform(param.lower, param.upper)
    return TruncatedNormal(param.lower, param.upper, p.mu, p.sigma)


@dataclass(frozen=True)
class StageResult:
    """One sampled posterior: the free models and data sets of one stage."""

    models: tuple[str, ...]
    datasets: tuple[str, ...]
    idata: object  # arviz.InferenceData
    logdensity: NetworkLogDensity

    def draws(self, var: str) -> np.ndarray:
        """Flattened draws of a posterior variable, shape (chains * draws, ...)."""
        arr = np.asarray(self.idata.posterior[var].values)
        return arr.reshape((-1,) + arr.shape[2:])


@dataclass(frozen=True)
class NetworkPosterior:
    """Posterior of a network calibration.

    Attributes
    ----------
    mode, plug : str
        How it was calibrated.
    stages : tuple of StageResult
        One per sampled posterior (one for joint; one per model with data, segmented).
    theta : dict of model -> ndarray (n_draws, n_parameters)
        Parameter draws per model, aligned across models (for segmented calibration the
        upstream draws are resampled to the downstream count).
    hyper : dict of data set -> dict(ell (n_draws, q), sd2 (n_draws,), se2 (n_draws,))
    data : dict of data set -> ExperimentalData used (training rows)
    standardisation : dict of data set -> (mean, sd) on the modelled scale
    prior_only : tuple of str
        Models left at their prior (segmented, no data of their own).
    """

    mode: str
    plug: str
    stages: tuple[StageResult, ...]
    theta: Mapping[str, np.ndarray]
    hyper: Mapping[str, Mapping[str, np.ndarray]]
    data: Mapping[str, ExperimentalData]
    standardisation: Mapping[str, tuple[float, float]]
    prior_only: tuple[str, ...] = ()
    timings: Mapping[str, float] = field(default_factory=dict)

    @property
    def n_draws(self) -> int:
        return next(iter(self.theta.values())).shape[0] if self.theta else 0


def _term(network: Network, ds_name: str, emulator_variance: bool) -> TermSpec:
    ds = network.dataset(ds_name)
    model = network.model(ds.observed_model)
    q = len(model.inputs)
    disc = ds.discrepancy
    return TermSpec(ds.name, model.name, ds.observes,
                    (LogNormal(disc.length_scale_prior.mu, disc.length_scale_prior.sigma),) * q,
                    InverseGamma(disc.variance_prior.a, disc.variance_prior.b),
                    InverseGamma(disc.noise_prior.a, disc.noise_prior.b), emulator_variance)


def term_data(network: Network, data: ExperimentalData) -> tuple[dict, tuple[float, float]]:
    ds = network.dataset(data.name)
    out = network.model(ds.observed_model).output(ds.observed_output)
    y = np.log(data.y) if out.transform == "log" else data.y
    if out.transform == "log" and np.any(data.y <= 0):
        raise CalibrationError(f"data set {data.name}: output is modelled on the log scale but "
                               "has values <= 0; remove them or drop transform: log")
    mean, sd = standardise(y)
    xp = {k: jnp.asarray(data.x[:, j]) for j, k in enumerate(data.input_keys)}
    return {"y": jnp.asarray((y - mean) / sd), "y_mean": mean, "y_sd": sd, "xp": xp}, (mean, sd)


def build_network_logdensity(network: Network, surrogates: Surrogates, *,
                             free: tuple[str, ...], datasets: Mapping[str, ExperimentalData],
                             upstream: Mapping[str, np.ndarray] | None = None,
                             emulator_variance: bool = True, name: str = "network",
                             plan: ChainPlan | None = None) -> NetworkLogDensity:
    """KOH log-density with the parameters of ``free`` models sampled and those of the
    ``upstream`` models fixed to the given draws (model -> (D, n_parameters))."""
    plan = plan or ChainPlan.from_network(network)
    upstream = dict(upstream or {})
    free_specs = tuple((m, tuple(theta_prior(p) for p in network.model(m).parameters))
                       for m in free if network.model(m).parameters)
    terms = tuple(_term(network, ds, emulator_variance) for ds in datasets)
    tdata, std = [], {}
    for ds_name, d in datasets.items():
        td, std[ds_name] = term_data(network, d)
        tdata.append(td)
    spec = NetworkKOHSpec(plan, free_specs, tuple(sorted(upstream)), terms)
    gps = {k: s.gp for k, s in surrogates.items.items()}
    data = {"gps": gps, "terms": tdata,
            "upstream": {m: jnp.asarray(v, dtype=float) for m, v in upstream.items()},
            "y": jnp.concatenate([t["y"] for t in tdata]) if tdata else jnp.zeros(0)}
    for term, td in zip(terms, tdata, strict=True):
        if spec.inputs_fixed(term):  # segmented: upstream GPs evaluated once, not per step
            td["x_fixed"] = spec.fixed_inputs(data, term, td)
    n_obs = sum(len(d.y) for d in datasets.values())
    ld = NetworkLogDensity(spec, data, name,
                           {m.name: m.parameter_names for m in network.models},
                           {m.name: m.input_names for m in network.models})
    if n_obs < ld.dim:
        warnings.warn(f"{name}: {n_obs} data points for {ld.dim} sampled parameters "
                      "(calibration parameters and discrepancy hyperparameters); the "
                      "posterior will lean on the priors", CalibrationWarning, stacklevel=2)
    return ld


def _sample(ld: NetworkLogDensity, sampler: SamplerSettings, seed: int, progress):
    from calnet.calibration.sampling import sample_nuts

    return sample_nuts(ld, seed=seed, num_chains=sampler.chains, num_warmup=sampler.warmup,
                       num_draws=sampler.draws, thin=sampler.thin,
                       target_accept=sampler.target_accept, chain_method=sampler.chain_method,
                       progress=progress or False)


def calibrate(network: Network, surrogates: Surrogates, *, data=None, mode: str | None = None,
              plug: str | None = None, seed: int | None = None,
              sampler: SamplerSettings | None = None, emulator_variance: bool | None = None,
              upstream_draws: int | None = None,
              progress: Callable[[str], None] | None = None) -> NetworkPosterior:
    """Calibrate every model of ``network`` against its data sets.

    Parameters
    ----------
    network : Network
    surrogates : Surrogates
        A GP for every observed output and every output feeding a link.
    data : mapping of data set name -> ExperimentalData, optional
        Training data (default: the spec's data sets, training split).
    mode : {"segmented", "joint"}, optional
    plug : {"mode", "posterior"}, optional
        Segmented only: plug in the upstream posterior mode, or propagate draws.
    seed : int, optional
    sampler : SamplerSettings, optional
    emulator_variance : bool, optional
        Add each surrogate's predictive variance to the KOH covariance.
    upstream_draws : int, optional
        Number of upstream draws propagated with ``plug="posterior"``.
    progress : callable, optional
        Called with a message before each stage.

    Returns
    -------
    NetworkPosterior
    """
    cfg = network.settings.calibration
    mode, plug = mode or cfg.mode, plug or cfg.plug
    if mode not in ("segmented", "joint") or plug not in ("mode", "posterior"):
        raise CalibrationError(f"mode must be segmented or joint and plug mode or posterior, "
                               f"got {mode!r} / {plug!r}")
    seed = network.settings.seed if seed is None else seed
    sampler = sampler or network.settings.sampler
    emu = cfg.emulator_variance if emulator_variance is None else emulator_variance
    n_up = upstream_draws or cfg.upstream_draws
    if data is None:
        data = {k: v.train for k, v in read_all(network).items()}
    if not data:
        raise CalibrationError("the network has no data sets; add one under 'data:' to "
                               "calibrate")
    plan = ChainPlan.from_network(network)
    if mode == "joint":
        return _joint(network, surrogates, data, plan, seed, sampler, emu, progress)
    return _segmented(network, surrogates, data, plan, seed, sampler, emu, plug, n_up, progress)


def _joint(network, surrogates, data, plan, seed, sampler, emu, progress) -> NetworkPosterior:
    free = tuple(m for m in network.order if network.model(m).parameters)
    if progress:
        progress("joint: " + ", ".join(free))
    ld = build_network_logdensity(network, surrogates, free=free, datasets=data,
                                  emulator_variance=emu, name="joint", plan=plan)
    idata = _sample(ld, sampler, seed, None)
    summarize(idata, warn=True, stacklevel=4)  # R-hat, ESS and divergence warnings
    stage = StageResult(free, tuple(data), idata, ld)
    theta = {m: stage.draws(f"theta_{m}") for m in free}
    return _posterior(network, "joint", "-", (stage,), theta, data, ld, ())


def _segmented(network, surrogates, data, plan, seed, sampler, emu, plug, n_up, progress):
    stages, theta, prior_only = [], {}, []
    rng = np.random.default_rng(seed)
    n_stage = sampler.chains * (sampler.draws // sampler.thin)
    for i, name in enumerate(network.order):
        model = network.model(name)
        own = {k: v for k, v in data.items() if network.dataset(k).observed_model == name}
        if not model.parameters and not own:
            continue
        ancestors = [m for m in network.ancestors(name) if network.model(m).parameters]
        if not own:  # prior draws stand in, also for the downstream stages
            prior_only.append(name)
            theta[name] = _prior_draws(model, n_stage, seed)
            continue
        upstream = _plug(theta, ancestors, plug, n_up, rng)
        if progress:
            progress(f"segmented: {name}")
        ld = build_network_logdensity(network, surrogates, free=(name,), datasets=own,
                                      upstream=upstream, emulator_variance=emu, name=name,
                                      plan=plan)
        idata = _sample(ld, sampler, seed + i, None)
        summarize(idata, warn=True, stacklevel=4)
        stage = StageResult((name,), tuple(own), idata, ld)
        stages.append(stage)
        if model.parameters:
            theta[name] = stage.draws(f"theta_{name}")
    n = max((v.shape[0] for v in theta.values()), default=0)
    theta = {m: (v if v.shape[0] == n else v[rng.integers(0, v.shape[0], n)])
             for m, v in theta.items()}
    return _posterior(network, "segmented", plug, tuple(stages), theta, data, None,
                      tuple(prior_only))


def _prior_draws(model, n: int, seed: int) -> np.ndarray:
    """(n, n_parameters) draws of the prior of a model without data."""
    priors = [theta_prior(p) for p in model.parameters]
    prior_rng = np.random.default_rng([seed, 7919])
    return np.stack([np.asarray(p.sample(prior_rng, (n,))) for p in priors], 1)


def _plug(theta, ancestors, plug, n_up, rng) -> dict[str, np.ndarray]:
    """Upstream parameter values plugged into a downstream stage, model -> (D, p)."""
    out = {}
    for m in ancestors:
        draws = theta.get(m)
        if draws is None:
            continue
        if plug == "mode":
            out[m] = np.array([[kde_mode(draws[:, j]) for j in range(draws.shape[1])]])
        else:
            idx = rng.choice(draws.shape[0], size=min(n_up, draws.shape[0]), replace=False)
            out[m] = draws[idx]
    if plug == "posterior" and out:  # the same draw index across upstream models
        d = min(v.shape[0] for v in out.values())
        out = {m: v[:d] for m, v in out.items()}
    return out


def _posterior(network, mode, plug, stages, theta, data, ld, prior_only) -> NetworkPosterior:
    hyper, std = {}, {}
    for stage in stages:
        for ds in stage.datasets:
            hyper[ds] = {h: stage.draws(f"{h}_{ds}") for h in ("ell", "sd2", "se2")}
    for ds_name, d in data.items():
        std[ds_name] = term_data(network, d)[1]
    n = max((v.shape[0] for v in theta.values()), default=0)
    for ds, h in hyper.items():  # align hyperparameter draws with theta draws
        if n and next(iter(h.values())).shape[0] != n:
            idx = np.random.default_rng(0).integers(0, next(iter(h.values())).shape[0], n)
            hyper[ds] = {k: v[idx] for k, v in h.items()}
    attrs = {"+".join(s.models): s.idata.posterior.attrs for s in stages}  # sample_nuts's
    timings = {f"stage_{k}": float(a.get("sampling_time", 0.0)) + float(a.get("compile_time", 0.0))
               for k, a in attrs.items()}
    return NetworkPosterior(mode, plug, stages, theta, hyper, dict(data), std,
                            prior_only, timings)
