"""Variance-based (Sobol) sensitivity of a vectorised model over a box of inputs.

The inputs are uniform over the box ``bounds`` (method.md section 6). The low level is
:func:`saltelli_design` (the input sample) and :func:`analyze_outputs` (indices from the
model outputs on that sample); :func:`sobol_indices` is the one-call driver and
:func:`sobol_spread` repeats the analysis for several posterior draws of a calibrated chain
from one call of a model that returns a row per draw (:func:`sobol_over_draws` takes one
model per draw).
SALib does the sampling (scrambled Sobol' sequence, Saltelli cross-sampling) and the
estimation (Saltelli 2010 first order, Jansen total effect, bootstrap confidence
intervals). :func:`jansen_total` is an independent pure-NumPy Monte Carlo cross-check of
the total-effect indices.

Examples
--------
>>> import numpy as np
>>> res = sobol_indices(lambda x: x[:, 0] + 2.0 * x[:, 1], [[0, 1], [0, 1]],
...                     names=["a", "b"], n_base=256, n_bootstrap=20)
>>> [round(float(s), 1) for s in res.ST]
[0.2, 0.8]
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from calnet.errors import SensitivityError

VectorFunc = Callable[[np.ndarray], Any]


@dataclass(frozen=True)
class SobolResult:
    """First-order and total-effect Sobol indices of one scalar output.

    Attributes
    ----------
    names : tuple of str, length d
        Input names, in the column order of ``bounds``.
    S1, ST : array, shape (d,)
        First-order and total-effect indices (dimensionless, nominally in [0, 1]; MC
        estimates can fall slightly outside).
    S1_conf, ST_conf : array, shape (d,)
        Half-widths of the bootstrap confidence intervals at ``conf_level``
        (``S1 +/- S1_conf``).
    conf_level : float
        Confidence level of the intervals.
    n_base : int
        Base sample size N; the model was evaluated ``n_evals = N * (d + 2)`` times.
    n_evals : int
        Number of model evaluations.
    output_mean, output_var : float
        Mean and variance of the output over the sample, in the output's units
        (squared for the variance).
    seed : int
        Seed used for the design and the bootstrap.
    """

    names: tuple[str, ...]
    S1: np.ndarray
    S1_conf: np.ndarray
    ST: np.ndarray
    ST_conf: np.ndarray
    conf_level: float
    n_base: int
    n_evals: int
    output_mean: float
    output_var: float
    seed: int

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict: ``{"names", "S1", "S1_conf", "ST", "ST_conf", ...}``."""
        out: dict[str, Any] = {"names": list(self.names)}
        for key in ("S1", "S1_conf", "ST", "ST_conf"):
            out[key] = [float(v) for v in getattr(self, key)]
        out.update(conf_level=float(self.conf_level), n_base=int(self.n_base),
                   n_evals=int(self.n_evals), output_mean=float(self.output_mean),
                   output_var=float(self.output_var), seed=int(self.seed))
        return out


@dataclass(frozen=True)
class SobolSpread:
    """Sobol indices computed for each of several posterior draws, and their spread.

    Attributes
    ----------
    names : tuple of str, length d
        Input names.
    S1_draws, ST_draws : array, shape (n_draws, d)
        Indices for each draw (same input design for every draw).
    S1_mean, S1_lo, S1_hi, ST_mean, ST_lo, ST_hi : array, shape (d,)
        Mean and 2.5 / 97.5 percentiles across draws.
    n_base : int
        Base sample size per draw.
    seed : int
        Seed of the shared design and bootstraps.
    """

    names: tuple[str, ...]
    S1_draws: np.ndarray
    ST_draws: np.ndarray
    S1_mean: np.ndarray
    S1_lo: np.ndarray
    S1_hi: np.ndarray
    ST_mean: np.ndarray
    ST_lo: np.ndarray
    ST_hi: np.ndarray
    n_base: int
    seed: int

    @property
    def n_draws(self) -> int:
        """Number of posterior draws."""
        return int(self.S1_draws.shape[0])

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict with per-input summaries and the per-draw indices."""
        out: dict[str, Any] = {"names": list(self.names), "n_draws": self.n_draws,
                               "n_base": int(self.n_base), "seed": int(self.seed)}
        for key in ("S1_mean", "S1_lo", "S1_hi", "ST_mean", "ST_lo", "ST_hi"):
            out[key] = [float(v) for v in getattr(self, key)]
        for key in ("S1_draws", "ST_draws"):
            out[key] = [[float(v) for v in row] for row in getattr(self, key)]
        return out


class JansenEstimate(NamedTuple):
    """Total-effect indices from :func:`jansen_total` with their Monte Carlo errors.

    Attributes
    ----------
    ST : array, shape (d,)
        Total-effect indices.
    ST_se : array, shape (d,)
        Standard errors of the numerators divided by the output variance (the
        variance's own error is neglected).
    """

    ST: np.ndarray
    ST_se: np.ndarray


def _check_bounds(bounds: Any, names: Sequence[str] | None) -> np.ndarray:
    b = np.asarray(bounds, dtype=float)
    if b.ndim != 2 or b.shape[1] != 2 or b.shape[0] == 0:
        raise SensitivityError(f"bounds must have shape (d, 2) with d >= 1, got {b.shape}; "
                               "give one [lower, upper] row per input")
    if not np.all(np.isfinite(b)):
        raise SensitivityError("bounds must be finite; give a finite [lower, upper] per input")
    bad = np.flatnonzero(b[:, 0] >= b[:, 1])
    if bad.size:
        label = [names[i] for i in bad] if names is not None and len(names) == len(b) else bad
        raise SensitivityError(f"bounds need lower < upper; inputs {list(label)} have "
                               f"{b[bad].tolist()}; swap or widen them")
    if names is not None:
        if len(names) != b.shape[0]:
            raise SensitivityError(f"got {len(names)} names for {b.shape[0]} bounds rows; "
                                   "give one name per input")
        if len(set(names)) != len(names):
            raise SensitivityError(f"input names must be unique, got {list(names)}")
    return b


def _check_power_of_two(n: int, what: str) -> int:
    n = int(n)
    if n < 2 or n & (n - 1):
        suggestion = 1 << max(1, int(np.ceil(np.log2(max(n, 2)))))
        raise SensitivityError(f"{what} must be a power of 2 (Sobol' sequence balance), "
                               f"got {n}; use {suggestion}")
    return n


def _evaluate(func: VectorFunc, x: np.ndarray) -> np.ndarray:
    """Evaluate a vectorised model and check the outputs: shape (n,), finite, not constant."""
    y = np.asarray(func(x), dtype=float)
    n = x.shape[0]
    if y.shape == (n, 1):
        y = y[:, 0]
    if y.shape != (n,):
        raise SensitivityError(f"func must map an ({n}, {x.shape[1]}) array to shape ({n},), "
                               f"got {y.shape}; return one scalar output per row")
    return _checked(y, x)


def _checked(y: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``y`` (n,), the outputs at inputs ``x`` (n, d), if finite and not constant."""
    n = x.shape[0]
    bad = ~np.isfinite(y)
    if bad.any():
        first = x[np.argmax(bad)].tolist()
        raise SensitivityError(f"func returned {int(bad.sum())} non-finite outputs out of {n} "
                               f"(first at input {first}); make the model finite over the "
                               "whole box or shrink the bounds")
    if np.ptp(y) == 0.0:
        raise SensitivityError(f"func output is constant ({y[0]!r}) over the box, so its "
                               "variance is zero and Sobol indices are undefined; check that "
                               "the inputs reach the model")
    return y


def _bootstrap_seed(seed: int) -> int:
    # SALib's analyze ignores a falsy seed (0) and then uses the global RNG; derive a
    # positive seed so that every user seed, 0 included, is reproducible.
    return int(np.random.SeedSequence(int(seed)).generate_state(1)[0]) | 1


def saltelli_design(bounds: Any, *, n_base: int = 1024, seed: int = 0) -> np.ndarray:
    """Saltelli cross-sampled design over the box (scrambled Sobol' sequence, via SALib).

    Parameters
    ----------
    bounds : array_like, shape (d, 2)
        ``[lower, upper]`` of each input, physical units.
    n_base : int
        Base sample size N, a power of 2.
    seed : int
        Seed of the Sobol' scrambling.

    Returns
    -------
    array, shape (n_base * (d + 2), d)
        Inputs in physical units, in SALib's (A, AB_1..AB_d, B) block order.
    """
    from SALib.sample import sobol as sobol_sample

    b = _check_bounds(bounds, None)
    n_base = _check_power_of_two(n_base, "n_base")
    problem = {"num_vars": b.shape[0], "names": [f"x{i}" for i in range(b.shape[0])],
               "bounds": b.tolist()}
    return sobol_sample.sample(problem, n_base, calc_second_order=False, scramble=True,
                               seed=int(seed))


def analyze_outputs(y: np.ndarray, *, names: Sequence[str], n_base: int,
                    n_bootstrap: int = 200, seed: int = 0,
                    conf_level: float = 0.95) -> SobolResult:
    """Sobol indices from model outputs on a :func:`saltelli_design` sample.

    Parameters
    ----------
    y : array, shape (n_base * (d + 2),)
        Finite outputs at the design points, in design order.
    names : sequence of str, length d
        Input names.
    n_base : int
        Base sample size the design was built with.
    n_bootstrap : int
        Bootstrap resamples for the confidence intervals (>= 2).
    seed : int
        Seed of the bootstrap.
    conf_level : float
        Confidence level of the intervals, in (0, 1).

    Returns
    -------
    SobolResult
        With one input, ``S1 = ST = 1`` with intervals of zero width: the identity, not
        an estimate (the estimators scatter around it by their Monte Carlo error).
    """
    from SALib.analyze import sobol as sobol_analyze

    d = len(names)
    y = np.asarray(y, dtype=float)
    if y.shape != (n_base * (d + 2),):
        raise SensitivityError(f"expected {n_base * (d + 2)} outputs (n_base * (d + 2)), got "
                               f"shape {y.shape}; evaluate the model on saltelli_design()")
    if not 0.0 < conf_level < 1.0:
        raise SensitivityError(f"conf_level must be in (0, 1), got {conf_level}")
    if int(n_bootstrap) < 2:
        raise SensitivityError(f"n_bootstrap must be >= 2, got {n_bootstrap}")
    if d == 1:  # one input carries all the variance: S1 = ST = 1 exactly, no estimate
        one, zero = np.ones(1), np.zeros(1)
        return SobolResult(names=tuple(names), S1=one, S1_conf=zero, ST=one.copy(),
                           ST_conf=zero.copy(), conf_level=float(conf_level),
                           n_base=int(n_base), n_evals=int(y.size),
                           output_mean=float(y.mean()), output_var=float(y.var()),
                           seed=int(seed))
    problem = {"num_vars": d, "names": list(names), "bounds": [[0.0, 1.0]] * d}
    si = sobol_analyze.analyze(problem, y, calc_second_order=False,
                               num_resamples=int(n_bootstrap), conf_level=conf_level,
                               print_to_console=False, seed=_bootstrap_seed(seed))
    return SobolResult(names=tuple(names), S1=np.array(si["S1"]),
                       S1_conf=np.array(si["S1_conf"]), ST=np.array(si["ST"]),
                       ST_conf=np.array(si["ST_conf"]), conf_level=float(conf_level),
                       n_base=int(n_base), n_evals=int(y.size), output_mean=float(y.mean()),
                       output_var=float(y.var()), seed=int(seed))


def sobol_indices(func: VectorFunc, bounds: Any, *, names: Sequence[str], n_base: int = 1024,
                  n_bootstrap: int = 200, seed: int = 0,
                  conf_level: float = 0.95) -> SobolResult:
    """First-order and total-effect Sobol indices of ``func``, inputs uniform over a box.

    Parameters
    ----------
    func : callable
        Vectorised model: an ``(n, d)`` array of inputs in physical units to ``(n,)``
        outputs (NumPy or JAX arrays; ``(n, 1)`` is accepted).
    bounds : array_like, shape (d, 2)
        ``[lower, upper]`` of each input, physical units; lower < upper.
    names : sequence of str, length d
        Input names.
    n_base : int
        Base sample size N (power of 2); ``func`` sees ``N * (d + 2)`` rows in one call.
    n_bootstrap : int
        Bootstrap resamples for the confidence intervals.
    seed : int
        Seed of the design and the bootstrap; same seed, same result.
    conf_level : float
        Confidence level of the intervals.

    Returns
    -------
    SobolResult

    Raises
    ------
    SensitivityError
        Bad bounds or names, non-finite outputs (the count is given), constant output.
    """
    _check_bounds(bounds, names)
    x = saltelli_design(bounds, n_base=n_base, seed=seed)
    y = _evaluate(func, x)
    return analyze_outputs(y, names=names, n_base=n_base, n_bootstrap=n_bootstrap, seed=seed,
                           conf_level=conf_level)


def jansen_total(func: VectorFunc, bounds: Any, *, n: int, seed: int) -> JansenEstimate:
    """Total-effect indices by plain Monte Carlo with the Jansen estimator (pure NumPy).

    An independent cross-check of :func:`sobol_indices`: two independent uniform samples
    ``x^(1)``, ``x^(2)`` of size n, and for each input u

        T_u = (1 / 2N) sum_i (f(x_i^(1)) - f(x_i^(1) with u from x_i^(2)))^2 / Var f

    (method.md section 6). ``func`` is called once with ``n * (d + 2)`` rows.

    Parameters
    ----------
    func : callable
        Vectorised model, ``(n, d)`` inputs (physical units) to ``(n,)`` outputs.
    bounds : array_like, shape (d, 2)
        ``[lower, upper]`` of each input.
    n : int
        Monte Carlo sample size (>= 2).
    seed : int
        Seed of the NumPy generator.

    Returns
    -------
    JansenEstimate
        ``(ST, ST_se)``, each of shape (d,).
    """
    b = _check_bounds(bounds, None)
    if int(n) < 2:
        raise SensitivityError(f"n must be >= 2, got {n}")
    n, d = int(n), b.shape[0]
    rng = np.random.default_rng(seed)
    lo, width = b[:, 0], b[:, 1] - b[:, 0]
    x1 = lo + width * rng.random((n, d))
    x2 = lo + width * rng.random((n, d))
    mixed = np.repeat(x1[None], d, axis=0)  # (d, n, d): block u has column u from x2
    mixed[np.arange(d), :, np.arange(d)] = x2.T
    y = _evaluate(func, np.concatenate([x1, x2, mixed.reshape(n * d, d)]))
    f1, f2, fmix = y[:n], y[n:2 * n], y[2 * n:].reshape(d, n)
    var = np.var(np.concatenate([f1, f2]), ddof=1)
    sq = 0.5 * (f1[None, :] - fmix) ** 2  # method.md section 6, Jansen numerator terms
    return JansenEstimate(ST=sq.mean(axis=1) / var,
                          ST_se=sq.std(axis=1, ddof=1) / np.sqrt(n) / var)


def sobol_over_draws(func_of_draw: Callable[[Any], VectorFunc], draws: Iterable[Any],
                     bounds: Any, *, names: Sequence[str], n_base: int = 1024,
                     n_bootstrap: int = 100, seed: int = 0,
                     conf_level: float = 0.95) -> SobolSpread:
    """Sobol indices for each posterior draw, and their spread across draws.

    The same input design (and bootstrap seed) is used for every draw, so the spread
    reflects posterior uncertainty rather than fresh Monte Carlo noise per draw.

    Parameters
    ----------
    func_of_draw : callable
        ``func_of_draw(draw)`` returns a vectorised model as in :func:`sobol_indices`.
    draws : iterable
        Posterior draws, e.g. rows of an ``(n_draws, p)`` array or a list of dicts.
    bounds : array_like, shape (d, 2)
        ``[lower, upper]`` of each input, physical units.
    names : sequence of str, length d
        Input names.
    n_base, n_bootstrap, seed, conf_level
        As in :func:`sobol_indices`.

    Returns
    -------
    SobolSpread
        Per-input mean and 2.5 / 97.5 percentiles of S1 and ST across draws.
    """
    draws = list(draws)
    if not draws:
        raise SensitivityError("draws is empty; pass at least one posterior draw")
    return sobol_spread(lambda x: np.stack([_evaluate(func_of_draw(d), x) for d in draws]),
                        bounds, names=names, n_base=n_base, n_bootstrap=n_bootstrap,
                        seed=seed, conf_level=conf_level)


def sobol_spread(func_draws: Callable[[np.ndarray], Any], bounds: Any, *,
                 names: Sequence[str], n_base: int = 1024, n_bootstrap: int = 100,
                 seed: int = 0, conf_level: float = 0.95) -> SobolSpread:
    """:func:`sobol_over_draws` for a model that evaluates every draw in one call.

    Parameters
    ----------
    func_draws : callable
        An ``(n, d)`` array of inputs (physical units) to ``(n_draws, n)`` outputs: one row
        per posterior draw.
    bounds, names, n_base, n_bootstrap, seed, conf_level
        As in :func:`sobol_over_draws`.

    Examples
    --------
    >>> import numpy as np
    >>> w = np.array([[1.0, 2.0], [2.0, 1.0]])  # two "draws" of a linear model
    >>> res = sobol_spread(lambda x: w @ x.T, [[0, 1], [0, 1]], names=["a", "b"],
    ...                    n_base=256, n_bootstrap=20)
    >>> np.round(res.ST_draws, 1).tolist()
    [[0.2, 0.8], [0.8, 0.2]]
    """
    _check_bounds(bounds, names)
    x = saltelli_design(bounds, n_base=n_base, seed=seed)
    y = np.asarray(func_draws(x), dtype=float)
    if y.ndim != 2 or y.shape[1] != x.shape[0]:
        raise SensitivityError(f"func_draws must map an {x.shape} array to shape "
                               f"(n_draws, {x.shape[0]}), got {y.shape}; return one row per "
                               "draw")
    if not len(y):
        raise SensitivityError("func_draws returned no draws; pass at least one posterior "
                               "draw")
    results = [analyze_outputs(_checked(row, x), names=names, n_base=n_base,
                               n_bootstrap=n_bootstrap, seed=seed, conf_level=conf_level)
               for row in y]
    s1 = np.stack([r.S1 for r in results])
    st = np.stack([r.ST for r in results])
    s1_lo, s1_hi = np.percentile(s1, [2.5, 97.5], axis=0)
    st_lo, st_hi = np.percentile(st, [2.5, 97.5], axis=0)
    return SobolSpread(names=tuple(names), S1_draws=s1, ST_draws=st, S1_mean=s1.mean(axis=0),
                       S1_lo=s1_lo, S1_hi=s1_hi, ST_mean=st.mean(axis=0), ST_lo=st_lo,
                       ST_hi=st_hi, n_base=int(n_base), seed=int(seed))
