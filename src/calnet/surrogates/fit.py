"""Fit a GP surrogate: validate the data, maximise the log marginal likelihood, condition.

The optimiser is SciPy's L-BFGS-B on the closed-form value and gradient of
:func:`calnet.surrogates.likelihood.nlml_value_and_grad`, jitted once per data size (JAX
caches the compiled function by array shape, so restarts reuse it; the folds of a
cross-validation, :func:`held_out_predictions`, run it on the full data's arrays with
their held-out points decoupled, so they reuse the full fit's). method.md section 2.
"""

from __future__ import annotations

import dataclasses
import warnings

import jax
import numpy as np
from scipy.linalg import solve_triangular
from scipy.optimize import minimize

from calnet._jax import device_array
from calnet.errors import SurrogateError, SurrogateWarning
from calnet.surrogates.gp import FittedGP, condition, held_out_moments
from calnet.surrogates.likelihood import MEANS, basis, n_basis, nlml_value_and_grad, trend_runs

LENGTHSCALE_BOUNDS = (1e-2, 1e2)  # unit-cube units
SIGNAL_VAR_BOUNDS = (1e-3, 1e3)  # standardised-output units
NUGGET_BOUNDS = (1e-8, 1e-1)  # standardised-output units; the lower end is the floor
TRANSFORMS = (None, "log")
#: ``fit_gp``'s ``mean``: a mean function, or ``"auto"``, the one of highest leave-one-out
#: predictive density
MEAN_CHOICES = (*MEANS, "auto")
#: ``mean="auto"`` tries a trend only with at least this many runs per coefficient: with
#: fewer, the closed-form leave-one-out density (hyperparameters held at the full fit's)
#: favoured a linear trend in 5 inputs on 18 runs whose refitted folds predicted worse
#: (benchmarks/README.md, "Mean function")
AUTO_RUNS_PER_COEFFICIENT = 5
_PENALTY = 1e10  # objective value reported to L-BFGS-B where K is not positive definite
_NUGGET_RETRIES = 3

_value_and_grad = jax.jit(nlml_value_and_grad)


def _label(name: str) -> str:
    return f"output {name!r}" if name else "output"


def validate_training_data(
    x, y, *, lower, upper, transform: str | None = None, name: str = "", min_points: int = 0
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Check training data at the edge and return float64 copies ``(x, y, lower, upper)``.

    Raises
    ------
    SurrogateError
        One line naming the output and the fix, for: wrong shapes or bounds, non-finite
        values, too few points (``n < d + 2`` or ``n < min_points``), a constant output,
        non-positive outputs with ``transform="log"``, an unknown transform.
    """
    lab = _label(name)
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    if x.ndim != 2:
        raise SurrogateError(f"{lab}: X must have shape (n, d), got {x.shape}; "
                             "use X.reshape(-1, 1) for a single input")
    n, d = x.shape
    if y.shape != (n,):
        raise SurrogateError(f"{lab}: y must have shape ({n},) to match X, got {y.shape}")
    lower = np.asarray(lower, dtype=np.float64)
    upper = np.asarray(upper, dtype=np.float64)
    if lower.shape != (d,) or upper.shape != (d,):
        raise SurrogateError(f"{lab}: lower and upper must have shape ({d},), got "
                             f"{lower.shape} and {upper.shape}")
    if not (np.all(np.isfinite(lower)) and np.all(np.isfinite(upper)) and np.all(upper > lower)):
        raise SurrogateError(f"{lab}: input bounds must be finite with upper > lower, got "
                             f"lower={lower.tolist()} upper={upper.tolist()}")
    if transform not in TRANSFORMS:
        raise SurrogateError(f"{lab}: transform must be None or 'log', got {transform!r}")
    bad = ~(np.all(np.isfinite(x), axis=1) & np.isfinite(y))
    if bad.any():
        raise SurrogateError(f"{lab}: {int(bad.sum())} of {n} training points have non-finite "
                             "inputs or outputs; drop failed runs before fitting")
    need = max(d + 2, min_points)
    if n < need:
        why = f"d + 2 = {d + 2}" if need == d + 2 else f"{min_points} for {min_points}-fold CV"
        raise SurrogateError(f"{lab}: {n} training points for {d} inputs, need at least "
                             f"{why}; run a larger campaign")
    if transform == "log" and np.any(y <= 0):
        raise SurrogateError(f"{lab}: transform='log' needs positive outputs, got "
                             f"{int(np.sum(y <= 0))} values <= 0; use transform=None")
    z = np.log(y) if transform == "log" else y
    if np.ptp(z) <= 1e-12 * max(1.0, float(np.max(np.abs(z)))):
        raise SurrogateError(f"{lab} is constant (value {float(y[0]):g} at all {n} points); a GP "
                             "cannot be fitted: remove what needs its surrogate (the data "
                             "set, link or settings.predict entry that uses it), or widen the "
                             "box over which the model's runs vary it")
    return x, y, lower, upper


def _starts(d, n_restarts, rng, ell_b, s2_b, nug_b) -> np.ndarray:
    """Default start plus ``n_restarts`` random starts, log-uniform in central boxes."""
    lo = np.log([*[max(ell_b[0], 0.1)] * d, max(s2_b[0], 0.3), nug_b[0]])
    hi = np.log([*[min(ell_b[1], 10.0)] * d, min(s2_b[1], 3.0), min(nug_b[1], 1e-2)])
    hi = np.maximum(hi, lo)
    default = np.log([*[np.clip(0.5, *ell_b)] * d, np.clip(1.0, *s2_b),
                      np.clip(np.sqrt(nug_b[0] * min(nug_b[1], 1e-2)), *nug_b)])
    return np.vstack([default, rng.uniform(lo, hi, size=(n_restarts, d + 2))])


def _bounds_and_starts(d, n_restarts, seed, lengthscale_bounds, signal_var_bounds,
                       nugget_bounds, init, name):
    """L-BFGS-B's bounds on the log hyperparameters and its starts (``init`` first)."""
    bounds = [tuple(np.log(lengthscale_bounds))] * d + [tuple(np.log(signal_var_bounds)),
                                                         tuple(np.log(nugget_bounds))]
    starts = _starts(d, n_restarts, np.random.default_rng(seed), lengthscale_bounds,
                     signal_var_bounds, nugget_bounds)
    if init is not None:
        init = np.asarray(init, dtype=np.float64)
        if init.shape != (d + 2,) or not np.all(np.isfinite(init)):
            raise SurrogateError(f"{_label(name)}: init must be {d + 2} finite log "
                                 f"hyperparameters, got shape {init.shape}")
        starts[0] = np.clip(init, [b[0] for b in bounds], [b[1] for b in bounds])
    return bounds, starts


def _optimise(xs, ys, starts, bounds, H=None, mask=None):
    """Run L-BFGS-B from each start; return (best log_params, best value). ``mask``
    (device array of ones and zeros, default all ones): the points the likelihood keeps
    (:func:`~calnet.surrogates.likelihood.nlml_value_and_grad`); a full fit passes all
    ones, so that it and the folds of its cross-validation share one compiled program."""
    if mask is None:
        mask = device_array(np.ones(xs.shape[0]), float)

    def fun(p):
        v, g = _value_and_grad(device_array(p, float), xs, ys, H, mask)
        v = float(v)
        if not np.isfinite(v):
            return _PENALTY, np.zeros_like(p)
        return v, np.asarray(g, dtype=np.float64)

    best_p, best_v = starts[0], np.inf
    for p0 in starts:
        res = minimize(fun, p0, jac=True, method="L-BFGS-B", bounds=bounds,
                       options={"maxiter": 1000})
        if res.fun < best_v:
            best_p, best_v = np.asarray(res.x), float(res.fun)
    return best_p, best_v


def fit_gp(
    X,
    y,
    *,
    lower,
    upper,
    transform: str | None = None,
    n_restarts: int = 5,
    seed: int = 0,
    lengthscale_bounds: tuple[float, float] = LENGTHSCALE_BOUNDS,
    signal_var_bounds: tuple[float, float] = SIGNAL_VAR_BOUNDS,
    nugget_bounds: tuple[float, float] = NUGGET_BOUNDS,
    name: str = "",
    min_points: int = 0,
    init=None,
    mean: str = "constant",
) -> FittedGP:
    """Fit a Matern 3/2 ARD GP surrogate to one output by maximum marginal likelihood.

    Inputs are scaled to the unit cube with ``lower``/``upper``; outputs are transformed
    (``transform``) and standardised. Hyperparameters maximise the log marginal
    likelihood (the restricted one with a linear mean) with L-BFGS-B from a default
    start plus ``n_restarts`` seeded random ones.

    Parameters
    ----------
    X : array, shape (n, d)
        Training inputs, physical units.
    y : array, shape (n,)
        Training outputs, natural scale.
    lower, upper : array, shape (d,)
        Input bounds, physical units (the design space of the campaign).
    transform : {None, "log"}, default None
        ``"log"`` models ``log(y)``; ``y`` must then be positive.
    n_restarts : int, default 5
        Random starts in addition to the default start (scikit-learn's
        ``n_restarts_optimizer``).
    seed : int, default 0
        Seed of the random starts.
    lengthscale_bounds : (float, float), default (1e-2, 1e2)
        Bounds on every length scale, unit-cube units.
    signal_var_bounds : (float, float), default (1e-3, 1e3)
        Bounds on the signal variance, standardised-output units.
    nugget_bounds : (float, float), default (1e-8, 1e-1)
        Bounds on the nugget, standardised-output units; the lower end is the floor that
        keeps ``K`` well conditioned.
    name : str
        Output name for messages and for the result.
    min_points : int, default 0
        Extra minimum on ``n`` (cross-validation passes its ``k``).
    init : array, shape (d + 2,), optional
        Log hyperparameters ``(log ell_1..d, log signal_var, log nugget)`` to start from
        instead of the default start (e.g. a fit on more data: CV folds warm-start from
        the full-data optimum); the ``n_restarts`` random starts are added as usual.
    mean : {"constant", "linear", "quadratic", "auto"}, default "constant"
        Mean function (:mod:`calnet.surrogates.gp`): the outputs' mean, a linear or a
        quadratic (all products of two inputs) trend in the inputs with its
        coefficients' uncertainty in the variance, or ``"auto"``: each of them that has
        at least :data:`AUTO_RUNS_PER_COEFFICIENT` (5) runs per coefficient fitted, and
        the one whose leave-one-out predictive density of the training outputs (closed
        form, :func:`loo_log_density`) is highest kept (the simpler on a tie). A smooth
        output with a trend across the box gets a far smaller, and honest, variance from
        a trend.

    Returns
    -------
    FittedGP

    Raises
    ------
    SurrogateError
        Bad data (see :func:`validate_training_data`), or ``K`` not positive definite
        even after raising the nugget tenfold ``3`` times.

    Warns
    -----
    SurrogateWarning
        When the nugget had to be raised above the optimum to factorise ``K``.

    Examples
    --------
    >>> import numpy as np
    >>> from calnet.surrogates import fit_gp
    >>> X = np.random.default_rng(0).uniform(0, 2, (20, 1))
    >>> gp = fit_gp(X, np.sin(X[:, 0]), lower=[0.0], upper=[2.0], n_restarts=1)
    >>> mean, var = gp.predict(np.array([[1.0]]))
    >>> bool(abs(mean[0] - np.sin(1.0)) < 1e-2)
    True
    """
    x, y, lower, upper = validate_training_data(X, y, lower=lower, upper=upper,
                                                transform=transform, name=name,
                                                min_points=min_points)
    d = x.shape[1]
    xs = device_array((x - lower) / (upper - lower), float)
    z = np.log(y) if transform == "log" else y
    ys = device_array((z - z.mean()) / z.std(), float)
    bounds, starts = _bounds_and_starts(d, n_restarts, seed, lengthscale_bounds,
                                        signal_var_bounds, nugget_bounds, init, name)
    if mean not in MEAN_CHOICES:
        raise SurrogateError(f"{_label(name)}: mean must be one of {list(MEAN_CHOICES)}, got "
                             f"{mean!r}")
    n = x.shape[0]
    if mean != "auto" and n < trend_runs(mean, d):
        raise SurrogateError(
            f"{_label(name)}: a {mean} mean in {d} input{'s' if d != 1 else ''} has "
            f"{n_basis(mean, d)} coefficients and needs at least {trend_runs(mean, d)} "
            f"runs, got {n}; run more simulations, or set the model's surrogate: "
            "{mean: auto} or {mean: constant}")
    tries = (tuple(m for m in MEANS if n >= AUTO_RUNS_PER_COEFFICIENT * n_basis(m, d))
             if mean == "auto" else (mean,))
    fits = []
    for form in tries:
        H = None if form == "constant" else basis(xs, form)
        p, _ = _optimise(xs, ys, starts, bounds, H)
        fits.append(_condition_with_retries(x, y, xs, ys, p, lower=lower, upper=upper,
                                            transform=transform, name=name, mean=form))
    if len(fits) == 1:
        return fits[0]
    scores = [loo_log_density(gp) for gp in fits]
    return fits[int(np.argmax(np.nan_to_num(scores, nan=-np.inf)))]  # the simpler on a tie


def held_out_predictions(
    x: np.ndarray,
    y: np.ndarray,
    keep: np.ndarray,
    *,
    lower,
    upper,
    transform: str | None = None,
    n_restarts: int = 5,
    seed: int = 0,
    lengthscale_bounds: tuple[float, float] = LENGTHSCALE_BOUNDS,
    signal_var_bounds: tuple[float, float] = SIGNAL_VAR_BOUNDS,
    nugget_bounds: tuple[float, float] = NUGGET_BOUNDS,
    name: str = "",
    init=None,
    mean: str = "constant",
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`fit_gp` on the points of ``keep`` (bool (n,)) and its predictions at the
    others (a new run's variance: the nugget included), modelled scale: one fold of a
    cross-validation. The same starts, optimum and predictions as ``fit_gp(x[keep],
    y[keep], ...)`` followed by ``predict(x[~keep], include_nugget=True)`` (to round-off),
    computed in arrays of the full shape (the held-out points decoupled), so that the
    folds of a cross-validation and the full fit share their compiled programs. ``x``,
    ``y``, ``lower``, ``upper`` are float64 arrays; ``mean`` is one of the mean functions
    (not ``"auto"``).

    Returns
    -------
    mean, var : ndarray, shape (number of held-out points,)
    """
    keep = np.asarray(keep, bool)
    validate_training_data(x[keep], y[keep], lower=lower, upper=upper, transform=transform,
                           name=name)  # a fold of constant outputs, say
    d = x.shape[1]
    xs = device_array((x - lower) / (upper - lower), float)
    z = np.log(y) if transform == "log" else y
    y_mean, y_std = z[keep].mean(), z[keep].std()
    ys = device_array(np.where(keep, (z - y_mean) / y_std, 0.0), float)
    mask = device_array(keep.astype(float), float)
    bounds, starts = _bounds_and_starts(d, n_restarts, seed, lengthscale_bounds,
                                        signal_var_bounds, nugget_bounds, init, name)
    H = None if mean == "constant" else basis(xs, mean) * mask[:, None]
    p, _ = _optimise(xs, ys, starts, bounds, H, mask)
    ell, s2, nugget = device_array(np.exp(p[:-2]), float), float(np.exp(p[-2])), \
        float(np.exp(p[-1]))

    def attempt(nug: float):
        mu, var, ok = held_out_moments(xs, ys, mask, ell, s2, nug, mean)
        return (mu, var) if bool(ok) else None

    (mu, var), _ = _with_nugget_retries(attempt, nugget, name)
    out = ~keep
    return y_mean + y_std * np.asarray(mu)[out], y_std**2 * np.asarray(var)[out]


def _with_nugget_retries(attempt, nugget: float, name: str):
    """``(attempt(nug), nug)`` for the first nugget, ``nugget`` raised tenfold up to
    :data:`_NUGGET_RETRIES` times, at which ``attempt`` (None where ``K`` did not
    factorise) succeeds, warning when the nugget had to be raised; else a
    :class:`SurrogateError`."""
    for tries in range(_NUGGET_RETRIES + 1):
        result = attempt(nugget)
        if result is not None:
            if tries:
                warnings.warn(f"{_label(name)}: nugget raised to {nugget:.3g} to factorise K",
                              SurrogateWarning, stacklevel=4)
            return result, nugget
        nugget *= 10.0
    raise SurrogateError(f"{_label(name)}: the covariance matrix is not positive definite "
                         f"even with nugget {nugget / 10:.3g}; remove duplicate or "
                         "near-duplicate training inputs or raise nugget_bounds")


def loo_log_density(gp: FittedGP) -> float:
    """Leave-one-out log predictive density of ``gp``'s training outputs (standardised
    scale, hyperparameters fixed), from the closed form ``mu_-i = y_i - (P y)_i / P_ii``,
    ``var_-i = 1 / P_ii`` (Rasmussen and Williams 2006, eq. 5.12), ``P = K^-1`` for a
    constant mean and the restricted projection for a trend, whose coefficients are then
    re-estimated without the point (Dubrule 1983). NaN where ``K`` did not factorise.
    """
    z, diag = _loo_residuals(gp)
    if z is None:
        return float("nan")
    return float(np.sum(-0.5 * np.log(2 * np.pi / diag) - 0.5 * z**2))


def _loo_residuals(gp: FittedGP) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The closed-form leave-one-out residuals of the training outputs in predictive sds
    (n,) and the precisions ``P_ii`` (:func:`loo_log_density`); None, None where ``K``
    did not factorise."""
    chol = np.asarray(gp.chol, float)
    if not np.all(np.isfinite(chol)):
        return None, None
    l_inv = solve_triangular(chol, np.eye(chol.shape[0]), lower=True)
    prec = l_inv.T @ l_inv  # K^-1
    if gp.beta.shape[0]:
        w = np.asarray(gp.basis_solve, float)  # L^-1 H
        c = np.linalg.solve(np.asarray(gp.basis_chol, float), (l_inv.T @ w).T)  # R^-1 H^T K^-1
        prec = prec - c.T @ c
    diag = np.diag(prec)
    if not np.all(diag > 0):
        return None, None
    return np.asarray(gp.alpha, float) / np.sqrt(diag), diag  # alpha = P y_s


#: a GP whose signal variance reached this share of its upper bound ...
OVERSTATED_AT_BOUND = 0.5
#: ... and whose median |leave-one-out z| is below this (0.674 for a calibrated one)
OVERSTATED_MEDIAN_Z = 0.25


def overstated_variance(gp: FittedGP, upper: float = SIGNAL_VAR_BOUNDS[1]) -> float | None:
    """The median |z| of ``gp``'s closed-form leave-one-out residuals (in predictive sds)
    when its variance is overstated, else None. The symptom: the signal variance at its
    upper bound ``upper`` (the likelihood's optimum lies beyond it, with ever longer
    length scales: an output smoother than the Matern 3/2 kernel's sample paths), and at
    most runs an error far below the predictive sd (median |z| under
    :data:`OVERSTATED_MEDIAN_Z`, where a calibrated GP gives about 0.67). Such a
    surrogate's mean can be very good while its variance is many times too large,
    mostly between the runs."""
    if float(gp.signal_var) < OVERSTATED_AT_BOUND * upper:
        return None
    z, _ = _loo_residuals(gp)
    if z is None:
        return None
    median = float(np.median(np.abs(z)))
    return median if median < OVERSTATED_MEDIAN_Z else None


def _condition_with_retries(x, y, xs, ys, p, *, lower, upper, transform, name,
                            mean: str = "constant") -> FittedGP:
    """Condition at ``p``; if ``K`` will not factorise, raise the nugget tenfold and retry."""
    ell, s2 = np.exp(p[:-2]), float(np.exp(p[-2]))

    def attempt(nug: float):
        gp = condition(x, y, lower=lower, upper=upper, lengthscales=ell, signal_var=s2,
                       nugget=nug, transform=transform, name=name, mean=mean)
        return gp if np.isfinite(np.asarray(gp.alpha)).all() else None

    gp, nugget = _with_nugget_retries(attempt, float(np.exp(p[-1])), name)
    # the value half of the optimiser's program: a value-only one would compile again
    nlml, _ = _value_and_grad(device_array(np.log(np.r_[ell, s2, nugget]), float), xs, ys,
                              None if mean == "constant" else basis(xs, mean),
                              device_array(np.ones(xs.shape[0]), float))
    return dataclasses.replace(gp, nlml=nlml)
