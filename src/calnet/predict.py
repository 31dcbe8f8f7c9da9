"""Posterior prediction through the network, with an uncertainty budget (method.md §5).

For new process settings the chain pushes them through the calibrated upstream surrogates
to the observing model; for each posterior draw the KOH predictive is

    E[y^P] = yhat(x^P) + C_d(x^P, X^E) [C_d(X^E, X^E) + s_eps^2 I]^-1 (Y^E - yhat(X^E))

with variance from the discrepancy, the surrogate and the noise. The mixture over draws
gives the predictive distribution; the variance is split into its sources.
"""

from __future__ import annotations

import hashlib
import math
import warnings
from collections.abc import Collection, Sequence
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from calnet._jax import FEW_CALLS, device_array
from calnet.calibration.calibrate_network import (
    NetworkPosterior,
    direction_models,
    uncalibrated,
)
from calnet.calibration.koh import KOHModel
from calnet.calibration.persist import FILE as POSTERIOR_FILE
from calnet.calibration.persist import load_posterior
from calnet.calibration.terms import (
    draw_index,
    draws_at,
    hyper_at,
    known_noise_var,
    links_into,
    make_term,
)
from calnet.chain import ChainPlan
from calnet.errors import CalibrationWarning, CalnetError, UsageError
from calnet.spec import Network
from calnet.surrogates.cv import mape_meaningful
from calnet.surrogates.fit_network import Surrogates, check_surrogates

Z95 = 1.959963984540054


MIXTURE_ESS_MIN = 20.0
"""Fewest effective draws carrying a predictive mixture's density at an observation for
:meth:`Prediction.log_density` to take the mixture's value."""


@dataclass(frozen=True)
class Prediction:
    """Posterior predictive of one data set's output at process settings ``x``, or of a
    simulator output through the chain (:func:`calnet.emulation.predict_output`).

    Attributes
    ----------
    dataset : str or None
        The data set; None for a simulator output predicted without one.
    observes : str
        ``model.output`` predicted.
    input_keys : tuple of str
        ``model.input`` of each column of ``x``.
    x : ndarray (n, k)
    mean, lower, upper : ndarray (n,)
        Predictive mean (the mixture's over the posterior draws) and central 95 %
        interval (from the samples) of a new measurement, natural scale.
    budget : dict of str -> ndarray (n,)
        Variance contributions on the modelled, standardised scale, by source:
        ``parameters``, ``emulator <model.output>`` (one per surrogate), ``discrepancy``,
        ``noise``.
    samples : ndarray (k, n), optional
        Predictive samples of a new measurement, natural scale.
    draw_mean, draw_sd : ndarray (draws, n), optional
        The Gaussian predictive of a new measurement given each posterior draw, on the
        modelled scale (``log`` units for a log-transformed output):
        :meth:`log_density` is their mixture's.
    log : bool
        Whether the modelled scale is the log of the natural one.
    """

    dataset: str | None
    observes: str
    input_keys: tuple[str, ...]
    x: np.ndarray
    mean: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    budget: dict[str, np.ndarray] = field(default_factory=dict)
    prob: np.ndarray | None = None
    samples: np.ndarray | None = field(default=None, repr=False)
    draw_mean: np.ndarray | None = field(default=None, repr=False)
    draw_sd: np.ndarray | None = field(default=None, repr=False)
    log: bool = False

    def log_density(self, y: np.ndarray, min_ess: float = MIXTURE_ESS_MIN
                    ) -> tuple[np.ndarray, np.ndarray]:
        """Log predictive density (n,) of observations ``y`` (n,, natural scale) on the
        modelled scale, and whether each is the mixture's (n,) bool.

        The density is the mean over draws of each draw's Gaussian. Far in its tail (an
        outlier) a few draws carry that mean, and a finite set of draws puts the log
        density far too low (the draws that would carry it lie in the posterior's
        tail): where the effective number of draws carrying it falls below ``min_ess``,
        the Gaussian with the mixture's mean and variance is used instead, which is
        exact for a Gaussian predictive (a model linear in its parameters)."""
        from scipy.special import logsumexp
        from scipy.stats import norm

        if self.draw_mean is None or self.draw_sd is None:
            raise ValueError("this prediction keeps no per-draw moments")
        y = np.asarray(y, float)
        ym = np.log(y) if self.log else y
        lp = norm.logpdf(ym[None], self.draw_mean, self.draw_sd)  # (draws, n)
        mixture = logsumexp(lp, axis=0) - math.log(lp.shape[0])
        w = np.exp(lp - lp.max(axis=0))
        ess = w.sum(axis=0) ** 2 / np.sum(w**2, axis=0)
        var = np.mean(self.draw_sd**2, axis=0) + np.var(self.draw_mean, axis=0)
        gauss = norm.logpdf(ym, np.mean(self.draw_mean, axis=0), np.sqrt(var))
        ok = ess >= min_ess
        return np.where(ok, mixture, gauss), ok

    def pit(self, y: np.ndarray) -> np.ndarray:
        """Probability integral transform of observations ``y`` (n,) under the predictive:
        uniform on [0, 1] for a calibrated predictive. Exact for the mixture of the
        draws' Gaussians (its distribution function at ``y``, which resolves a tail
        probability of any size); from the samples for a prediction that keeps no
        per-draw moments."""
        y = np.asarray(y, float)
        if self.draw_mean is None or self.draw_sd is None:
            return np.mean(self.samples <= y[None], axis=0)
        from scipy.stats import norm

        with np.errstate(divide="ignore", invalid="ignore"):
            ym = np.log(y) if self.log else y
        return np.mean(norm.cdf(ym[None], self.draw_mean, self.draw_sd), axis=0)

    def point_shares(self) -> dict[str, np.ndarray]:
        """Share of each source in the predictive variance at every point, (n,) each."""
        total = sum(self.budget.values())
        safe = np.where(total > 0, total, 1.0)
        return {k: v / safe for k, v in self.budget.items()}

    def shares(self) -> dict[str, float]:
        """Average share of each source in the predictive variance (sums to 1)."""
        return {k: float(np.mean(v)) for k, v in self.point_shares().items()}

    def to_dict(self) -> dict:
        return {"dataset": self.dataset, "observes": self.observes,
                "inputs": list(self.input_keys), "x": self.x.tolist(),
                "mean": self.mean.tolist(), "lower95": self.lower.tolist(),
                "upper95": self.upper.tolist(),
                "variance_shares": self.shares()}


@partial(jax.jit, static_argnums=(0,), compiler_options=FEW_CALLS)
def _moments_over_draws(spec, on, gps, tdata, xp_new, thetas, hyper, eps, noise_new):
    """The KOH predictive of ``spec``'s one term for every posterior draw (vmap), with each
    linked surrogate ``k`` perturbed by ``on[k] * eps[k]`` (``on[k]`` 0 or 1). ``on`` is
    traced, so one compiled program per shape serves every choice of perturbed links."""
    term = spec.terms[0]
    data = {"gps": gps}

    def one(th, hy, ep):
        return spec.term_predict(data, term, tdata, th, hy, xp_new,
                                 {k: on[k] * ep[k] for k in ep}, noise_new)
    return jax.vmap(one)(thetas, hyper, eps)


def _switches(links: tuple[str, ...], on: tuple[str, ...] = ()) -> dict:
    """``on`` argument of :func:`_moments_over_draws`: 1.0 for the links in ``on``."""
    return {k: jnp.asarray(1.0 if k in on else 0.0) for k in links}


DRAW_BLOCK = 20
"""Posterior draws per call of a compiled predictive program."""
ROW_BLOCKS = (64, 1024)
"""Rows (process settings) per call: the smallest block that holds them all, else the
largest, as often as needed. With the draws in blocks of :data:`DRAW_BLOCK`, a data set's
predictive programs compile once for its data, leave-one-out points and test points (64)
and once for its Sobol points and map grid (1024), whatever the number of draws."""


def _padded(a: np.ndarray, n: int, axis: int) -> np.ndarray:
    """``a`` repeated at its last entry along ``axis`` to length ``n``."""
    k = a.shape[axis]
    if k == n:
        return a
    return np.take(a, np.r_[np.arange(k), np.full(n - k, k - 1)], axis=axis)


def _block(tree, where: tuple[slice, ...], sizes: tuple[int, ...]):
    """Every array of ``tree`` cut to ``where`` along its first axes and padded to
    ``sizes`` (see :func:`_padded`)."""
    def cut(a):
        a = a[where]
        for axis, n in enumerate(sizes):
            a = _padded(a, n, axis)
        return a
    return jax.tree.map(cut, tree)


def _blocked(fn, n_draws: int, n_rows: int, draws, rows, both=None):
    """``fn(draws, rows, both)`` over blocks of draws and rows, the results (pytrees of
    (draws, rows) arrays) put together as NumPy arrays.

    ``draws``: pytree of arrays with the draws first; ``rows``: with the rows first;
    ``both``: (draws, rows, ...). A short block is padded with copies of its last draw or
    row, whose results are dropped: the rows and draws of the predictive are independent.
    The blocks are cut on the host (NumPy): eager JAX slicing would compile a program per
    block shape.
    """
    draws, rows, both = jax.tree.map(np.asarray, (draws, rows, both or {}))
    if not n_rows or not n_draws:
        return jax.tree.map(np.asarray, fn(draws, rows, both))
    R = next((b for b in ROW_BLOCKS if n_rows <= b), ROW_BLOCKS[-1])
    D = DRAW_BLOCK
    columns = []
    for r0 in range(0, n_rows, R):
        r = slice(r0, min(r0 + R, n_rows))
        blocks = []
        for d0 in range(0, n_draws, D):
            d = slice(d0, min(d0 + D, n_draws))
            res = jax.tree.map(np.asarray, fn(_block(draws, (d,), (D,)),
                                              _block(rows, (r,), (R,)),
                                              _block(both, (d, r), (D, R))))
            blocks.append(_block(res, (slice(0, d.stop - d.start), slice(0, r.stop - r.start)),
                                 ()))
        columns.append(jax.tree.map(lambda *a: np.concatenate(a, axis=0), *blocks))
    return jax.tree.map(lambda *a: np.concatenate(a, axis=1), *columns)


@dataclass(frozen=True)
class _Setup:
    """What every predictive evaluation of one data set needs."""

    spec: KOHModel
    gps: dict
    tdata: dict
    thetas: dict
    hyper: dict
    keys: tuple[str, ...]
    log: bool


def warn_not_finite(what: str, samples: np.ndarray) -> None:
    """Warn where a prediction (predictive samples (m, n) of n points) is not a number at
    some points: a surrogate upstream gave values the input it feeds cannot take."""
    bad = ~np.all(np.isfinite(samples), axis=0)
    if bad.any():
        rows = np.flatnonzero(bad) + 1  # numbered from 1, as check_settings does
        warnings.warn(f"{what}: {rows.size} of {bad.size} point(s) have no finite prediction "
                      f"(point(s) {rows[:5].tolist()}{', ...' if rows.size > 5 else ''}): a "
                      "surrogate upstream gives values there that the input it feeds "
                      "cannot take (<= 0 into an input on the log scale, for instance); "
                      "declare 'transform: log' on such an output (calnet check warns of "
                      "one)", UserWarning, stacklevel=3)


def as_settings(network: Network, target: str, x) -> np.ndarray:
    """Process settings ``x`` for ``target`` as an array (n, k): a 1-D array is n points
    of a target with one process input, else one point."""
    x = np.asarray(x, dtype=float)
    if x.ndim == 1:
        one = len(network.process_input_keys(target_model(network, target))) == 1
        x = x[:, None] if one else x[None, :]
    return x


def check_settings(network: Network, surrogates: Surrogates, posterior: NetworkPosterior,
                   target: str, x: np.ndarray, what: str = "predict",
                   warn_outside: bool = True) -> None:
    """Process settings ``x`` (n, k) for predicting ``target`` (a data set or
    ``model.output``) as the Python predictions take them: a :class:`UsageError`
    (message starting with ``what``) for a wrong shape, no rows, or a setting that is
    not a finite number (or not positive on a log-scale input); with ``warn_outside``, a
    warning for settings outside the declared bounds and for linked inputs they take
    outside theirs (:func:`link_notes`), where the surrogates extrapolate (as
    :func:`settings_matrix` and the command line say them)."""
    model = target_model(network, target)
    keys = network.process_input_keys(model)
    if x.ndim != 2 or x.shape[1] != len(keys):
        got = f"{x.shape[1]} column(s)" if x.ndim == 2 else f"an array of shape {x.shape}"
        raise UsageError(f"{what}: expected {len(keys)} process inputs {list(keys)} as "
                         f"columns, got {got}")
    if not len(x):
        raise UsageError(f"{what}: no settings given (x has 0 rows)")
    for j, (key, (m, i)) in enumerate(zip(keys, network.process_inputs(model), strict=True)):
        var, v = network.model(m).variable(i), x[:, j]
        rows = np.flatnonzero(~np.isfinite(v))
        if rows.size:
            raise UsageError(f"{what}: {key} = {v[rows[0]]} at point {rows[0] + 1} is not a "
                             f"finite number ({rows.size} point(s)); give finite process "
                             "inputs")
        if getattr(var, "scale", "linear") == "log" and (v <= 0).any():
            r = int(np.flatnonzero(v <= 0)[0])
            raise UsageError(f"{what}: {key} = {v[r]:g} at point {r + 1} must be > 0 (its "
                             "scale is log)")
        rows = np.flatnonzero((v < var.lower) | (v > var.upper))
        if rows.size and warn_outside:
            unit = f" {var.unit}" if var.unit != "1" else ""
            warnings.warn(f"{what}: {key} lies outside its bounds [{var.lower:g}, "
                          f"{var.upper:g}]{unit} at {rows.size} of {len(v)} point(s) (point "
                          f"{rows[0] + 1}: {v[rows[0]]:g}); the surrogates extrapolate there",
                          UserWarning, stacklevel=3)
    if warn_outside:
        for note in link_notes(network, surrogates, posterior, target, x):
            warnings.warn(f"{what}: {note}", UserWarning, stacklevel=3)


def _setup(network: Network, surrogates: Surrogates, posterior: NetworkPosterior,
           dataset: str, idx: np.ndarray) -> _Setup:
    """The data set's KOH term (from the calibration data) and the draws ``idx``."""
    ds = network.dataset(dataset)
    if dataset not in posterior.hyper:
        raise CalnetError(f"data set '{dataset}' was not calibrated; nothing to predict")
    plan = ChainPlan.from_network(network)
    emu = network.settings.calibration.emulator_variance
    term, tdata = make_term(network, posterior.data[dataset], emulator_variance=emu, plan=plan,
                            directions=direction_models(network, posterior, dataset))
    spec = KOHModel(plan, (), (), (), (term.without_priors(),))
    thetas = draws_at(posterior.theta, plan, idx)
    hyper = hyper_at(posterior.hyper[dataset], idx, len(term.ell_priors))
    log = network.observed(ds).transform == "log"
    gps = {k: s.gp for k, s in surrogates.items.items()}
    return _Setup(spec, gps, tdata, thetas, hyper,
                  tuple(network.process_input_keys(ds.observed_model)), log)


@partial(jax.jit, static_argnums=(0,), compiler_options=FEW_CALLS)
def _loo_conditionals(spec, gps, tdata, thetas, hyper):
    """Per draw and point, the mean and precision of the point given the other points of
    the data set under the KOH model, standardised: (S, n) each.

    For ``r ~ N(0, K)``: ``r_i | r_-i ~ N(r_i - g_i / c_i, 1 / c_i)`` with ``g = K^-1 r``,
    ``c = diag(K^-1)`` (the discrepancy and the surrogates' covariance make the points
    dependent, so the pointwise likelihood is this conditional, not ``N(r_i; 0, K_ii)``).
    """
    term = spec.terms[0]
    data = {"gps": gps}

    def one(th, hy):
        r, K, _ = spec.train(data, term, tdata, th, hy)
        if K.ndim == 1:
            g, c = r / K, 1.0 / K
        else:
            L = jnp.linalg.cholesky(K)
            g = jax.scipy.linalg.cho_solve((L, True), r)
            c = jnp.diag(jax.scipy.linalg.cho_solve((L, True), jnp.eye(r.shape[0])))
        return tdata["y"] - g / c, c
    return jax.vmap(one)(thetas, hyper)


@dataclass(frozen=True)
class LOOConditionals:
    """Leave-one-out conditionals of a data set's calibration points, per posterior draw.

    Attributes
    ----------
    mean, sd : ndarray (S, n)
        Mean and sd of point i given the other points, on the modelled scale (logs for a
        log-modelled output), data units.
    loglik : ndarray (S, n)
        ``log p(y_i | y_-i, draw)`` on the modelled scale: the pointwise log-likelihood
        for PSIS leave-one-out.
    y : ndarray (n,)
        The observations on the modelled scale.
    log : bool
        Whether the output is modelled on the log scale.
    """

    mean: np.ndarray
    sd: np.ndarray
    loglik: np.ndarray
    y: np.ndarray
    log: bool


def loo_conditionals(network: Network, surrogates: Surrogates, posterior: NetworkPosterior,
                     dataset: str, idx: np.ndarray | None = None) -> LOOConditionals:
    """:class:`LOOConditionals` of ``dataset``'s calibration points at draws ``idx``
    (default: every draw)."""
    idx = np.arange(posterior.n_draws) if idx is None else np.asarray(idx)
    st = _setup(network, surrogates, posterior, dataset, idx)
    mean, prec = (np.asarray(a) for a in _loo_conditionals(st.spec, st.gps, st.tdata,
                                                               st.thetas, st.hyper))
    s, mu = float(st.tdata["y_sd"]), float(st.tdata["y_mean"])
    y = np.asarray(st.tdata["y"]) * s + mu
    m, sd = mean * s + mu, s / np.sqrt(prec)
    loglik = -0.5 * np.log(2 * np.pi) - np.log(sd) - 0.5 * ((y - m) / sd) ** 2
    return LOOConditionals(m, sd, loglik, y, st.log)


def _noise_at(st: _Setup, m: int, noise_var: np.ndarray | None) -> jnp.ndarray:
    """Known noise variance at ``m`` new points: given, or the calibration data's mean."""
    if noise_var is not None:
        return jnp.asarray(noise_var, dtype=float)
    return jnp.full(m, jnp.mean(st.tdata["noise_var"]))


@partial(jax.jit, static_argnums=(0,), compiler_options=FEW_CALLS)
def _means_over_draws(spec, gps, tdata, xp_new, thetas, hyper):
    """The KOH predictive mean (draws, m) of ``spec``'s one term for every posterior draw,
    without perturbed links: the variances' solves are left out of the program."""
    term = spec.terms[0]
    data = {"gps": gps}
    m = next(iter(xp_new.values())).shape[0]

    def one(th, hy):
        return spec.term_predict(data, term, tdata, th, hy, xp_new, {}, jnp.zeros(m))[0]
    return jax.vmap(one)(thetas, hyper)


def mean_function(network: Network, surrogates: Surrogates, posterior: NetworkPosterior,
                  dataset: str, idx: np.ndarray, *, per_draw: bool = False):
    """``f(x) -> (m,)``: the posterior mean over draws ``idx`` of the KOH predictive mean
    at process settings ``x`` (m, k), natural scale (the Sobol stage's function). With
    ``per_draw``, ``f(x) -> (len(idx), m)``: each draw's predictive mean."""
    st = _setup(network, surrogates, posterior, dataset, np.asarray(idx))

    def f(x):
        x = np.atleast_2d(np.asarray(x, dtype=float))
        xp = {k: device_array(x[:, j]) for j, k in enumerate(st.keys)}
        mean = _blocked(lambda d, r, _: _means_over_draws(st.spec, st.gps, st.tdata, r,
                                                          d["thetas"], d["hyper"]),
                        len(idx), len(x), {"thetas": st.thetas, "hyper": st.hyper}, xp)
        z = mean * float(st.tdata["y_sd"]) + float(st.tdata["y_mean"])
        z = np.exp(z) if st.log else z
        return z if per_draw else np.mean(z, axis=0)

    return f


def point_normals(seed: int, x: np.ndarray, stream: str, shape: tuple[int, ...]) -> np.ndarray:
    """Standard normal draws ``(*shape, n)`` for the points ``x`` (n, k), column ``i`` from
    its own generator, seeded by ``seed``, ``stream`` and the point's input values.

    A point's draws, and so its prediction, depend on the seed and the point only, not on
    which other points are predicted with it or in what order (method.md section 5).
    The point's values enter as the bytes of little-endian float64 (-0.0 as 0.0), hashed
    with BLAKE2b, so the draws are the same on every platform.
    """
    x = np.atleast_2d(np.asarray(x, dtype="<f8")) + 0.0
    out = np.empty((*shape, len(x)))
    for i, row in enumerate(x):
        digest = hashlib.blake2b(row.tobytes() + stream.encode(), digest_size=16).digest()
        words = np.frombuffer(digest, dtype="<u4").tolist()
        out[..., i] = np.random.default_rng([seed, *words]).standard_normal(shape)
    return out


def predict(network: Network, surrogates: Surrogates, posterior: NetworkPosterior,
            dataset: str, x: np.ndarray, *, n_draws: int = 200, seed: int = 0,
            n_samples: int = 20,
            within: tuple[float | None, float | None] | None = None,
            noise_var: np.ndarray | None = None, warn_outside: bool = True) -> Prediction:
    """Posterior predictive of the output observed by ``dataset`` at process settings.

    Parameters
    ----------
    x : array (n, k)
        Process inputs, columns in the order of ``network.process_inputs(model)``.
        A 1-D array is n points of a target with one process input.
    n_draws : int
        Posterior draws used (thinned evenly from the posterior; repeated where it holds
        fewer), each with its own draw of the upstream surrogates.
    n_samples : int
        Predictive samples per draw used for the 95 % interval.
    seed : int
        Seeds each point's draws of the upstream surrogates and of the new measurement
        (:func:`point_normals`): a point's prediction depends on the seed and the point,
        not on the other rows of ``x``.
    within : (lower, upper), optional
        Also return the probability that a new measurement lies in this range (either
        end may be None).
    noise_var : array (n,), optional
        Known noise variance of a new measurement at each point (modelled scale), for a
        data set with known noise. Default: the mean over its calibration data of the
        variance in the data's units, which for an output modelled on the log scale is
        divided by the square of each draw's predicted value at the point (a known sd is
        a relative one there, ``sd / y``).
    warn_outside : bool
        Warn where a setting lies outside its input's bounds (the surrogates extrapolate
        there). A setting that is not a finite number is an error either way.
    """
    # n_draws rows even from fewer draws (repeated), so that the upstream surrogates'
    # draws below still number n_draws (a posterior without parameters has 0 draws)
    idx = np.resize(draw_index(posterior.n_draws, n_draws), n_draws)
    st = _setup(network, surrogates, posterior, dataset, idx)
    x = as_settings(network, dataset, x)
    check_settings(network, surrogates, posterior, dataset, x, "predict", warn_outside)
    xp_new = {k: device_array(x[:, j]) for j, k in enumerate(st.keys)}
    # the surrogates upstream of the observed model: the others play no part
    links = links_into(st.spec.plan, network.dataset(dataset).observed_model)
    eps = {k: device_array(point_normals(seed, x, f"emulator {k}", (len(idx),)))
           for k in links}
    noise_new = _noise_at(st, len(x), noise_var)
    key = network.dataset(dataset).observes

    def run(eps_on):
        on = _switches(links, tuple(eps_on))
        return _blocked(lambda d, r, b: _moments_over_draws(
            st.spec, on, st.gps, st.tdata, r["xp"], d["thetas"], d["hyper"], b, r["noise"]),
            len(idx), len(x), {"thetas": st.thetas, "hyper": st.hyper},
            {"xp": xp_new, "noise": noise_new}, eps)

    mean0, var_delta, var_emu, noise = (np.asarray(a) for a in run(()))
    # the spread of the mean over draws: parameters, and the discrepancy's and noise's
    # hyperparameters (only those where the network has no calibration parameters)
    spread = ("parameters" if any(network.model(m).parameters for m in network.order)
              else "hyperparameters")
    budget = {spread: mean0.var(axis=0)}
    perturbed = {(): mean0}
    for k in links:  # upstream emulator variance, one surrogate at a time
        perturbed[(k,)] = np.asarray(run((k,))[0])
        budget[f"emulator {k}"] = np.mean((perturbed[(k,)] - mean0) ** 2, axis=0)
    if links not in perturbed:  # every link at once (the same run when there is one)
        perturbed[links] = np.asarray(run(links)[0])
    mean_all = perturbed[links]
    s, mu = float(st.tdata["y_sd"]), float(st.tdata["y_mean"])
    if noise_var is None and st.log and network.dataset(dataset).noise.known:
        # a known sd in the data's units is a relative one on the log scale, sd / y: at a
        # new point that of the value each draw predicts there
        absolute = float(np.mean(np.asarray(posterior.data[dataset].noise_sd, float) ** 2))
        noise = absolute * np.exp(-2.0 * (mean_all * s + mu)) / s**2
    budget[f"emulator {key}"] = var_emu.mean(axis=0)
    budget["discrepancy"] = var_delta.mean(axis=0)
    budget["noise"] = noise.mean(axis=0)
    sd = np.sqrt(var_delta + var_emu + noise)
    z = point_normals(seed, x, "new measurement", (n_samples, len(idx)))
    samples = (mean_all[None] + sd[None] * z).reshape(-1, len(x)) * s + mu
    if st.log:
        samples = np.exp(samples)
    lo, hi = np.percentile(samples, [2.5, 97.5], axis=0)
    warn_not_finite(dataset, samples)
    prob = None
    if within is not None:
        ok = np.ones(samples.shape, dtype=bool)
        if within[0] is not None:
            ok &= samples >= within[0]
        if within[1] is not None:
            ok &= samples <= within[1]
        prob = ok.mean(axis=0)
    draw_mean, draw_sd = mean_all * s + mu, sd * s
    # the mixture's mean, exact given the draws (the samples' mean adds their noise)
    mean = (np.mean(np.exp(draw_mean + 0.5 * draw_sd**2), axis=0) if st.log
            else np.mean(draw_mean, axis=0))
    return Prediction(dataset, key, st.keys, x, mean, lo, hi, budget, prob, samples,
                      draw_mean, draw_sd, bool(st.log))


def predict_data(network: Network, surrogates: Surrogates, posterior: NetworkPosterior,
                 data, **kwargs) -> Prediction:
    """:func:`predict` at a data set's own rows, with their known noise if any."""
    return predict(network, surrogates, posterior, data.name, data.x,
                   noise_var=known_noise_var(network, data), warn_outside=False, **kwargs)


def crps_from_samples(y: np.ndarray, samples: np.ndarray) -> np.ndarray:
    """Continuous ranked probability score of each point (n,) from predictive samples
    (k, n): ``E|X - y| - E|X - X'| / 2``, with the second term from the sorted samples
    (exact for the empirical distribution)."""
    x = np.sort(np.asarray(samples, float), axis=0)
    k = x.shape[0]
    first = np.mean(np.abs(x - np.asarray(y, float)[None]), axis=0)
    weights = (2 * np.arange(1, k + 1) - k - 1)[:, None]
    return first - np.sum(weights * x, axis=0) / k**2


def interval_score(y: np.ndarray, lower: np.ndarray, upper: np.ndarray,
                   alpha: float = 0.05) -> np.ndarray:
    """Interval score of central (1 - alpha) intervals, per point (Gneiting & Raftery
    2007): the width plus 2 / alpha times the miss."""
    y, lower, upper = (np.asarray(a, float) for a in (y, lower, upper))
    return ((upper - lower) + (2 / alpha) * np.maximum(lower - y, 0)
            + (2 / alpha) * np.maximum(y - upper, 0))


def metrics(y: np.ndarray, mean: np.ndarray, lower: np.ndarray | None = None,
            upper: np.ndarray | None = None, *, samples: np.ndarray | None = None,
            pit: np.ndarray | None = None, y_range: float | None = None,
            relative: bool = False, mape_y: np.ndarray | None = None
            ) -> dict[str, float | None]:
    """Errors of predictions of ``y``: RMSE (the reference study's SE_pred, method.md
    section 5), NRMSE (RMSE / ``y_range``, default the range of y: pass the whole data
    set's so that its splits share one scale), MAPE (%, None where
    :func:`mape_meaningful` says no for ``mape_y``, default y: pass the whole data set's
    so that its splits agree; ``relative`` for data modelled on the log scale, see
    there); with a 95 % band its coverage and mean interval
    score; with predictive samples (k, n) the mean CRPS; with PIT values (n,) the
    coverage of the central 50, 80 and 95 % intervals."""
    y, mean = np.asarray(y, float), np.asarray(mean, float)
    rmse = float(np.sqrt(np.mean((y - mean) ** 2)))
    spread = (float(y_range) if y_range is not None
              else float(np.ptp(y)) if len(y) > 1 else 0.0)
    out: dict[str, float | None] = {
        "n": int(len(y)), "rmse": rmse,
        "nrmse": rmse / spread if spread > 0 else None,
        "mape": (float(np.mean(np.abs(y - mean) / np.abs(y)) * 100)
                 if mape_meaningful(y if mape_y is None else mape_y, relative=relative)
                 else None)}
    if lower is not None and upper is not None:
        out["coverage95"] = float(np.mean((y >= lower) & (y <= upper)))
        out["interval_score95"] = float(np.mean(interval_score(y, lower, upper)))
    if samples is not None:
        out["crps"] = float(np.mean(crps_from_samples(y, samples)))
    if pit is not None:
        pit = np.asarray(pit, float)
        for level in (50, 80, 95):
            out[f"pit_coverage{level}"] = float(np.mean(np.abs(pit - 0.5) <= level / 200))
    return out


def target_model(network: Network, target: str) -> str:
    """The model whose output ``target`` predicts: a data set's observed model, or the
    model of ``model.output``."""
    return target.split(".")[0] if "." in target else network.dataset(target).observed_model


def resolve_input(network: Network, target: str, name: str) -> str | None:
    """``model.input`` of the process input ``name`` (bare or qualified) of ``target`` (a
    data set or ``model.output``); None if it is none of them, CalnetError if ambiguous."""
    keys = network.process_input_keys(target_model(network, target))
    if name in keys:
        return name
    matches = [k for k in keys if k.split(".")[1] == name]
    if len(matches) > 1:
        raise CalnetError(f"'{name}' is ambiguous for {target} ({matches}); write it as "
                          "model.input")
    return matches[0] if matches else None


def settings_matrix(network: Network, target: str, rows: list[dict[str, float | str]], *,
                    skip: Collection[str] = ()) -> tuple[np.ndarray, list[str]]:
    """Process settings for predicting ``target`` (a data set or ``model.output``) as an
    array ``(n, k)``.

    Each row maps input names (bare ``P`` or qualified ``melt_pool.P``) to values. Every
    process input must be given; names that are not process inputs of the target's
    chain are an error, except those in ``skip`` (inputs of other targets predicted
    from the same rows), which are ignored. Returns the array and a list of warnings for
    values outside the declared bounds (the surrogates extrapolate there). A point that
    misses an input or gives one that is not a finite number (text from a CSV cell, for
    instance) is a :class:`~calnet.errors.UsageError`.
    """
    model = target_model(network, target)
    what = target if "." in target else network.dataset(target).observes
    pairs = network.process_inputs(model)
    keys = network.process_input_keys(model)
    x = np.empty((len(rows), len(keys)))
    notes: list[str] = []
    for r, row in enumerate(rows):
        given: dict[str, float | str] = {}
        for name, value in row.items():
            key = resolve_input(network, target, name)
            if key is None:
                if name in skip:
                    continue
                raise UsageError(f"'{name}' is not a process input of '{what}'; "
                                 f"give {_names(keys)}")
            given[key] = value
        missing = [k for k in keys if k not in given]
        if missing:
            raise UsageError(f"point {r + 1}: missing {_names(missing)}; '{what}' "
                             f"needs {_names(keys)}")
        for j, (key, (m, i)) in enumerate(zip(keys, pairs, strict=True)):
            value = given[key]
            if isinstance(value, str):
                raise UsageError(f"point {r + 1}: {key} = '{value}' is not a number; give "
                                 "a number for every input")
            if not np.isfinite(value):
                raise UsageError(f"point {r + 1}: {key} = {value} is not a finite number")
            var = network.model(m).variable(i)
            if getattr(var, "scale", "linear") == "log" and value <= 0:
                raise UsageError(f"point {r + 1}: {key} = {value:g} must be > 0 (its scale "
                                 "is log)")
            if not var.lower <= value <= var.upper:
                unit = f" {var.unit}" if var.unit != "1" else ""  # not "[0, 1] 1"
                notes.append(f"point {r + 1}: {key} = {value:g} lies outside its bounds "
                             f"[{var.lower:g}, {var.upper:g}]{unit}; the surrogates "
                             "extrapolate there")
            x[r, j] = value
    return x, notes


LINK_TOLERANCE = 0.01
"""Fraction of an input's range by which a linked value must leave it to be reported
(:func:`link_notes`)."""


def link_notes(network: Network, surrogates: Surrogates, posterior: NetworkPosterior,
               target: str, x: np.ndarray) -> list[str]:
    """A note for every linked input of ``target``'s chain that leaves its declared bounds
    at the process settings ``x`` (n, k) (as :func:`settings_matrix` returns them): the
    downstream surrogate was not trained there and extrapolates.

    The linked values are the upstream surrogates' means at the posterior median of the
    upstream parameters (at the middle of their bounds where there is no posterior), so a
    value near a bound is an estimate (an identity link's value is exact): a value counts
    as outside only beyond :data:`LINK_TOLERANCE` of the input's range (on its log scale
    where declared), so a surrogate mean that overshoots a bound a little at a setting
    inside the box says nothing.
    """
    model = target_model(network, target)
    plan = ChainPlan.from_network(network)
    gps = {k: s.gp for k, s in surrogates.items.items()}
    xp = {k: device_array(x[:, j], float)
          for j, k in enumerate(network.process_input_keys(model))}
    thetas = {}
    for m in network.order:
        draws = posterior.theta.get(m)
        if draws is not None and np.size(draws):
            thetas[m] = device_array(np.median(draws, axis=0), float)
        else:
            thetas[m] = device_array([0.5 * (p.lower + p.upper)
                                      for p in network.model(m).parameters], float)
    notes = []
    for m in (*network.ancestors(model), model):
        linked = [(j, var) for j, var in enumerate(network.model(m).inputs)
                  if network.link_into(m, var.name) is not None]
        if not linked:
            continue
        values = np.asarray(plan.inputs(gps, m, xp, thetas))
        for j, var in linked:
            source = network.link_into(m, var.name).source
            unit = f" {var.unit}" if var.unit != "1" else ""
            v, lo, hi = values[:, j], var.lower, var.upper
            if getattr(var, "scale", "linear") == "log":
                v, lo, hi = np.log(np.maximum(v, 1e-300)), math.log(lo), math.log(hi)
            tol = LINK_TOLERANCE * (hi - lo)
            for r in np.flatnonzero((v < lo - tol) | (v > hi + tol)):
                notes.append(f"point {r + 1}: {m}.{var.name} = {values[r, j]:.4g} (from "
                             f"{source}) lies outside its bounds [{var.lower:g}, "
                             f"{var.upper:g}]{unit}; the {m} surrogates extrapolate there")
    return notes


def _names(keys: list[str]) -> str:
    bare = [k.split(".", 1)[1] for k in keys]
    return ", ".join(bare if len(set(bare)) == len(bare) else keys)


def load_surrogates(network: Network, run_dir: str | Path) -> Surrogates:
    """The surrogates that ``calnet run`` (or ``calnet surrogates``) wrote to ``run_dir``,
    checked to be ``network``'s (a run folder of another spec fails here)."""
    from calnet.files import check_complete

    run_dir = Path(run_dir)
    check_complete(run_dir)
    sur_dir = run_dir / "surrogates"
    if not (sur_dir / "surrogates.json").is_file():
        raise CalnetError(f"no fitted surrogates in '{sur_dir}'; run 'calnet run SPEC --out "
                          f"{run_dir}' first, or pass --run DIR")
    sur = Surrogates.load(sur_dir)
    check_surrogates(network, sur, sur_dir)
    return sur


def load_run(network: Network, run_dir: str | Path) -> tuple[Surrogates, NetworkPosterior]:
    """The surrogates and posterior that ``calnet run`` (or ``calnet surrogates`` and
    ``calnet calibrate``) wrote to ``run_dir``; for a network without parameters that was
    never calibrated, the empty posterior."""
    run_dir = Path(run_dir)
    sur = load_surrogates(network, run_dir)
    folder = run_dir / "posterior"
    if (not (folder / f"{POSTERIOR_FILE}.json").is_file()
            and not any(m.parameters for m in network.models)):
        post = uncalibrated(network)
    else:
        post = load_posterior(folder, network)
        _warn_changed_data(network, post, run_dir)
    return sur, post


def _warn_changed_data(network: Network, post: NetworkPosterior, run_dir: Path) -> None:
    """Warn of each data set whose file no longer holds the training points that the
    posterior in ``run_dir`` was calibrated with: predictions condition on the
    calibration's points (the discrepancy included), not on the file as it is now."""
    from calnet.spec import read_all

    with warnings.catch_warnings():  # the data's own warnings were given at calibration
        warnings.simplefilter("ignore")
        now = read_all(network)
    for name, used in post.data.items():
        if name not in now:
            continue
        cur = now[name].train
        same = (cur.x.shape == used.x.shape and np.array_equal(cur.x, used.x)
                and np.array_equal(cur.y, used.y))
        if not same:
            what = (f"it now has {len(cur.y)} training points, the calibration had "
                    f"{len(used.y)}" if len(cur.y) != len(used.y) else
                    f"{int(np.sum(np.any(cur.x != used.x, axis=1) | (cur.y != used.y)))} of "
                    f"its {len(cur.y)} training points differ from the calibration's")
            warnings.warn(f"data set {name}: its file changed after the calibration in "
                          f"'{run_dir}' ({what}); the predictions use the calibration's "
                          "points; calibrate again (calnet run) to use the file as it is",
                          CalibrationWarning, stacklevel=3)


def prediction_targets(network: Network, surrogates: Surrogates, posterior: NetworkPosterior,
                       asked: Sequence[str] = ()) -> list[str]:
    """What to predict: the data sets and ``model.output`` names ``asked``, or (none
    asked) every calibrated data set and every output of ``settings.predict``."""
    names = list(asked) or [*posterior.hyper, *network.settings.predict]
    unknown = [d for d in names if d not in (surrogates.items if "." in d else posterior.hyper)]
    if unknown:
        choices = [f"a calibrated data set {list(posterior.hyper)}" if posterior.hyper
                   else "", f"an output with a surrogate {list(surrogates.items)}"
                   if surrogates.items else ""]
        raise (UsageError if asked else CalnetError)(
            f"nothing to predict for {unknown}; choose "
            + (" or ".join(c for c in choices if c) or "nothing: this run calibrated no "
               "data set and fitted no surrogate"))
    if not names:
        raise CalnetError("nothing to predict: the network has no data sets and "
                          "settings.predict is empty; pass -d model.output")
    return names


def _takes(network: Network, target: str, name: str) -> bool:
    """Whether ``name`` (bare or qualified) is a process input of ``target``."""
    try:
        return resolve_input(network, target, name) is not None
    except CalnetError:  # ambiguous: predicting the target says so
        return True


def shared_inputs(network: Network, targets: Sequence[str],
                  rows: list[dict[str, float | str]]) -> set[str]:
    """The names in ``rows`` that some of ``targets`` take: a point given for several
    targets may carry inputs that only some of them take (``skip`` of
    :func:`settings_matrix`)."""
    return {k for row in rows for k in row if any(_takes(network, t, k) for t in targets)}


def read_points(path: str | Path) -> list[dict[str, float | str]]:
    """Process settings from a CSV file, one point per row under a header of input names
    (bare ``P`` or qualified ``melt_pool.P``): ``[{name: value}, ...]``.

    A cell that is not a number stays text (an ID or label column, for instance): the
    columns that are not process inputs are ignored, and text in an input column is
    refused by :func:`settings_matrix`. A missing, unreadable or empty file is a
    :class:`~calnet.errors.UsageError`.
    """
    import pandas as pd  # pandas only where points come from a file

    path = Path(path)
    if not path.is_file():
        raise UsageError(f"--csv: no file '{path}'; give a CSV file of points, one column "
                         "per input")
    try:
        frame = pd.read_csv(path)
    except Exception as err:  # noqa: BLE001 - any parse failure is the user's file
        raise UsageError(f"--csv {path}: cannot read it as CSV ({err})") from None
    if frame.empty:
        raise UsageError(f"--csv {path}: no rows; write one point per row under the header")
    return [{str(k): _cell(v) for k, v in row.items()} for row in frame.to_dict("records")]


def _cell(value: object) -> float | str:
    """A CSV cell as a float, or as its text where it is not a number."""
    try:
        return float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return str(value)


def shares_per_point(prediction: Prediction) -> list[dict[str, float]]:
    """Share of each source in the predictive variance, one dict per point."""
    shares = prediction.point_shares()
    return [{k: float(v[i]) for k, v in shares.items()} for i in range(len(prediction.mean))]


def largest_shares(prediction: Prediction, n: int = 3) -> list[list[tuple[str, float]]]:
    """Per point, the ``n`` sources with the largest shares of the predictive variance,
    largest first: ``[[(source, share), ...], ...]``."""
    return [sorted(point.items(), key=lambda kv: -kv[1])[:n]
            for point in shares_per_point(prediction)]
