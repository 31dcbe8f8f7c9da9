"""What the stages of ``calnet run`` hand to the report: frozen result objects, each with
``to_dict()``, and :class:`RunResults`, whose :meth:`RunResults.to_metrics` is the one
place ``metrics.json`` is assembled.

Plain data only (numbers, arrays, dicts of numbers): this module imports nothing else of
calnet, so the report can read every result without importing the stages that made it.
The objects the stages already return typed (the surrogates, the predictions, the
sensitivity explorations, the emulated outputs) are held as they are and written with
their own ``summary()``/``to_dict()``.

Examples
--------
>>> c = CampaignSummary(n_total=230, n_excluded=5, status_counts={"ok": 225, "failed": 5})
>>> c.to_dict()["n_excluded"], c.n_ok
(5, 225)
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np


def rhat_text(r_hat: float, limit: float = 1.01) -> str:
    """R-hat with three decimals, or four where three would show it equal to ``limit``
    (1.0104 -> "1.0104", not "1.010 > 1.01")."""
    text = f"{r_hat:.3f}"
    return f"{r_hat:.4f}" if r_hat > limit and float(text) <= limit else text


@dataclass(frozen=True)
class CampaignSummary:
    """The simulator runs of one model's campaign.

    Attributes
    ----------
    n_total : int
        Finished runs in the store.
    n_excluded : int
        Runs left out of the surrogate fit (status not ok).
    status_counts : dict of str -> int
        Finished runs per outcome (``ok``, ``failed``, ...).
    """

    n_total: int
    n_excluded: int
    status_counts: Mapping[str, int]

    @property
    def n_ok(self) -> int:
        return self.n_total - self.n_excluded

    def to_dict(self) -> dict[str, Any]:
        return {"n_total": self.n_total, "n_excluded": self.n_excluded,
                "status_counts": dict(self.status_counts)}


@dataclass(frozen=True)
class DatasetValidation:
    """How well the calibrated network predicts one data set.

    Error measures are dicts of :func:`calnet.predict.metrics` (``n``, ``rmse``, ``nrmse``,
    ``mape`` %, ``coverage95``, ``crps``, ...), in the observed output's unit.

    Attributes
    ----------
    train : dict
        Errors of the posterior predictive at the calibration points.
    pit : ndarray (n_points,)
        Probability integral transform of every measurement under its (in-sample)
        predictive; uniform on [0, 1] for a calibrated model.
    loo : dict
        Leave-one-out by PSIS (:func:`calnet.validation.psis_loo`), with the sampler of
        the exact refits under ``sampler``.
    variance_shares : dict of str -> float
        Average share of each source in the predictive variance (sums to 1).
    test : dict or None
        Errors at the held-out test points; None without test points.
    baselines_test : dict of str -> dict, or None
        The naive baselines' errors at the test points (``training_mean``,
        ``power_law``, ``direct_gp``); None without test points.
    """

    train: Mapping[str, Any]
    pit: np.ndarray
    loo: Mapping[str, Any]
    variance_shares: Mapping[str, float]
    test: Mapping[str, Any] | None = None
    baselines_test: Mapping[str, Any] | None = None

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"train": self.train, "pit": np.asarray(self.pit).tolist()}
        if self.test is not None:
            out["test"] = self.test
        out["loo"] = self.loo
        out["variance_shares"] = self.variance_shares
        if self.baselines_test is not None:
            out["baselines_test"] = self.baselines_test
        return out


@dataclass(frozen=True)
class VariantScore:
    """One model of a comparison by leave-one-out on one data set (ArviZ ``compare``).

    Attributes
    ----------
    elpd_loo, p_loo : float
        Expected log predictive density and effective number of parameters.
    elpd_diff, dse : float
        Difference of ELPD to the best model and its standard error.
    weight : float
        Stacking weight.
    max_pareto_k : float
        Largest Pareto k of the PSIS weights.
    draws : int
        Posterior draws of the model's calibration.
    notes : tuple of str
        A variant's failed convergence or surrogate checks (the spec's own are reported
        with its calibration).
    dse_spec : float or None
        Standard error of the ELPD difference to the spec's own model (0 for the spec's).
    """

    elpd_loo: float
    p_loo: float
    elpd_diff: float
    dse: float
    weight: float
    max_pareto_k: float
    draws: int
    notes: tuple[str, ...] = ()
    dse_spec: float | None = None

    def to_dict(self) -> dict[str, Any]:
        return {"elpd_loo": self.elpd_loo, "p_loo": self.p_loo, "elpd_diff": self.elpd_diff,
                "dse": self.dse, "weight": self.weight, "max_pareto_k": self.max_pareto_k,
                "draws": self.draws, "notes": list(self.notes), "dse_spec": self.dse_spec}


#: ``{data set: {model name: score}}``; the spec's own model is named ``spec``
Comparison = Mapping[str, Mapping[str, VariantScore]]


@dataclass(frozen=True)
class PriorPanel:
    """One parameter's prior density and posterior draws, for the prior-vs-posterior
    figure.

    Attributes
    ----------
    name, unit : str
    lower, upper : float
        The parameter's calibration range.
    prior_x, prior_y : ndarray (200,)
        Grid over the range and the prior density there (1 / unit).
    posterior_samples : ndarray (n_draws,)
    mode : float
        Posterior mode (KDE).
    """

    name: str
    unit: str
    lower: float
    upper: float
    prior_x: np.ndarray
    prior_y: np.ndarray
    posterior_samples: np.ndarray
    mode: float

    def to_dict(self) -> dict[str, Any]:
        """The panel as :func:`calnet.report.figures.prior_posterior_grid` takes it."""
        return {"name": self.name, "unit": self.unit, "lower": self.lower,
                "upper": self.upper, "prior_pdf_x": self.prior_x, "prior_pdf_y": self.prior_y,
                "posterior_samples": self.posterior_samples, "mode": self.mode}


@dataclass(frozen=True)
class CalibrationResult:
    """A network calibration as the report and ``metrics.json`` see it.

    Attributes
    ----------
    mode, plug : str
        ``joint`` or ``segmented``, and how upstream parameters are plugged in
        (``"-"`` for joint).
    calibrated : bool
        False without data sets (nothing calibrated; priors kept).
    models : dict
        Per model, :func:`calnet.calibration.summary.posterior_summary`: parameters
        (range, mode, mean, interval, R-hat, ESS), divergences, max R-hat, min bulk ESS.
    rhat_max, ess_min : float
        The convergence limits the sampler's diagnostics are held to
        (:mod:`calnet.calibration.diagnostics`).
    theta : dict of model -> ndarray (n_draws, n_parameters)
        Parameter draws per model.
    panels : dict of model -> tuple of PriorPanel
        For every model with a posterior.
    sampler : dict
        The NUTS settings used (chains, warm-up, draws, ...).
    notes : tuple of str
        Problems of the posterior (warned by ``calnet run``).
    info : tuple of str
        How the calibration was set up where a user may not expect it (segmented mode's
        placement of a shared parameter or of a model without data); not a problem.
    surrogate_check : dict of data set -> dict
        The surrogates' sd at the posterior against the data's.
    datasets : dict of data set -> dict
        :func:`calnet.calibration.summary.data_set_summary`: the noise sd (known or its
        posterior) and the discrepancy's sd and length scales.
    """

    mode: str
    plug: str
    calibrated: bool
    models: Mapping[str, Mapping[str, Any]]
    rhat_max: float
    ess_min: float
    theta: Mapping[str, np.ndarray] = field(default_factory=dict)
    panels: Mapping[str, tuple[PriorPanel, ...]] = field(default_factory=dict)
    sampler: Mapping[str, Any] = field(default_factory=dict)
    notes: tuple[str, ...] = ()
    surrogate_check: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    datasets: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    info: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        """The ``calibration`` entry of metrics.json."""
        return {"mode": self.mode, "plug": self.plug, "sampler": self.sampler,
                "models": self.models, "datasets": self.datasets, "notes": list(self.notes),
                "info": list(self.info),
                "surrogate_check": self.surrogate_check}


@dataclass(frozen=True)
class RunResults:
    """Every stage's result of one ``calnet run``.

    Attributes
    ----------
    network : str
        The network's name.
    quick : bool
        Fewer draws, restarts and folds.
    campaigns : dict of model -> CampaignSummary
    surrogates : Surrogates
        :func:`calnet.surrogates.fit_network.fit_surrogates` (``summary()`` per output).
    calibration : CalibrationResult
    predictions : dict of data set -> Prediction
        :func:`calnet.predict.predict_data` at every point of the data set.
    validation : dict of data set -> DatasetValidation
    sensitivity : dict of data set -> Exploration
        :func:`calnet.explore.explore`: Sobol indices and the process map.
    predicted_outputs : dict of model.output -> OutputSlices
        The outputs of ``settings.predict``, predicted through the chain.
    comparison : Comparison or None
        The spec's discrepancy against ``settings.compare``'s variants.
    warnings : tuple of str
        Every distinct warning of the run, sorted.
    reference : dict or None
        The reference study's published values (``reference.json`` beside the spec).
    """

    network: str
    quick: bool
    campaigns: Mapping[str, CampaignSummary]
    surrogates: Any
    calibration: CalibrationResult
    predictions: Mapping[str, Any] = field(default_factory=dict)
    validation: Mapping[str, DatasetValidation] = field(default_factory=dict)
    sensitivity: Mapping[str, Any] = field(default_factory=dict)
    predicted_outputs: Mapping[str, Any] = field(default_factory=dict)
    comparison: Comparison | None = None
    warnings: tuple[str, ...] = ()
    reference: Mapping[str, Any] | None = None

    def to_metrics(self) -> dict[str, Any]:
        """The content of ``metrics.json`` (results only: two runs with the same seed give
        the same dict)."""
        out: dict[str, Any] = {
            "network": self.network, "quick": self.quick,
            "campaigns": {k: c.to_dict() for k, c in self.campaigns.items()},
            "surrogates": self.surrogates.summary(),
            "validation": {k: v.to_dict() for k, v in self.validation.items()}}
        if self.comparison is not None:
            out["comparison"] = {ds: {name: s.to_dict() for name, s in rows.items()}
                                 for ds, rows in self.comparison.items()}
        if self.calibration.calibrated:
            out["calibration"] = self.calibration.to_dict()
        out["predictions"] = {k: p.to_dict() for k, p in self.predictions.items()}
        if self.predicted_outputs:
            out["predicted_outputs"] = {k: s.to_dict()
                                        for k, s in self.predicted_outputs.items()}
        out["warnings"] = list(self.warnings)
        out["sensitivity"] = {k: e.to_dict() for k, e in self.sensitivity.items()}
        # the axes under the inputs' names (P and v for the case study)
        out["maps"] = {k: e.map.to_dict() for k, e in self.sensitivity.items()
                       if e.map is not None}
        return out
