"""Validation of a calibrated network on data: held-out test points, leave-one-out, and
naive baselines beside them (method.md sections 5 and 7)."""

from __future__ import annotations

import contextlib
import warnings
from collections.abc import Mapping, Sequence

import numpy as np
from scipy import stats
from scipy.special import logsumexp

from calnet.calibration.calibrate_network import (
    NetworkPosterior,
    StageResult,
    _owners,
    _sample,
    build_koh,
    calibrate,
    direction_models,
    stage_keys,
    with_stage,
)
from calnet.calibration.diagnostics import MORE_DRAWS, RHAT_MAX, import_arviz
from calnet.calibration.terms import data_scale, known_noise_var, parameter_keys
from calnet.chain import ChainPlan
from calnet.errors import CalibrationWarning, CalnetError, alike
from calnet.predict import Prediction, loo_conditionals, metrics, predict
from calnet.results import Comparison, DatasetValidation, VariantScore
from calnet.spec import ExperimentalData, Network
from calnet.spec.models import DiscrepancySettings, SamplerSettings
from calnet.surrogates import fit_gp
from calnet.surrogates.fit_network import Surrogates


def baselines(network: Network, train: ExperimentalData, test: ExperimentalData,
              *, seed: int = 0) -> dict[str, dict[str, float]]:
    """Metrics of two naive predictors of ``test``: the training mean, and a GP fitted
    directly to process inputs -> output on the training points."""
    every = np.r_[train.y, test.y]  # the data set's: one NRMSE scale, one MAPE rule
    span, rel = float(np.ptp(every)), relative_errors(network, train.name)
    out = {"training_mean": metrics(test.y, np.full(len(test.y), train.y.mean()),
                                    y_range=span, relative=rel, mape_y=every)}
    power = _power_law(train, test, span, relative=rel, mape_y=every)
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
        out["direct_gp"] = metrics(test.y, mean, mean - 1.96 * sd, mean + 1.96 * sd,
                                   y_range=span, relative=rel, mape_y=every)
    except Exception as err:  # too few points for a GP is a result, not a failure
        out["direct_gp"] = {"error": str(err)}
    return out


def relative_errors(network: Network, dataset: str) -> bool:
    """Whether data set ``dataset`` is modelled on the log scale: its errors are relative,
    so its MAPE is given whatever range its values span (:func:`calnet.predict.metrics`)."""
    return network.observed(network.dataset(dataset)).transform == "log"


def _power_law(train: ExperimentalData, test: ExperimentalData,
               span: float | None = None, *, relative: bool = False,
               mape_y: np.ndarray | None = None) -> dict | None:
    """``y = c prod_j x_j^b_j`` by least squares on the logs (only for positive data); the
    reference study's second naive baseline (method.md section 7)."""
    if (train.x <= 0).any() or (test.x <= 0).any() or (train.y <= 0).any():
        return None
    A = np.column_stack([np.ones(len(train.y)), np.log(train.x)])
    if len(train.y) <= A.shape[1]:
        return None
    coef, *_ = np.linalg.lstsq(A, np.log(train.y), rcond=None)
    pred = np.exp(np.column_stack([np.ones(len(test.y)), np.log(test.x)]) @ coef)
    return {**metrics(test.y, pred, y_range=span, relative=relative, mape_y=mape_y),
            "exponents": coef[1:].tolist()}


K_HAT_MAX = 0.7  # Pareto k above which PSIS is unreliable (Vehtari et al. 2024)


@contextlib.contextmanager
def _quiet_pareto():
    """ArviZ's warning of a Pareto k above 0.7 is silenced: calnet reports every k."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Estimated shape parameter of Pareto")
        yield


def psis_loo(network: Network, surrogates: Surrogates, posterior: NetworkPosterior,
             dataset: str, *, sampler: SamplerSettings | None = None, seed: int = 0,
             k_max: float = K_HAT_MAX, refit_max: int | None = None, n_samples: int = 4000,
             progress=None, y_range: float | None = None,
             mape_y: np.ndarray | None = None) -> dict:
    """Leave-one-out predictive of every calibration point of ``dataset`` by
    Pareto-smoothed importance sampling of the posterior (ArviZ's ``loo``/``psislw``).

    The pointwise log-likelihood is the KOH model's density of a point given the data
    set's other points (:func:`calnet.predict.loo_conditionals`), so the discrepancy's
    and the surrogates' correlation between points is accounted for. The LOO predictive
    of point i is the mixture over draws of those conditionals with the PSIS weights.
    Points whose Pareto k exceeds ``k_max`` are refitted exactly (the observing model's
    stage re-sampled without the point, :class:`_Refitter`) when ``sampler`` is given,
    the highest k first and at most ``refit_max`` of them; the others keep the
    PSIS answer and are counted in ``n_unreliable``.

    Returns a dict: ``calnet`` (metrics of the LOO predictive), ``training_mean``
    (the mean of the other points), ``mean``/``lower95``/``upper95`` per point,
    ``y_range`` scales the NRMSE and ``mape_y`` decides whether a MAPE is given (default:
    the calibration points; pass the whole data set's).
    ``elpd_loo``, ``elpd_se``, ``p_loo`` and ``elpd_pointwise`` (modelled scale; a
    refitted point counts with the log density of its refit's predictive, a mixture
    over the refit's draws, or where few draws carry it (a far outlier) the Gaussian of
    the same mean and variance: :meth:`calnet.predict.Prediction.log_density`), ``pareto_k`` per
    point, ``refit`` (indices refitted exactly), ``influential`` (the points over
    ``k_max``, highest k first: index, k, whether refitted, measurement and process
    inputs) and ``method``.
    """
    az = import_arviz()
    network.dataset(dataset)  # UnknownName, naming the data sets, for another name
    if dataset not in posterior.data:
        raise CalnetError(f"data set '{dataset}' was not calibrated; nothing to leave out")
    full = posterior.data[dataset]
    if posterior.n_draws < 2 or len(full.y) < 2:
        n_points = len(full.y)
        return {"method": "psis", "skipped": f"{posterior.n_draws} posterior draws and "
                f"{n_points} calibration point{'' if n_points == 1 else 's'}: nothing to "
                "leave out"}
    cond = loo_conditionals(network, surrogates, posterior, dataset)
    S, n = cond.loglik.shape
    idata = az.from_dict(log_likelihood={dataset: cond.loglik[None]})
    with _quiet_pareto():  # the k of every point is reported and acted on below
        loo = az.loo(idata, pointwise=True, reff=1.0)
        logw, khat = az.psislw(-cond.loglik.T.copy(), reff=1.0)  # (n, S) log weights
    khat = np.asarray(khat)
    w = np.exp(np.asarray(logw))
    rng = np.random.default_rng(seed)
    mean, lo, hi = np.empty(n), np.empty(n), np.empty(n)
    samples = np.empty((n_samples, n))
    # LOO-PIT, exact for the mixture (a monotone transform leaves it unchanged)
    pit = np.sum(w * stats.norm.cdf((cond.y[None] - cond.mean) / cond.sd).T, axis=1) \
        / w.sum(axis=1)
    for i in range(n):
        comp = rng.choice(S, size=n_samples, p=w[i] / w[i].sum())
        z = cond.mean[comp, i] + cond.sd[comp, i] * rng.standard_normal(n_samples)
        samples[:, i] = np.exp(z) if cond.log else z
        # the mixture's own 2.5 and 97.5 % quantiles, so that the band agrees with the
        # exact LOO-PIT (a point is outside the band exactly when its PIT is in the tails)
        q = [_mixture_quantile(w[i] / w[i].sum(), cond.mean[:, i], cond.sd[:, i], p)
             for p in (0.025, 0.975)]
        if cond.log:  # the mixture of log-normals' mean, from the log weights
            lw = np.asarray(logw)[i]
            mean[i] = np.exp(logsumexp(lw + cond.mean[:, i] + 0.5 * cond.sd[:, i] ** 2)
                             - logsumexp(lw))
            lo[i], hi[i] = np.exp(q)
        else:
            mean[i] = np.sum(w[i] * cond.mean[:, i]) / w[i].sum()
            lo[i], hi[i] = q
    bad = np.flatnonzero(khat > k_max)
    ranked = bad[np.argsort(-khat[bad], kind="stable")]  # highest k first
    todo = ranked[:refit_max] if sampler else ranked[:0]
    refit, gaussian = [], []
    pointwise = np.asarray(loo.loo_i, float)  # (n,) log predictive density of each point
    if len(todo):
        refitter = _Refitter(network, surrogates, posterior, full, sampler)
        with _once_per_kind(f"exact leave-one-out refits of {dataset}"):
            for j, i in enumerate(todo):
                if progress:
                    progress(j, len(todo))
                mean[i], lo[i], hi[i], samples[:, i], pit[i], pointwise[i], mixed = \
                    refitter.predict(int(i), seed + int(i), n_samples)
                refit.append(int(i))
                if not mixed:
                    gaussian.append(int(i))
    refit.sort()
    if refit:  # the refitted points' exact densities replace their importance-sampled ones
        loo = _with_pointwise(loo, pointwise)
    naive = np.array([np.delete(full.y, i).mean() for i in range(n)])
    influential = [{"point": int(i), "pareto_k": float(khat[i]), "refit": int(i) in refit,
                    "density": ("moment-matched Gaussian" if int(i) in gaussian
                                else "mixture" if int(i) in refit else "PSIS"),
                    "y": float(full.y[i]),
                    "inputs": {k.split(".", 1)[1]: float(full.x[i, j])
                               for j, k in enumerate(full.input_keys)}}
                   for i in ranked]
    return {"method": "psis",
            "calnet": metrics(full.y, mean, lo, hi, samples=samples, pit=pit,
                              y_range=y_range, relative=bool(cond.log), mape_y=mape_y),
            "training_mean": metrics(full.y, naive, y_range=y_range,
                                     relative=bool(cond.log), mape_y=mape_y),
            "mean": mean.tolist(), "lower95": lo.tolist(), "upper95": hi.tolist(),
            "pit": pit.tolist(),
            "pit_check": pit_check(dataset, pit, fixed=_nothing_estimated(network, dataset)),
            "elpd_loo": float(loo["elpd_loo"]), "elpd_se": float(loo["se"]),
            "p_loo": float(loo["p_loo"]),
            "elpd_pointwise": pointwise.tolist(), "pareto_k": khat.tolist(),
            "max_pareto_k": float(khat.max()) if khat.size else None, "k_threshold": k_max,
            "n_unreliable": int(len(bad)) - len(refit), "refit": refit,
            "influential": influential, "n_draws": S}


PIT_P_MIN = 0.01  # a Kolmogorov-Smirnov p-value of the PIT below this flags the model
#: what a flagged predictive check concludes
NOT_DESCRIBED = "the model, its discrepancy or its noise does not describe these data"


def _nothing_estimated(network: Network, dataset: str) -> bool:
    """Whether data set ``dataset``'s noise is known and it has no discrepancy: neither
    term of its likelihood has a prior that could be too generous."""
    ds = network.dataset(dataset)
    return bool(ds.noise.known and not ds.discrepancy.enabled)


def pit_check(name: str, pit, *, fixed: bool = False) -> dict:
    """Whether the predictive is calibrated for data set ``name``, from its PIT values:
    a Kolmogorov-Smirnov test against the uniform distribution (bias, too wide), and a
    binomial test of the number of points outside the central 95 % band (too narrow;
    the KS test is weak against PIT values piled at both ends), and one of the number
    inside the central 50 % band (too wide). ``fixed``: the noise is known and there is
    no discrepancy, so a too-wide predictive is not put down to their priors. Returns
    ``dict(ks_pvalue, outside95, outside_pvalue, inside50, inside50_pvalue, flagged,
    too_wide, message)``."""
    pit = np.asarray(pit, float)
    n, outside, p_out = _outside95(pit)
    inside50 = int(np.sum(np.abs(pit - 0.5) <= 0.25))
    p_ks = float(stats.kstest(pit, "uniform").pvalue) if n >= 3 else float("nan")
    # too wide: too many points in the central half (the KS test is weak there too)
    p_wide = float(stats.binom.sf(inside50 - 1, n, 0.5)) if n else float("nan")
    flagged = bool(p_ks < PIT_P_MIN or p_out < PIT_P_MIN or p_wide < PIT_P_MIN)
    message = ""
    too_wide = bool(flagged and p_out >= PIT_P_MIN and (p_wide < PIT_P_MIN or np.mean(
        np.abs(pit - 0.5) < 0.25) > 0.75))
    if too_wide:
        why = ("the declared noise sd may be larger than these data's scatter (or, with "
               "few points, it may be chance)" if fixed else
               "its noise or discrepancy is larger than these data need (their priors may "
               "be too generous)")
        message = (f"{name}: the leave-one-out predictive is too wide ({inside50} of {n} "
                   f"points inside its central 50 % band where {0.5 * n:.1f} are expected, "
                   f"p = {p_wide:.2g}; PIT uniformity p = {p_ks:.2g}); {why}, so its bands "
                   "overstate the uncertainty")
    elif flagged:
        shape = ("too narrow: the data fall in its tails" if p_out < PIT_P_MIN else
                 "biased" if abs(float(np.mean(pit)) - 0.5) > 0.15 else "miscalibrated")
        message = (f"{name}: the leave-one-out predictive is {shape} ({outside} of {n} "
                   f"points outside its 95 % band where {0.05 * n:.1f} are expected, "
                   f"p = {p_out:.2g}; PIT uniformity p = {p_ks:.2g}); {NOT_DESCRIBED}")
    return {"ks_pvalue": p_ks, "outside95": outside, "outside_pvalue": p_out,
            "inside50": inside50, "inside50_pvalue": p_wide, "flagged": flagged,
            "too_wide": too_wide, "message": message}


def _outside95(pit: np.ndarray) -> tuple[int, int, float]:
    """Points, points outside the central 95 % band (PIT below 0.025 or above 0.975), and
    the binomial p-value of at least that many where 5 % are expected."""
    n = len(pit)
    outside = int(np.sum((pit < 0.025) | (pit > 0.975)))
    return n, outside, float(stats.binom.sf(outside - 1, n, 0.05)) if n else float("nan")


def fit_check(name: str, pit) -> dict:
    """Whether the posterior predictive covers its own calibration points: a binomial
    test of the number outside its central 95 % band. A well-specified model's in-sample
    band covers at least 95 % (it has seen the points), so too many outside is strong
    evidence of misfit, also where leave-one-out looks better (a surrogate's variance in
    the likelihood, correlated across the points, lets a left-out point be predicted
    from its neighbours' misfit). Returns ``dict(outside95, n, outside_pvalue, flagged,
    message)``."""
    n, outside, p_out = _outside95(np.asarray(pit, float))
    flagged = bool(p_out < PIT_P_MIN)
    message = (f"{name}: the posterior predictive misses its own calibration points "
               f"({outside} of {n} outside its 95 % band where at most {0.05 * n:.1f} are "
               f"expected, p = {p_out:.2g}); {NOT_DESCRIBED}") if flagged else ""
    return {"outside95": outside, "n": n, "outside_pvalue": p_out, "flagged": flagged,
            "message": message}


def held_out_check(name: str, pit, where: list[str] | None = None,
                   n_samples: int | None = None) -> dict:
    """Whether the posterior predictive covers data set ``name``'s test points, which the
    calibration has not seen: a binomial test of the number outside its central 95 %
    band, and a test of the most extreme point (its two-sided tail probability
    ``2 min(PIT, 1 - PIT)`` times the number of points, Bonferroni's bound: a p-value
    whatever the predictive's shape), which flags one point far in a tail that a count
    of a few points cannot. ``pit`` is exact (:meth:`calnet.predict.Prediction.pit`) or,
    with ``n_samples``, from that many predictive samples, which resolve tail
    probabilities down to about ``1 / n_samples`` only: a point beyond every sample then
    counts as lying at half a sample's share. ``where`` names the points (their
    settings). Returns ``dict(outside95, n, outside_pvalue, extreme_pvalue,
    extreme_index, flagged, message)``."""
    pit = np.asarray(pit, float)
    n, outside, p_out = _outside95(pit)
    if not n:
        return {"outside95": 0, "n": 0, "outside_pvalue": float("nan"),
                "extreme_pvalue": float("nan"), "extreme_index": None, "flagged": False,
                "message": ""}
    floor = 0.5 / max(int(n_samples), 1) if n_samples else np.finfo(float).tiny
    tail = 2.0 * np.minimum(np.clip(pit, floor, 1.0 - floor),
                            1.0 - np.clip(pit, floor, 1.0 - floor))
    worst = int(np.argmin(tail))
    p_extreme = float(min(1.0, n * tail[worst]))
    flagged = bool(p_out < PIT_P_MIN or p_extreme < PIT_P_MIN)
    message = ""
    if flagged:
        side = "below" if pit[worst] < 0.5 else "above"
        share = pit[worst] if side == "below" else 1.0 - pit[worst]
        if n_samples:
            beyond = ("every sample of its predictive" if share == 0 else
                      f"{1 - share:.4g} of its predictive's samples")
        else:
            beyond = f"all but {share:.2g} of its predictive"
        message = (f"{name}: the posterior predictive misses its test points, which the "
                   f"calibration has not seen ({outside} of {n} outside its 95 % band "
                   f"where {0.05 * n:.1f} are expected, p = {p_out:.2g}; the test point "
                   f"at {where[worst] if where else worst + 1} lies {side} {beyond}, "
                   f"p = {p_extreme:.2g} for the most extreme of {n}); {NOT_DESCRIBED}")
    return {"outside95": outside, "n": n, "outside_pvalue": p_out,
            "extreme_pvalue": p_extreme, "extreme_index": worst, "flagged": flagged,
            "message": message}


def misfit_hint(network: Network, name: str, surrogate_warned: bool,
                unconverged: float | None = None) -> str:
    """What to try when data set ``name``'s predictive checks flag a misfit
    (``unconverged``: the R-hat of a stage behind it that did not converge)."""
    hints = []
    if unconverged is not None:
        hints.append(f"its calibration did not converge (R-hat {unconverged:.3g}): these "
                     "checks inherit that, so fix the sampling first")
    if not network.dataset(name).discrepancy.enabled:
        hints.append("its spec sets discrepancy: none; the default discrepancy (or "
                     "settings.compare: [reference]) would show whether one is needed")
    if surrogate_warned:
        hints.append("the surrogate check warns for it too: misfit counted as surrogate "
                     "error makes leave-one-out look better than the fit")
    model = network.dataset(name).observed_model
    others = [d.name for d in network.datasets_for(model) if d.name != name]
    if others:
        hints.append(f"{', '.join(others)} also observe{'s' if len(others) == 1 else ''} "
                     f"'{model}': data sets that pull its parameters apart each show misfit "
                     "(the one that fits may be flagged too); calibrating with each alone "
                     "shows which")
    return "".join(f"; {h}" for h in hints)


#: a naive predictor whose test RMSE is below this fraction of calnet's is warned of
BASELINE_BETTER = 0.5
_NAIVE = {"training_mean": "the training mean", "power_law": "a power law in the inputs",
          "direct_gp": "a GP fitted directly to the training points"}


def baseline_check(name: str, test: dict | None, naive: dict | None) -> str | None:
    """A warning where a naive predictor of data set ``name``'s test points (the
    :func:`baselines`) has an RMSE below :data:`BASELINE_BETTER` of the calibrated
    network's: the network then misses structure that the data themselves show (its
    model form, or surrogates whose error the discrepancy absorbs)."""
    if not test or not naive or not test.get("n"):
        return None
    scored = {k: m["rmse"] for k, m in naive.items() if isinstance(m, dict) and "rmse" in m}
    if not scored:
        return None
    best = min(scored, key=scored.get)
    if not scored[best] < BASELINE_BETTER * test["rmse"]:
        return None
    return (f"{name}: {_NAIVE.get(best, best)} predicts the {test['n']} test point(s) "
            f"{test['rmse'] / max(scored[best], 1e-300):.1f} times better than the calibrated "
            f"network (RMSE {scored[best]:.3g} against {test['rmse']:.3g}): the network "
            "misses structure the data show (its model form, or surrogate error that the "
            "discrepancy takes up); see the surrogate checks and 'calnet verify'")


VARIANTS = ("no_discrepancy", "non_orthogonal", "reference")


def variant(network: Network, name: str) -> Network:
    """``network`` with every data set's discrepancy replaced: ``no_discrepancy`` (none),
    ``non_orthogonal`` (the same priors, not orthogonal to the parameters; a data set
    without a discrepancy keeps none) or ``reference`` (the reference study's KOH)."""
    def new(ds):
        if name == "no_discrepancy":
            return DiscrepancySettings(enabled=False)
        if name == "non_orthogonal":  # a data set without a discrepancy keeps none
            return (ds.discrepancy.model_copy(update={"orthogonal": False})
                    if ds.discrepancy.enabled else ds.discrepancy)
        if name == "reference":
            return DiscrepancySettings.model_validate("reference")
        raise ValueError(f"unknown variant '{name}'; known: {list(VARIANTS)}")

    data = tuple(ds.model_copy(update={"discrepancy": new(ds)}) for ds in network.data)
    return network.model_copy(update={"data": data})


def changes_nothing(same: tuple[str, ...], then: str, why: str = "") -> str:
    """``"no_discrepancy changes nothing in this spec<why>, so it is <then>"`` for the
    variants ``same`` that :func:`same_as_spec` found."""
    one = len(same) == 1
    return (f"{' and '.join(same)} change{'s' if one else ''} nothing in this spec{why}, so "
            f"{'it is' if one else 'they are'} {then}")


def same_as_spec(network: Network, variants) -> tuple[str, ...]:
    """The ``variants`` that change nothing in ``network`` (``no_discrepancy`` where no
    data set has a discrepancy, ``non_orthogonal`` where none has an orthogonal one):
    comparing them would compare the spec's model with itself."""
    return tuple(name for name in variants if variant(network, name) == network)


#: the most chains, warm-up iterations and draws of :func:`secondary_sampler`
SECONDARY_MOST = {"chains": 2, "warmup": 300, "draws": 500}


def secondary_sampler(sampler: SamplerSettings) -> SamplerSettings:
    """The sampler of the calibrations made beside the spec's own (exact leave-one-out
    refits, the variants of :func:`compare_variants`): at most :data:`SECONDARY_MOST`
    (2 chains of 300 warm-up and 500 draws), plenty for a predictive mean and band or a
    leave-one-out ELPD."""
    return sampler.model_copy(update={k: min(getattr(sampler, k), most)
                                      for k, most in SECONDARY_MOST.items()})


def calibrate_variants(network: Network, surrogates: Surrogates, data, variants, *,
                       sampler: SamplerSettings, seed: int = 0,
                       progress=None) -> dict[str, tuple[Network, NetworkPosterior]]:
    """Calibrate each variant of ``network`` (:func:`variant`) on ``data`` (data set ->
    training :class:`ExperimentalData`): ``{variant: (network, posterior)}``.

    Nothing is warned: each posterior's convergence and surrogate checks are in its
    ``notes``, so this can run in a thread beside the spec's own calibration.
    """
    out = {}
    for name in variants:
        if progress:
            progress(name)
        net = variant(network, name)
        out[name] = (net, calibrate(net, surrogates, data=dict(data), seed=seed,
                                    sampler=sampler, warn=False))
    return out


def compare_variants(network: Network, surrogates: Surrogates, posterior: NetworkPosterior,
                     variants: tuple[str, ...], *, sampler: SamplerSettings, seed: int = 0,
                     progress=None, calibrated=None,
                     spec_pointwise: Mapping[str, np.ndarray] | None = None,
                     spec_refit: Mapping[str, Sequence[int]] | None = None) -> Comparison:
    """Calibrate each variant of ``network`` (:func:`variant`) on the posterior's data
    and compare it with the spec's own model by PSIS-LOO, per data set (ArviZ's
    ``compare``: ELPD, difference to the best and its standard error, stacking weight).

    ``sampler``: the spec's; the variants are calibrated with its
    :func:`secondary_sampler`. ``calibrated``: the variants' ``{name: (network,
    posterior)}`` from :func:`calibrate_variants` (with that sampler), when they were
    calibrated already. ``spec_pointwise``:
    ``{data set: pointwise ELPD}`` of the spec's model from :func:`psis_loo` with its
    exact refits (``elpd_pointwise``), so that the comparison scores the spec's model as
    its leave-one-out does, and ``spec_refit``: ``{data set: the points refitted}``,
    whose Pareto k then no longer matters; the variants are not refitted (their Pareto k
    says how far to trust them).

    Returns ``{data set: {model name: VariantScore}}`` where the spec's own model is
    named ``spec``; a score's ``notes`` are a variant's failed convergence or surrogate
    checks (the spec's own are reported with its calibration).
    """
    az = import_arviz()
    if calibrated is None:
        calibrated = calibrate_variants(network, surrogates, posterior.data, variants,
                                        sampler=secondary_sampler(sampler), seed=seed,
                                        progress=progress)
    posts = {"spec": (network, posterior), **calibrated}
    out = {}
    for ds in posterior.data:
        loos = {}
        for name, (net, post) in posts.items():
            ll = loo_conditionals(net, surrogates, post, ds).loglik
            with _quiet_pareto():
                loos[name] = az.loo(az.from_dict(log_likelihood={ds: ll[None]}),
                                    pointwise=True, reff=1.0)
        if spec_pointwise is not None and ds in spec_pointwise:
            loos["spec"] = _with_pointwise(loos["spec"], spec_pointwise[ds])
        pointwise = {name: np.asarray(loo["loo_i"], float) for name, loo in loos.items()}
        with _quiet_pareto(), warnings.catch_warnings():
            # ArviZ 0.23's compare sorts in place, which pandas >= 3.1 deprecates: not
            # the user's to act on
            warnings.filterwarnings("ignore", message="The inplace keyword")
            table = az.compare(loos, ic="loo")
        out[ds] = {name: VariantScore(
                       elpd_loo=float(row["elpd_loo"]), p_loo=float(row["p_loo"]),
                       elpd_diff=float(row["elpd_diff"]), dse=float(row["dse"]),
                       weight=float(row["weight"]),
                       max_pareto_k=_max_k(loos[name].pareto_k, (spec_refit or {}).get(ds, ())
                                           if name == "spec" else ()),
                       draws=int(posts[name][1].n_draws),
                       notes=() if name == "spec" else tuple(
                           _variant_note(n, sampler) for n in posts[name][1].notes),
                       dse_spec=_pair_se(pointwise["spec"], pointwise[name]))
                   for name, row in table.iterrows()}
    return out


def _variant_note(note: str, sampler: SamplerSettings) -> str:
    """A variant's calibration note, whose advice to raise the draws cannot help where
    the variants' sampler (:func:`secondary_sampler` of the spec's ``sampler``) is at its
    cap."""
    if not note.endswith(MORE_DRAWS) or sampler.draws < SECONDARY_MOST["draws"]:
        return note  # more draws would reach the variants
    used = secondary_sampler(sampler)
    return note.removesuffix(MORE_DRAWS) + (
        f"the variants compared sample {used.chains} chains of {used.draws} draws whatever "
        "settings.sampler says, so its ELPD carries more Monte Carlo error than the spec's")


def _max_k(khat, refitted: Sequence[int]) -> float:
    """The largest Pareto k of the points not refitted exactly (0 where all were)."""
    k = np.asarray(khat, float).copy()
    k[list(refitted)] = -np.inf
    return float(max(k.max(), 0.0)) if k.size else 0.0


def _with_pointwise(loo, pointwise: np.ndarray):
    """ArviZ's ``ELPDData`` ``loo`` with the pointwise ELPD ``pointwise`` (n,): the ELPD,
    its standard error and ``p_loo`` (the in-sample lppd less the ELPD) from it."""
    pointwise = np.asarray(pointwise, float)
    lppd = float(loo["elpd_loo"]) + float(loo["p_loo"])
    new = loo.copy()
    new["loo_i"] = loo["loo_i"].copy(data=pointwise)
    new["elpd_loo"] = float(pointwise.sum())
    new["se"] = float(np.sqrt(len(pointwise) * np.var(pointwise)))
    new["p_loo"] = lppd - new["elpd_loo"]
    return new


def _pair_se(a: np.ndarray, b: np.ndarray) -> float:
    """Standard error of the ELPD difference of two models from their pointwise values
    (ArviZ's ``dse`` for a pair)."""
    d = np.asarray(a, float) - np.asarray(b, float)
    return float(np.sqrt(len(d) * np.var(d)))


def validate_dataset(network: Network, surrogates: Surrogates, posterior: NetworkPosterior,
                     data: ExperimentalData, prediction: Prediction, *,
                     sampler: SamplerSettings, seed: int = 0, loo_max: int | None = None,
                     baselines_test: dict | None = None, progress=None) -> DatasetValidation:
    """Errors of the posterior predictive of one data set: at its calibration points, at
    its test points, left out one at a time (:func:`psis_loo`), with the PIT of every
    point and the predictive variance's shares.

    Parameters
    ----------
    data : ExperimentalData
        The whole data set (training and test rows, ``data.is_test``).
    prediction : Prediction
        :func:`calnet.predict.predict_data` at every row of ``data``.
    sampler : SamplerSettings
        The calibration's sampler; the exact leave-one-out refits use
        :func:`secondary_sampler` of it.
    loo_max : int, optional
        Most points re-calibrated exactly where PSIS is unreliable.
    baselines_test : dict, optional
        :func:`baselines` at the test points.
    progress : callable, optional
        ``progress(text)`` with the refits done.

    Returns
    -------
    DatasetValidation
    """
    pred, train = prediction, ~data.is_test
    pit = pred.pit(data.y)  # posterior predictive check: uniform if calibrated
    span = float(np.ptp(data.y))  # every split's NRMSE on the whole data set's range
    rel = relative_errors(network, data.name)
    errors = metrics(data.y[train], pred.mean[train], pred.lower[train], pred.upper[train],
                     samples=pred.samples[:, train], pit=pit[train], y_range=span,
                     relative=rel, mape_y=data.y)
    test = None
    if data.is_test.any():
        test = metrics(data.test.y, pred.mean[data.is_test], pred.lower[data.is_test],
                       pred.upper[data.is_test], samples=pred.samples[:, data.is_test],
                       pit=pit[data.is_test], y_range=span, relative=rel, mape_y=data.y)
    # PSIS on the posterior; a point with Pareto k > 0.7 re-samples the observing model's
    # stage without it
    loo_sampler = secondary_sampler(sampler)
    loo = psis_loo(network, surrogates, posterior, data.name, sampler=loo_sampler, seed=seed,
                   refit_max=loo_max, y_range=span, mape_y=data.y,
                   progress=(lambda i, n: progress(f"LOO refit {data.name} {i + 1}/{n}"))
                   if progress else None)
    loo["fit_check"] = fit = fit_check(data.name, pit[train])
    check = loo.get("pit_check", {})
    said = check.get("message") if check.get("flagged") else fit["message"]
    if said and check.get("flagged") and fit["flagged"]:  # the stronger evidence too
        said += (f"; in-sample {fit['outside95']} of {fit['n']} calibration points fall "
                 f"outside the posterior predictive's 95 % band (p = "
                 f"{fit['outside_pvalue']:.2g})")
    if test is not None:
        where = [", ".join(f"{k}={v:.4g}" for k, v in zip(data.input_keys, row, strict=True))
                 for row in data.x[data.is_test]]
        test["check"] = held_out = held_out_check(data.name, pit[data.is_test], where)
        if held_out["flagged"]:
            said = (said + "; and " + held_out["message"].split(": ", 1)[1] if said
                    else held_out["message"])
    if said.count(NOT_DESCRIBED) > 1:  # the checks' common conclusion, said once
        said = said.replace("; " + NOT_DESCRIBED, "") + "; " + NOT_DESCRIBED
    if said and not (check.get("flagged") and check.get("too_wide")):  # a misfit: hints
        warned = any(c.dataset == data.name and c.message() for c in posterior.checks)
        rhat = max((st.diagnostics.max_r_hat for st in posterior.stages
                    if data.name in st.datasets and st.diagnostics is not None),
                   default=None)
        said += misfit_hint(network, data.name, warned,
                            rhat if rhat is not None and rhat > RHAT_MAX else None)
    if said:
        warnings.warn(said, CalibrationWarning, stacklevel=2)
    loo["sampler"] = {"chains": loo_sampler.chains, "warmup": loo_sampler.warmup,
                      "draws": loo_sampler.draws}
    return DatasetValidation(train=errors, pit=pit, loo=loo, variance_shares=pred.shares(),
                             test=test, baselines_test=baselines_test)


def _mixture_quantile(weights: np.ndarray, mean: np.ndarray, sd: np.ndarray,
                      p: float) -> float:
    """The ``p`` quantile of the Gaussian mixture ``sum_s weights_s N(mean_s, sd_s^2)``
    (weights summing to 1), by bisection on its distribution function."""
    from scipy.optimize import brentq

    lo, hi = float(np.min(mean - 12 * sd)), float(np.max(mean + 12 * sd))
    return float(brentq(lambda q: float(weights @ stats.norm.cdf((q - mean) / sd)) - p,
                        lo, hi, xtol=1e-12 * max(1.0, abs(lo), abs(hi))))


REFIT_DRAWS = 400  # posterior draws of a refit's predictive at its point


@contextlib.contextmanager
def _once_per_kind(what: str):
    """Warnings given in the block, each kind once (:func:`calnet.errors.alike`: the
    refits of one data set warn alike, with other chains and numbers), with how many
    times ``what`` gave it."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        yield
    texts = [str(w.message) for w in caught]
    for text, n in alike(texts):
        w = caught[texts.index(text)]
        more = f" ({n} of the {what} said so)" if n > 1 else ""
        warnings.warn_explicit(text + more, w.category, w.filename, w.lineno)


class _Refitter:
    """Exact leave-one-out of single points: the observing model's stage re-sampled
    without the point, the other models' parameters held at their posterior means (a
    segmented view). Every fold has the same shapes and priors (the full data set's
    scale), so one compiled sampler serves all of them."""

    def __init__(self, network, surrogates, posterior, full, sampler):
        self.network, self.surrogates, self.posterior = network, surrogates, posterior
        self.full, self.sampler = full, sampler
        self.model = network.dataset(full.name).observed_model
        self.plan = ChainPlan.from_network(network)
        # the parameters that segmented mode calibrates with this model's data: its own,
        # and those of the models upstream without data of their own
        self.own = stage_keys(network, _owners(network, posterior.data), self.model)[1]
        self.fixed = {}
        for m, draws in posterior.theta.items():
            for j, k in enumerate(parameter_keys(network, m)):
                if k not in self.own:
                    self.fixed[k] = float(np.mean(draws[:, j]))
        self.scales = {full.name: data_scale(network, full, surrogates)}
        # the calibration's discrepancy, also where the refit holds parameters fixed
        self.directions = {full.name: direction_models(network, posterior, full.name)}

    def predict(self, i: int, seed: int, n_samples: int = 4000):
        """Mean, 95 % bounds, ``n_samples`` predictive samples, the PIT and the log
        predictive density (modelled scale) of point i."""
        full, network = self.full, self.network
        data_i = full.subset(np.arange(len(full.y)) != i)
        ld = build_koh(network, self.surrogates, free=self.own, datasets={full.name: data_i},
                       fixed=self.fixed, name=f"{self.model} LOO", plan=self.plan,
                       scales=self.scales, directions=self.directions,
                       emulator_variance=network.settings.calibration.emulator_variance)
        idata = _sample(ld, self.sampler, seed)
        stage = StageResult((self.model,), (full.name,), idata, ld)
        post_i = with_stage(self.posterior, stage, {full.name: data_i})
        pred = predict(network, self.surrogates, post_i, full.name, full.x[i:i + 1],
                       n_draws=REFIT_DRAWS, n_samples=-(-n_samples // REFIT_DRAWS),
                       seed=seed, noise_var=_noise_var(network, full, i),
                       warn_outside=False)  # the data's bounds are checked when read
        draws = np.resize(pred.samples[:, 0], n_samples)
        lpd, mixture = pred.log_density(full.y[i:i + 1])
        return (float(pred.mean[0]), float(pred.lower[0]), float(pred.upper[0]), draws,
                float(pred.pit(full.y[i:i + 1])[0]), float(lpd[0]), bool(mixture[0]))


def _noise_var(network: Network, data: ExperimentalData, i: int):
    var = known_noise_var(network, data)
    return None if var is None else var[i:i + 1]
