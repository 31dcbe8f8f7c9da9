"""What a finished run hands the report: its results, small (for the headline and render
tests)."""

from calnet.results import CalibrationResult, DatasetValidation, RunResults

GUARD = ("pdas: the surrogate, not the data, sets the answer: the surrogate sd at the "
         "posterior (0.107) is 0.68 x the data's noise and discrepancy sd (0.157), ...")
RHAT = ("micro: R-hat 1.018 > 1.01 for ell_width[v]; chains disagree - raise "
        "settings.sampler.warmup and draws; chains that still disagree sit in separate "
        "modes the data cannot tell apart")
ESS = "micro: bulk ESS 178 < 400 for ell_width[v]; raise settings.sampler.draws"
BOUND = "micro.b: the posterior presses against its upper bound 1.6 (median 1.59); ..."


def row(mean, lo, hi, unit="W", **extra):
    return {"unit": unit, "lower": 0.0, "upper": 10.0, "mode": mean, "mean": mean,
            "sd": 0.1, "q2.5": lo, "q97.5": hi, "rhat": 1.0, "ess_bulk": 900.0, **extra}


def summary(rhat=1.002, ess=900.0, divergences=0):
    return {
        "thermal": {"parameters": {"a": row(1.2, 1.1, 1.3),
                                   "s": row(5.0, 4.0, 6.0, "1", shared=True)},
                    "max_rhat": 1.003, "min_ess_bulk": 1200.0, "divergences": 0,
                    "stage": "thermal"},
        "micro": {"parameters": {"b": row(0.8, 0.7, 0.9, "um"),
                                 "s": row(5.0, 4.0, 6.0, "1", shared=True)},
                  "max_rhat": rhat, "min_ess_bulk": ess, "divergences": divergences,
                  "stage": "micro"},
        "extra": {"prior_only": True}}


def calibration(summary_=None, *, mode="segmented", checks=None, notes=()):
    if checks is None:
        checks = {"pdas": {"ratio": 0.68, "warning": GUARD,
                           "surrogate_sd": {"thermal.G": 0.06, "micro.lam": 0.09},
                           "runs": {"thermal.G": 40, "micro.lam": 30},
                           "runs_needed": {"thermal.G": 900, "micro.lam": 552},
                           "needing_runs": ["micro.lam", "thermal.G"]},
                  "width": {"ratio": 0.2, "warning": None, "surrogate_sd": {},
                            "runs": {}, "runs_needed": {}}}
    return CalibrationResult(mode=mode, plug="mode", calibrated=True, rhat_max=1.01, ess_min=400,
                             models=summary() if summary_ is None else summary_,
                             notes=tuple(notes), surrogate_check=checks)


def err(rmse, mape, n):
    return {"rmse": rmse, "mape": mape, "n": n}


def validation():
    return {
        "width": DatasetValidation(
            train=err(7.7, 8.1, 30), test=err(12.9, 12.3, 10), pit=[], variance_shares={},
            baselines_test={"training_mean": err(44.1, 38.8, 10),
                            "direct_gp": {"error": "too few points"}},
            loo={"skipped": "40 points > loo_max 15"}),
        "hard": DatasetValidation(
            train=err(1.0, 0.5, 8), pit=[], variance_shares={},
            loo={"calnet": err(2.06, 0.762, 8), "training_mean": err(23.6, 10.4, 8)}),
        "tiny": DatasetValidation(train=err(0.1, 1.0, 3), pit=[], variance_shares={},
                                  loo={"skipped": "..."})}


def results(warnings=(), *, cal=None, valid=None, **kw):
    """A segmented run of three models (one at its prior) with three data sets."""
    return RunResults(network="t", quick=False, campaigns={}, surrogates=None,
                      calibration=calibration() if cal is None else cal,
                      validation=validation() if valid is None else valid,
                      warnings=tuple(sorted([GUARD, *warnings])), **kw)
