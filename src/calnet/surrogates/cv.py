"""k-fold cross-validation of GP surrogates and its metrics (method.md section 2).

Each point is predicted by a GP fitted without its fold. Predictions are reported on the
natural output scale; for ``transform="log"`` the point prediction is the lognormal mean
and the 95 % interval is ``exp(mu +- 1.96 sd)`` from the log-scale moments.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from calnet.errors import SurrogateError
from calnet.surrogates.fit import fit_gp, held_out_predictions, validate_training_data
from calnet.surrogates.likelihood import n_basis, trend_runs

Z95 = 1.959963984540054  # standard normal 97.5 % quantile


@dataclass(frozen=True)
class CVResult:
    """Out-of-fold predictions and metrics of a k-fold cross-validation.

    Attributes
    ----------
    y : ndarray, shape (n,)
        Observed outputs, natural scale.
    mean, var : ndarray, shape (n,)
        Out-of-fold predictive mean and variance, natural scale (variance of a new
        simulator run: it includes the nugget).
    lower95, upper95 : ndarray, shape (n,)
        Central 95 % predictive interval, natural scale.
    mean_modelled, var_modelled : ndarray, shape (n,)
        The same predictions on the modelled scale (``log`` scale if ``transform="log"``).
    fold : ndarray of int, shape (n,)
        Fold index of each point, 0 .. k-1.
    mape : float or None
        ``mean(|y - mean| / |y|) * 100``, percent; None where outputs reach or come near
        zero (see :func:`cv_metrics`).
    rmse : float
        ``sqrt(mean((y - mean)^2))``, output units.
    coverage95 : float
        Fraction of points with ``lower95 <= y <= upper95``, in [0, 1].
    n, k : int
        Number of points and of folds.
    name : str
    transform : {None, "log"}
    """

    y: np.ndarray
    mean: np.ndarray
    var: np.ndarray
    lower95: np.ndarray
    upper95: np.ndarray
    mean_modelled: np.ndarray
    var_modelled: np.ndarray
    fold: np.ndarray
    mape: float | None
    rmse: float
    coverage95: float
    n: int
    k: int
    name: str = ""
    transform: str | None = None

    def metrics(self) -> dict[str, float | int | str | None]:
        """The scalar results as a JSON-ready dict (for ``metrics.json``)."""
        return {"name": self.name, "transform": self.transform, "n": self.n, "k": self.k,
                "mape": self.mape, "rmse": self.rmse, "coverage95": self.coverage95}


def cv_metrics(y, yhat, lower95, upper95, *, transform: str | None = None) -> dict:
    """MAPE (%), RMSE and 95 % interval coverage of predictions.

    Parameters
    ----------
    y, yhat, lower95, upper95 : array, shape (n,)
        Observations, point predictions and interval ends, same units.
    transform : {None, "log"}
        With ``"log"`` (a positive output modelled on the log scale, whose errors are
        relative) MAPE is always given; else only where every ``y`` has one sign and
        ``|y| >= 0.01 max |y|`` (a value at or near zero turns a small error into hundreds
        of percent; a simulator output over a whole design box may well span two decades).

    Returns
    -------
    dict
        ``{"mape": float (percent) or None, "rmse": float, "coverage95": float in
        [0, 1]}``.

    Examples
    --------
    >>> cv_metrics([1.0, 2.0], [1.1, 2.0], [0.9, 2.5], [1.2, 3.0])["coverage95"]
    0.5
    """
    y, yhat = np.asarray(y, float), np.asarray(yhat, float)
    lo, hi = np.asarray(lower95, float), np.asarray(upper95, float)
    return {
        "mape": (float(np.mean(np.abs(y - yhat) / np.abs(y)) * 100.0)
                 if transform == "log" or _away_from_zero(y) else None),
        "rmse": float(np.sqrt(np.mean((y - yhat) ** 2))),
        "coverage95": float(np.mean((lo <= y) & (y <= hi))),
    }


def _away_from_zero(y: np.ndarray) -> bool:
    """All of one sign and every |y| at least 1 % of the largest."""
    a = np.abs(y)
    return bool(len(y)) and (np.all(y > 0) or np.all(y < 0)) and a.min() >= 0.01 * a.max()


def mape_meaningful(y, *, relative: bool = False) -> bool:
    """Whether a percentage error is meaningful for observations ``y``: all of one sign
    and every |y| at least a tenth of their spread away from zero (else a near-zero
    value turns a small error into hundreds of percent). With ``relative`` (a positive
    quantity modelled on the log scale, whose errors are relative by declaration) every
    ``y > 0`` is enough, however many decades they span."""
    y = np.asarray(y, float)
    if not len(y) or not (np.all(y > 0) or np.all(y < 0)):
        return False
    if relative:
        return bool(np.all(y > 0))
    return float(np.abs(y).min()) >= 0.1 * float(np.ptp(y))


def kfold_indices(n: int, k: int, seed: int = 0) -> np.ndarray:
    """Fold index (0 .. k-1) of each of ``n`` points, shuffled with ``seed``; shape (n,).

    Fold sizes differ by at most one.
    """
    perm = np.random.default_rng(seed).permutation(n)
    fold = np.empty(n, dtype=np.int64)
    for i, idx in enumerate(np.array_split(perm, k)):
        fold[idx] = i
    return fold


def _check_k(k, name: str) -> None:
    if not isinstance(k, (int, np.integer)) or k < 2:
        lab = f"output {name!r}" if name else "output"
        raise SurrogateError(f"{lab}: k must be an integer >= 2 for k-fold CV, got {k!r}")


def check_folds(k, n: int, d: int, *, name: str = "", mean: str = "constant") -> None:
    """Raise :class:`~calnet.errors.SurrogateError` unless ``k``-fold cross-validation of
    ``n`` points in ``d`` dimensions is possible: ``k`` an integer in ``[2, n]`` and each
    training fold at least ``d + 2`` points, and as many as a trend ``mean`` (``"linear"``
    or ``"quadratic"``) needs (:func:`~calnet.surrogates.likelihood.trend_runs`; ``"auto"``
    tries a trend only with 5 runs per coefficient, so its choice always fits)."""
    _check_k(k, name)
    lab = f"output {name!r}" if name else "output"
    if k > n:
        raise SurrogateError(f"{lab}: {k}-fold CV needs at least {k} points, got {n}")
    smallest_train = n - math.ceil(n / k)
    if smallest_train < d + 2:
        model = name.split(".")[0] if "." in name else "MODEL"
        fix = (f"run more simulations (calnet campaign SPEC --model {model} --runs N)"
               if k >= n else "use more folds (the model's surrogate: {cv_folds: K}) or run "
               "more simulations")
        raise SurrogateError(f"{lab}: {k}-fold CV on {n} points leaves {smallest_train} "
                             f"training points, need d + 2 = {d + 2}; {fix}")
    if mean not in ("constant", "auto") and smallest_train < trend_runs(mean, d):
        raise SurrogateError(
            f"{lab}: its {mean} mean has {n_basis(mean, d)} coefficients, so each "
            f"cross-validation fold needs at least {trend_runs(mean, d)} training runs, but "
            f"{k}-fold CV on {n} runs leaves {smallest_train}; run more simulations, use more "
            "folds (surrogate: {cv_folds: K}, at most the runs), or set surrogate: "
            "{mean: auto}")


def cross_validate(
    X,
    y,
    *,
    k: int,
    lower,
    upper,
    transform: str | None = None,
    seed: int = 0,
    n_restarts: int = 5,
    name: str = "",
    before_fold: Callable[[], None] | None = None,
    **fit_kwargs,
) -> CVResult:
    """k-fold cross-validation of :func:`calnet.surrogates.fit_gp`.

    Parameters
    ----------
    X : array, shape (n, d)
        Inputs, physical units.
    y : array, shape (n,)
        Outputs, natural scale.
    k : int
        Number of folds, 2 <= k <= n (``k = n`` is leave-one-out).
    lower, upper : array, shape (d,)
        Input bounds, physical units.
    transform : {None, "log"}
    seed : int, default 0
        Seeds the fold shuffle and every fold's optimiser starts.
    n_restarts : int, default 5
        Passed to :func:`fit_gp`.
    name : str
    before_fold : callable, optional
        Called with no argument before each fold's fit; an exception it raises (an
        interrupted run) stops the cross-validation.
    **fit_kwargs
        Further keyword arguments of :func:`fit_gp` (bounds).

    Returns
    -------
    CVResult

    Raises
    ------
    SurrogateError
        Bad data (as :func:`fit_gp`), ``k`` out of range, or training folds with fewer
        than ``d + 2`` points.
    """
    _check_k(k, name)
    x, y, lower, upper = validate_training_data(X, y, lower=lower, upper=upper,
                                                transform=transform, name=name, min_points=k)
    n, d = x.shape
    check_folds(k, n, d, name=name, mean=fit_kwargs.get("mean", "constant"))
    fold = kfold_indices(n, k, seed)
    mu, var = np.empty(n), np.empty(n)
    for i in range(k):
        if before_fold is not None:
            before_fold()
        test = fold == i
        if fit_kwargs.get("mean", "constant") == "auto":  # a choice per fold: its own fits
            gp = fit_gp(x[~test], y[~test], lower=lower, upper=upper, transform=transform,
                        n_restarts=n_restarts, seed=seed, name=name, **fit_kwargs)
            m, v = gp.predict(x[test], include_nugget=True)
        else:
            m, v = held_out_predictions(x, y, ~test, lower=lower, upper=upper,
                                        transform=transform, n_restarts=n_restarts,
                                        seed=seed, name=name, **fit_kwargs)
        mu[test], var[test] = np.asarray(m), np.asarray(v)
    sd = np.sqrt(var)
    if transform == "log":
        # a fold that extrapolates far can give a log-scale variance whose natural-scale
        # mean and variance overflow: they are infinite then, and the metrics say so
        with np.errstate(over="ignore"):
            mean, nat_var = np.exp(mu + 0.5 * var), np.expm1(var) * np.exp(2.0 * mu + var)
            lo, hi = np.exp(mu - Z95 * sd), np.exp(mu + Z95 * sd)
    else:
        mean, nat_var, lo, hi = mu, var, mu - Z95 * sd, mu + Z95 * sd
    met = cv_metrics(y, mean, lo, hi, transform=transform)
    return CVResult(y=y, mean=mean, var=nat_var, lower95=lo, upper95=hi, mean_modelled=mu,
                    var_modelled=var, fold=fold, mape=met["mape"], rmse=met["rmse"],
                    coverage95=met["coverage95"], n=n, k=int(k), name=name,
                    transform=transform)
