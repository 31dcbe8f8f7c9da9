"""Prior distributions for calibration parameters and discrepancy hyperparameters.

Each prior is a small frozen (hashable) dataclass holding plain floats, so that a prior can
be part of the key of a compiled sampler. It gives, as pure JAX functions,

* ``log_prob(x)``: the log-density on the constrained (physical) scale;
* ``to_constrained(u)`` / ``to_unconstrained(x)``: its bijection with the real line
  (the logit of the scaled value for a bounded parameter, the log for a positive one);
* ``log_abs_det_jacobian(u)``: ``log |dx/du|`` of that bijection;
* ``log_prob_unconstrained(u)``: the density of ``u``, i.e. ``log_prob(x(u)) + log|dx/du|``,
  written so that it stays finite far out in the tails (no ``log(0)`` when ``sigmoid(u)``
  rounds to 1);
* ``sample(rng, shape)``: NumPy draws on the constrained scale (initial points; NumPy
  rather than ``jax.random`` because JAX's beta/gamma samplers take seconds to compile).

The priors of the reference study (method.md section 3) are the defaults:
``Beta(1.1, 1.1)`` scaled to the bounds of a calibration parameter, ``LogNormal(0, 0.5)``
for discrepancy length scales (inputs scaled to the unit cube) and ``InverseGamma(2, 1)``
for the discrepancy and noise variances (outputs standardised).

Examples
--------
>>> import jax.numpy as jnp
>>> from calnet.calibration.priors import Beta
>>> prior = Beta(60.0, 100.0)
>>> x = prior.to_constrained(jnp.asarray(0.0))
>>> float(x)
80.0
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from jax.scipy.special import betaln, gammaln  # noqa: E402
from scipy.special import ndtr  # noqa: E402
from scipy.stats import truncnorm  # noqa: E402

from calnet.errors import CalibrationError  # noqa: E402

__all__ = [
    "Prior",
    "Beta",
    "Uniform",
    "Normal",
    "TruncatedNormal",
    "LogNormal",
    "InverseGamma",
    "stack_priors",
]

_LOG_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)


def _check_bounds(name: str, lower: float, upper: float) -> None:
    if not (math.isfinite(lower) and math.isfinite(upper) and lower < upper):
        raise CalibrationError(
            f"{name} prior: expected finite lower < upper, got lower={lower}, upper={upper}; "
            "fix the parameter bounds"
        )


def _check_positive(name: str, **values: float) -> None:
    for key, value in values.items():
        if not (math.isfinite(value) and value > 0):
            raise CalibrationError(f"{name} prior: expected {key} > 0, got {value}")


@dataclass(frozen=True)
class Prior:
    """Base class: a univariate prior and its bijection to the real line."""

    @property
    def support(self) -> tuple[float, float]:
        """``(lower, upper)`` of the constrained value (may be infinite)."""
        raise NotImplementedError

    def log_prob(self, x):
        """Log-density at constrained values ``x`` (any shape)."""
        raise NotImplementedError

    def to_constrained(self, u):
        """Map unconstrained reals ``u`` to the support."""
        raise NotImplementedError

    def to_unconstrained(self, x):
        """Inverse of :meth:`to_constrained`."""
        raise NotImplementedError

    def log_abs_det_jacobian(self, u):
        """``log |dx/du|`` at unconstrained ``u``."""
        raise NotImplementedError

    def log_prob_unconstrained(self, u):
        """Log-density of the unconstrained variable, ``log p(x(u)) + log|dx/du|``."""
        return self.log_prob(self.to_constrained(u)) + self.log_abs_det_jacobian(u)

    def sample(self, rng, shape=()):
        """Draws on the constrained scale, shape ``shape``; ``rng``: a NumPy Generator or seed."""
        raise NotImplementedError

    def sample_unconstrained(self, rng, shape=()):
        """Prior draws mapped to the unconstrained scale (finite), shape ``shape``."""
        return np.asarray(self.to_unconstrained(self.sample(rng, shape)))


@dataclass(frozen=True)
class _Bounded(Prior):
    """A prior on ``[lower, upper]`` with the scaled-logit bijection."""

    lower: float = 0.0
    upper: float = 1.0

    def __post_init__(self):
        object.__setattr__(self, "lower", float(self.lower))
        object.__setattr__(self, "upper", float(self.upper))
        _check_bounds(type(self).__name__, self.lower, self.upper)

    @property
    def support(self) -> tuple[float, float]:
        return (self.lower, self.upper)

    @property
    def width(self) -> float:
        return self.upper - self.lower

    def to_constrained(self, u):
        return self.lower + self.width * jax.nn.sigmoid(u)

    def to_unconstrained(self, x):
        z = (jnp.asarray(x) - self.lower) / self.width
        return jnp.log(z) - jnp.log1p(-z)

    def log_abs_det_jacobian(self, u):
        # x = lower + w * sigmoid(u)  =>  dx/du = w * sigmoid(u) * sigmoid(-u)
        return np.log(self.width) + jax.nn.log_sigmoid(u) + jax.nn.log_sigmoid(-u)

    def sample_unconstrained(self, rng, shape=()):
        # keep initial points off the bounds, where the logit is infinite
        z = (self.sample(rng, shape) - self.lower) / self.width
        z = np.clip(z, 1e-6, 1.0 - 1e-6)
        return np.log(z) - np.log1p(-z)

    def _inside(self, x):
        return (x >= self.lower) & (x <= self.upper)


@dataclass(frozen=True)
class Beta(_Bounded):
    """Beta(a, b) scaled to ``[lower, upper]`` (method.md section 3: a = b = 1.1)."""

    a: float = 1.1
    b: float = 1.1

    def __post_init__(self):
        super().__post_init__()
        object.__setattr__(self, "a", float(self.a))
        object.__setattr__(self, "b", float(self.b))
        _check_positive("Beta", a=self.a, b=self.b)

    def log_prob(self, x):
        z = (jnp.asarray(x) - self.lower) / self.width
        lp = ((self.a - 1.0) * jnp.log(z) + (self.b - 1.0) * jnp.log1p(-z)
              - betaln(self.a, self.b) - np.log(self.width))
        return jnp.where(self._inside(x), lp, -jnp.inf)

    def log_prob_unconstrained(self, u):
        # z = sigmoid(u): p(u) = z^a (1 - z)^b / B(a, b), evaluated through log_sigmoid
        return (self.a * jax.nn.log_sigmoid(u) + self.b * jax.nn.log_sigmoid(-u)
                - betaln(self.a, self.b))

    def sample(self, rng, shape=()):
        return self.lower + self.width * np.random.default_rng(rng).beta(self.a, self.b, shape)


@dataclass(frozen=True)
class Uniform(_Bounded):
    """Uniform on ``[lower, upper]``."""

    def log_prob(self, x):
        return jnp.where(self._inside(x), -np.log(self.width), -jnp.inf)

    def log_prob_unconstrained(self, u):
        return jax.nn.log_sigmoid(u) + jax.nn.log_sigmoid(-u)

    def sample(self, rng, shape=()):
        return np.random.default_rng(rng).uniform(self.lower, self.upper, shape)


@dataclass(frozen=True)
class TruncatedNormal(_Bounded):
    """Normal(mu, sigma) truncated to ``[lower, upper]`` (a bounded parameter)."""

    mu: float = 0.5
    sigma: float = 1.0

    def __post_init__(self):
        super().__post_init__()
        object.__setattr__(self, "mu", float(self.mu))
        object.__setattr__(self, "sigma", float(self.sigma))
        _check_positive("TruncatedNormal", sigma=self.sigma)

    def _log_mass(self) -> float:
        # log(Phi(b) - Phi(a)) in NumPy (a constant of the traced density); in the upper
        # tail through the survival function to keep precision
        a = (np.asarray(self.lower) - self.mu) / self.sigma
        b = (np.asarray(self.upper) - self.mu) / self.sigma
        return np.log(np.where(a < 0, ndtr(b) - ndtr(a), ndtr(-a) - ndtr(-b)))

    def log_prob(self, x):
        s = (jnp.asarray(x) - self.mu) / self.sigma
        lp = -0.5 * s**2 - _LOG_SQRT_2PI - np.log(self.sigma) - self._log_mass()
        return jnp.where(self._inside(x), lp, -jnp.inf)

    def sample(self, rng, shape=()):
        a = (self.lower - self.mu) / self.sigma
        b = (self.upper - self.mu) / self.sigma
        return truncnorm.rvs(a, b, loc=self.mu, scale=self.sigma, size=shape,
                             random_state=np.random.default_rng(rng))


@dataclass(frozen=True)
class Normal(Prior):
    """Normal(mu, sigma) on the whole real line (identity bijection)."""

    mu: float = 0.0
    sigma: float = 1.0

    def __post_init__(self):
        object.__setattr__(self, "mu", float(self.mu))
        object.__setattr__(self, "sigma", float(self.sigma))
        _check_positive("Normal", sigma=self.sigma)

    @property
    def support(self) -> tuple[float, float]:
        return (-math.inf, math.inf)

    def log_prob(self, x):
        s = (jnp.asarray(x) - self.mu) / self.sigma
        return -0.5 * s**2 - _LOG_SQRT_2PI - np.log(self.sigma)

    def to_constrained(self, u):
        return jnp.asarray(u)

    def to_unconstrained(self, x):
        return jnp.asarray(x)

    def log_abs_det_jacobian(self, u):
        return jnp.zeros_like(jnp.asarray(u, dtype=float))

    def sample(self, rng, shape=()):
        return np.random.default_rng(rng).normal(self.mu, self.sigma, shape)


@dataclass(frozen=True)
class _Positive(Prior):
    """A prior on ``(0, inf)`` with the log bijection."""

    @property
    def support(self) -> tuple[float, float]:
        return (0.0, math.inf)

    def to_constrained(self, u):
        return jnp.exp(u)

    def to_unconstrained(self, x):
        return jnp.log(x)

    def log_abs_det_jacobian(self, u):
        return jnp.asarray(u, dtype=float)


@dataclass(frozen=True)
class LogNormal(_Positive):
    """LogNormal(mu, sigma): ``log x ~ Normal(mu, sigma)``.

    The default ``sigma = 0.5`` (variance 1/4) is the reference prior of the discrepancy
    length scales on unit-cube inputs (method.md section 3).
    """

    mu: float = 0.0
    sigma: float = 0.5

    def __post_init__(self):
        object.__setattr__(self, "mu", float(self.mu))
        object.__setattr__(self, "sigma", float(self.sigma))
        _check_positive("LogNormal", sigma=self.sigma)

    def log_prob(self, x):
        x = jnp.asarray(x)
        safe = jnp.where(x > 0, x, 1.0)
        s = (jnp.log(safe) - self.mu) / self.sigma
        lp = -0.5 * s**2 - _LOG_SQRT_2PI - np.log(self.sigma) - jnp.log(safe)
        return jnp.where(x > 0, lp, -jnp.inf)

    def log_prob_unconstrained(self, u):
        # u = log x ~ Normal(mu, sigma)
        s = (u - self.mu) / self.sigma
        return -0.5 * s**2 - _LOG_SQRT_2PI - np.log(self.sigma)

    def sample(self, rng, shape=()):
        return np.random.default_rng(rng).lognormal(self.mu, self.sigma, shape)


@dataclass(frozen=True)
class InverseGamma(_Positive):
    """InverseGamma(a, b) with density ``b^a / Gamma(a) x^(-a-1) exp(-b / x)``.

    The default ``(2, 1)`` is the reference prior of the discrepancy and noise variances
    on standardised outputs (method.md section 3).
    """

    a: float = 2.0
    b: float = 1.0

    def __post_init__(self):
        object.__setattr__(self, "a", float(self.a))
        object.__setattr__(self, "b", float(self.b))
        _check_positive("InverseGamma", a=self.a, b=self.b)

    def log_prob(self, x):
        x = jnp.asarray(x)
        safe = jnp.where(x > 0, x, 1.0)
        lp = (self.a * np.log(self.b) - gammaln(self.a) - (self.a + 1.0) * jnp.log(safe)
              - self.b / safe)
        return jnp.where(x > 0, lp, -jnp.inf)

    def log_prob_unconstrained(self, u):
        # x = exp(u): log p = a log b - lgamma(a) - a u - b exp(-u)
        return self.a * np.log(self.b) - gammaln(self.a) - self.a * u - self.b * jnp.exp(-u)

    def sample(self, rng, shape=()):
        return self.b / np.random.default_rng(rng).gamma(self.a, 1.0, shape)


def stack_priors(priors) -> list[tuple[int, int, Prior]]:
    """Group a sequence of priors into runs of one class with stacked parameters.

    Returns ``(start, stop, stacked)`` triples where ``stacked`` is an instance of the
    run's class whose fields are NumPy arrays, so that one call of its methods on
    ``u[start:stop]`` evaluates the whole run (fewer, fused XLA operations than one call
    per coordinate). The stacked instances are not validated and not hashable; they live
    only while a log-density is traced.
    """
    out, start = [], 0
    priors = list(priors)
    while start < len(priors):
        cls = type(priors[start])
        stop = start
        while stop < len(priors) and type(priors[stop]) is cls:
            stop += 1
        stacked = object.__new__(cls)
        for f in fields(cls):
            object.__setattr__(stacked, f.name,
                               np.array([getattr(p, f.name) for p in priors[start:stop]]))
        out.append((start, stop, stacked))
        start = stop
    return out


def init_from_priors(blocks, seed, n_chains: int) -> np.ndarray:
    """Initial points drawn from the priors on the unconstrained scale, (n_chains, dim).

    ``blocks`` is a sequence of ``(name, priors)``, in the order of the flat parameter
    vector; ``seed`` is an int or a :class:`numpy.random.Generator`.
    """
    rng = np.random.default_rng(seed)
    priors = [pr for _, block in blocks for pr in block]
    return np.stack([pr.sample_unconstrained(rng, (n_chains,)) for pr in priors], axis=1)
