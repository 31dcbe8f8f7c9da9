"""The pieces of a network's KOH model that the calibration and its checks share: one
data set's term (priors, standardised observations), the parameters' keys, and the
choice of evenly spread posterior draws (method.md sections 3-4)."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from calnet._jax import device_array
from calnet.calibration.koh import Term, standardise
from calnet.calibration.priors import InverseGamma, LogNormal, scale_prior
from calnet.chain import ChainPlan
from calnet.errors import CalibrationError
from calnet.spec import ExperimentalData, Network
from calnet.spec.variables import HalfNormalPrior

__all__ = ["draw_index", "draws_at", "hyper_at", "links_into", "data_scale", "no_spread",
           "modelled", "known_noise_var", "make_term", "parameter_keys"]


def draw_index(total: int, n: int) -> np.ndarray:
    """``n`` posterior draws (at most ``total``) evenly spread over ``total``; one (index 0,
    into no arrays) for a posterior of 0 draws: nothing was sampled, so every draw is the
    same (a network without parameters whose noise is known and has no discrepancy)."""
    if total == 0:
        return np.zeros(1, dtype=int)
    return np.linspace(0, total - 1, min(n, total)).astype(int)


def draws_at(theta: dict[str, np.ndarray], plan: ChainPlan, idx: np.ndarray) -> dict:
    """Each model's parameter draws ``idx`` on the device, (len(idx), p); an empty
    (len(idx), 0) block for a model without parameters."""
    out = {m: device_array(v[idx]) for m, v in theta.items()}
    for m in plan.models:
        if m.n_parameters == 0:
            out[m.name] = device_array(np.zeros((len(idx), 0)))
    return out


def hyper_at(stored: dict[str, np.ndarray], idx: np.ndarray, n_ell: int) -> dict:
    """One data set's discrepancy and noise hyperparameter draws ``idx`` on the device;
    those it was calibrated without (no discrepancy, known noise) as the values that
    switch them off: length scales 1, variances 0."""
    n = len(idx)
    hyper = {"ell": stored["ell"][idx] if "ell" in stored else np.ones((n, n_ell)),
             "sd2": stored["sd2"][idx] if "sd2" in stored else np.zeros(n),
             "se2": stored["se2"][idx] if "se2" in stored else np.zeros(n)}
    return {k: device_array(v, float) for k, v in hyper.items()}


# ----------------------------------------------------------------------------- terms
def links_into(plan: ChainPlan, model: str) -> tuple[str, ...]:
    """``model.output`` of every surrogate whose output reaches ``model``'s inputs."""
    out: list[str] = []

    def walk(name):
        for src in plan.model(name).sources:
            if src[0] == "output":
                walk(src[1])
                out.append(src[2])
            elif src[0] == "identity":
                walk(src[1])

    walk(model)
    return tuple(dict.fromkeys(out))


def data_scale(network: Network, data: ExperimentalData, surrogates=None
               ) -> tuple[float, float]:
    """Mean and sd of a data set's observations on the modelled scale: the scale of the
    default noise and discrepancy priors.

    Observations without spread (one point, or all equal) have no sd; the sd is then the
    observed output's over its simulation runs (the surrogate's training outputs, from
    ``surrogates``), so that the default priors keep the output's units; 1 without
    ``surrogates`` or where the runs have no spread either (:func:`no_spread`)."""
    y = modelled(network, data)
    mean, sd = standardise(y)
    if no_spread(y) and surrogates is not None:
        key = network.dataset(data.name).observes
        runs_sd = float(surrogates[key].gp.y_std) if key in surrogates else 0.0
        if runs_sd > 0 and np.isfinite(runs_sd):
            sd = runs_sd
    return mean, sd


def no_spread(y: np.ndarray) -> bool:
    """Whether observations ``y`` (modelled scale) have no sd to scale priors with."""
    return len(y) < 2 or not float(np.std(y)) > 0


def modelled(network: Network, data: ExperimentalData) -> np.ndarray:
    """Observations on the modelled scale (``ln y`` for ``transform: log``)."""
    ds = network.dataset(data.name)
    out = network.observed(ds)
    if out.transform == "log":
        if np.any(data.y <= 0):
            raise CalibrationError(f"data set {data.name}: output is modelled on the log "
                                   "scale but has values <= 0; remove them or drop "
                                   "transform: log")
        return np.log(data.y)
    return np.asarray(data.y, dtype=float)


def known_noise_var(network: Network, data: ExperimentalData) -> np.ndarray | None:
    """Known noise variance per point on the modelled scale (``(sd / y)^2`` for log)."""
    if data.noise_sd is None:
        return None
    ds = network.dataset(data.name)
    log = network.observed(ds).transform == "log"
    sd = data.noise_sd / data.y if log else data.noise_sd
    return np.asarray(sd, dtype=float) ** 2


def make_term(network: Network, data: ExperimentalData, *, emulator_variance: bool,
              plan: ChainPlan, scale: tuple[float, float] | None = None,
              directions: tuple[str, ...] = ()) -> tuple[Term, dict]:
    """The KOH term of a data set and its arrays.

    ``scale`` (mean, sd) of the observations on the modelled scale sets the default priors
    and the internal standardisation; pass the full data set's when calibrating on a
    subset (leave-one-out) so that every subset shares one compiled sampler.
    ``directions``: the models whose sampled parameters the orthogonal discrepancy is
    orthogonal to (:attr:`Term.directions`; empty: the observed model alone).
    """
    ds = network.dataset(data.name)
    model = network.model(ds.observed_model)
    y = modelled(network, data)
    mean, s = scale or standardise(y)
    noise_var = known_noise_var(network, data)
    if ds.noise.known:
        se2_prior = None
    elif ds.noise.reference:
        se2_prior = InverseGamma(2.0, s**2)
    else:
        se2_prior = scale_prior(ds.noise.prior or HalfNormalPrior(sigma=s))
    disc = ds.discrepancy
    if not disc.enabled:
        ell_priors, sd2_prior = (), None
    else:
        ell = LogNormal(disc.length_scale_prior.mu, disc.length_scale_prior.sigma)
        ell_priors = (ell,) * len(model.inputs)
        sd2_prior = (InverseGamma(2.0, s**2) if disc.reference
                     else scale_prior(disc.sd_prior or HalfNormalPrior(sigma=s)))
    term = Term(data.name, model.name, ds.observes, ell_priors, sd2_prior, se2_prior,
                orthogonal=disc.enabled and disc.orthogonal,
                emulator_variance=emulator_variance, links=links_into(plan, model.name),
                directions=tuple(directions))
    tdata = {"y": device_array((y - mean) / s, float), "y_mean": jnp.asarray(mean),
             "y_sd": jnp.asarray(s),
             "xp": {k: device_array(data.x[:, j], float)
                    for j, k in enumerate(data.input_keys)},
             "noise_var": jnp.asarray(noise_var if noise_var is not None
                                      else np.zeros(len(y)))}
    return term, tdata


# ----------------------------------------------------------------------------- parameters
def parameter_keys(network: Network, model: str) -> list[str]:
    """Keys of ``model``'s parameters in declared order (see ``Network.param_key``)."""
    return [network.param_key(model, p.name) for p in network.model(model).parameters]
