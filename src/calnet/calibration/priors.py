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

Three families cover the positive quantities, each in three flavours that share one law:

* on ``(0, inf)`` with the log bijection, for scales: :class:`HalfNormal`, :class:`Gamma`,
  :class:`LogNormal` (and :class:`InverseGamma`);
* on a variance ``v`` through a law on its sd ``s = sqrt(v)`` (log bijection
  ``u = log v``): :class:`HalfNormalSd`, :class:`LogNormalSd`, :class:`GammaSd`;
* truncated to the finite bounds ``[lower, upper]`` of a calibration parameter (scaled-logit
  bijection): :class:`TruncatedHalfNormal`, :class:`TruncatedGamma`,
  :class:`TruncatedLogNormal` (and :class:`TruncatedNormal` on the whole line).

:func:`parameter_prior` and :func:`scale_prior` build them from the spec's prior models.

Defaults (docs/method.md section 8): ``Beta(1.1, 1.1)`` scaled to the bounds of a
calibration parameter and ``LogNormal(0, 0.5)`` for discrepancy length scales (inputs
scaled to the unit cube), as in the reference study; half-normal priors on the noise and
discrepancy sds (:class:`HalfNormalSd`) in the output's units.

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
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import betaln, gammaln
from scipy import stats
from scipy.special import ndtr
from scipy.stats import truncnorm

from calnet.errors import CalibrationError

__all__ = [
    "Prior",
    "Beta",
    "Uniform",
    "Normal",
    "TruncatedNormal",
    "LogNormal",
    "InverseGamma",
    "HalfNormal",
    "Gamma",
    "HalfNormalSd",
    "LogNormalSd",
    "GammaSd",
    "TruncatedHalfNormal",
    "TruncatedGamma",
    "TruncatedLogNormal",
    "parameter_prior",
    "scale_prior",
    "stack_priors",
]

_LOG_2 = math.log(2.0)
_LOG_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)
_LOG_SQRT_2_OVER_PI = 0.5 * math.log(2.0 / math.pi)


def _check_bounds(name: str, lower: float, upper: float) -> None:
    if not (math.isfinite(lower) and math.isfinite(upper) and lower < upper):
        raise CalibrationError(
            f"{name} prior: expected finite lower < upper, got lower={lower}, upper={upper}; "
            "fix the parameter bounds"
        )


def _check_positive(name: str, **values: float) -> None:
    for key, value in values.items():
        if not (math.isfinite(value) and value > 0):
            raise CalibrationError(f"{name} prior: expected {key} > 0, got {value}; "
                                   "pass a positive finite number")


def _check_finite(name: str, **values: float) -> None:
    for key, value in values.items():
        if not math.isfinite(value):
            raise CalibrationError(f"{name} prior: expected a finite {key}, got {value}; "
                                   "pass a finite number")


def _as_floats(prior: Prior, *names: str) -> None:
    """Store the named fields of a frozen prior as Python floats (hashable, traceable)."""
    for name in names:
        object.__setattr__(prior, name, float(getattr(prior, name)))


def _check_mass(prior: _Bounded) -> None:
    """Raise when a truncated prior has no finite, positive mass inside its bounds."""
    if not np.isfinite(float(prior._log_mass())):
        raise CalibrationError(
            f"{type(prior).__name__} prior has no mass inside [lower, upper] = "
            f"[{prior.lower:g}, {prior.upper:g}]; move its location into the bounds, "
            "widen its spread or widen the bounds"
        )


def _xlog(c, log_x):
    """``c * log_x`` with the limit ``0 * log 0 = 0`` (``x^0 = 1`` at ``x = 0``)."""
    return jnp.where(c == 0, 0.0, c * log_x)


@dataclass(frozen=True)
class Prior:
    """Base class: a univariate prior and its bijection to the real line."""

    def __post_init__(self):
        """Validate the fields (subclasses chain through ``super().__post_init__()``)."""

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
        _check_finite("TruncatedNormal", mu=self.mu)
        _check_positive("TruncatedNormal", sigma=self.sigma)
        _check_mass(self)

    def _log_mass(self) -> float:
        # log(Phi(b) - Phi(a)) in NumPy (a constant of the traced density); in the upper
        # tail through the survival function to keep precision
        a = (np.asarray(self.lower) - self.mu) / self.sigma
        b = (np.asarray(self.upper) - self.mu) / self.sigma
        with np.errstate(divide="ignore"):
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
        _check_finite("Normal", mu=self.mu)
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

    def sample_unconstrained(self, rng, shape=()):
        # keep initial points finite where a draw under- or overflows (Gamma with a << 1)
        tiny, huge = np.finfo(float).tiny, np.finfo(float).max
        return np.log(np.clip(self.sample(rng, shape), tiny, huge))


@dataclass(frozen=True)
class InverseGamma(_Positive):
    """InverseGamma(a, b) with density ``b^a / Gamma(a) x^(-a-1) exp(-b / x)``.

    ``(2, s^2)`` on a variance in the output's units is the reference study's
    ``InverseGamma(2, 1)`` on outputs standardised by their sd ``s`` (method.md section 3).
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


# ------------------------------------------------------------------ laws on (0, inf)
# A law mixin holds the float fields of a distribution on (0, inf) and gives
#   _log_pdf(x, log_x): its JAX log-density at x > 0, with log x passed in so that a
#                       flavour can supply it without cancellation far in a tail;
#   _draw(rng, shape):  NumPy draws;
#   _scipy():           the frozen scipy.stats law (elementwise on stacked fields).
# Each flavour below combines a law with a bijection: _PositiveLaw, _VarianceFromSd and
# _TruncatedLaw. All fields are floats, so stack_priors stacks every flavour.


@dataclass(frozen=True)
class _HalfNormalLaw(Prior):
    """HalfNormal(sigma): ``|z| sigma`` with ``z ~ Normal(0, 1)``; ``sigma`` in x's units."""

    sigma: float = 1.0

    def __post_init__(self):
        _as_floats(self, "sigma")
        _check_positive(type(self).__name__, sigma=self.sigma)
        super().__post_init__()

    def _log_pdf(self, x, log_x):
        return _LOG_SQRT_2_OVER_PI - np.log(self.sigma) - 0.5 * (x / self.sigma) ** 2

    def _draw(self, rng, shape):
        return np.abs(rng.normal(0.0, self.sigma, shape))

    def _scipy(self):
        return stats.halfnorm(scale=self.sigma)


@dataclass(frozen=True)
class _GammaLaw(Prior):
    """Gamma(a, b), shape ``a`` and rate ``b`` (units 1/x): ``b^a x^(a-1) e^(-b x) / G(a)``."""

    a: float = 2.0
    b: float = 1.0

    def __post_init__(self):
        _as_floats(self, "a", "b")
        _check_positive(type(self).__name__, a=self.a, b=self.b)
        super().__post_init__()

    def _log_pdf(self, x, log_x):
        return (self.a * np.log(self.b) - gammaln(self.a) + _xlog(self.a - 1.0, log_x)
                - self.b * x)

    def _draw(self, rng, shape):
        return rng.gamma(self.a, 1.0 / self.b, shape)

    def _scipy(self):
        return stats.gamma(self.a, scale=1.0 / self.b)


@dataclass(frozen=True)
class _LogNormalLaw(Prior):
    """LogNormal(mu, sigma): ``log x ~ Normal(mu, sigma)`` (mu, sigma unitless, on log x)."""

    mu: float = 0.0
    sigma: float = 0.5

    def __post_init__(self):
        _as_floats(self, "mu", "sigma")
        _check_finite(type(self).__name__, mu=self.mu)
        _check_positive(type(self).__name__, sigma=self.sigma)
        super().__post_init__()

    def _log_pdf(self, x, log_x):
        s = (log_x - self.mu) / self.sigma
        lp = -0.5 * s**2 - _LOG_SQRT_2PI - np.log(self.sigma) - log_x
        return jnp.where(log_x > -jnp.inf, lp, -jnp.inf)  # density 0 at x = 0, not nan

    def _draw(self, rng, shape):
        return rng.lognormal(self.mu, self.sigma, shape)

    def _scipy(self):
        return stats.lognorm(s=self.sigma, scale=np.exp(self.mu))


# ------------------------------------------------------------------ flavours
@dataclass(frozen=True)
class _PositiveLaw(_Positive):
    """A law mixin's distribution on ``(0, inf)``, log bijection ``u = log x``."""

    def log_prob(self, x):
        x = jnp.asarray(x, dtype=float)
        safe = jnp.where(x > 0, x, 1.0)
        return jnp.where(x > 0, self._log_pdf(safe, jnp.log(safe)), -jnp.inf)

    def log_prob_unconstrained(self, u):
        u = jnp.asarray(u, dtype=float)
        return self._log_pdf(jnp.exp(u), u) + u

    def sample(self, rng, shape=()):
        return self._draw(np.random.default_rng(rng), shape)


@dataclass(frozen=True)
class _VarianceFromSd(_Positive):
    """A prior on a variance ``v`` set by the law mixin's distribution of its sd ``sqrt(v)``.

    The bijection is ``u = log v``; with ``s = sqrt(v)``,
    ``log p(v) = log p_s(s) - log 2 - log s`` and ``log p(u) = log p_s(e^(u/2)) + u/2 - log 2``.
    """

    def log_prob(self, x):
        x = jnp.asarray(x, dtype=float)
        safe = jnp.where(x > 0, x, 1.0)
        log_s = 0.5 * jnp.log(safe)
        lp = self._log_pdf(jnp.sqrt(safe), log_s) - log_s - _LOG_2
        return jnp.where(x > 0, lp, -jnp.inf)

    def log_prob_unconstrained(self, u):
        log_s = 0.5 * jnp.asarray(u, dtype=float)
        return self._log_pdf(jnp.exp(log_s), log_s) + log_s - _LOG_2

    def sample(self, rng, shape=()):
        """Variances ``s^2``, shape ``shape``, with ``s`` drawn from the sd's law."""
        return self._draw(np.random.default_rng(rng), shape) ** 2


@dataclass(frozen=True)
class _TruncatedLaw(_Bounded):
    """A law mixin's distribution restricted to ``[lower, upper]``, ``0 <= lower``.

    Scaled-logit bijection as :class:`_Bounded`; the normalising constant (the law's mass
    inside the bounds) is a NumPy constant of the float fields.
    """

    def __post_init__(self):
        super().__post_init__()
        if self.lower < 0:
            raise CalibrationError(
                f"{type(self).__name__} prior: its law lives on x >= 0 but lower="
                f"{self.lower:g}; raise the lower bound to 0 or more, or use a normal or "
                "uniform prior"
            )
        _check_mass(self)

    def _log_mass(self):
        """``log P(lower <= X <= upper)`` under the untruncated law (NumPy)."""
        law = self._scipy()
        cdf_lower = law.cdf(self.lower)
        mass = np.where(cdf_lower < 0.5, law.cdf(self.upper) - cdf_lower,
                        law.sf(self.lower) - law.sf(self.upper))  # upper tail: sf keeps digits
        with np.errstate(divide="ignore"):
            return np.log(mass)

    def _log_lower(self):
        with np.errstate(divide="ignore"):
            return np.log(self.lower)  # -inf at lower = 0

    def log_prob(self, x):
        x = jnp.asarray(x, dtype=float)
        inside = self._inside(x)
        safe = jnp.where(inside, x, self.upper)
        lp = self._log_pdf(safe, jnp.log(safe)) - self._log_mass()
        return jnp.where(inside, lp, -jnp.inf)

    def log_prob_unconstrained(self, u):
        # log x = log(lower + width * sigmoid(u)), finite at lower = 0 however negative u is
        u = jnp.asarray(u, dtype=float)
        log_z = jax.nn.log_sigmoid(u)
        log_x = jnp.logaddexp(self._log_lower(), np.log(self.width) + log_z)
        return (self._log_pdf(self.to_constrained(u), log_x) - self._log_mass()
                + np.log(self.width) + log_z + jax.nn.log_sigmoid(-u))

    def sample(self, rng, shape=()):
        """Inverse-CDF draws on ``[lower, upper]``, shape ``shape`` (sf in the upper tail)."""
        law = self._scipy()
        q = np.random.default_rng(rng).uniform(size=shape)
        cdf_lower = law.cdf(self.lower)
        if cdf_lower < 0.5:
            x = law.ppf(cdf_lower + q * (law.cdf(self.upper) - cdf_lower))
        else:
            sf_lower = law.sf(self.lower)
            x = law.isf(sf_lower - q * (sf_lower - law.sf(self.upper)))
        return np.clip(x, self.lower, self.upper)


# ------------------------------------------------------------------ positive scales
@dataclass(frozen=True)
class HalfNormal(_HalfNormalLaw, _PositiveLaw):
    """HalfNormal(sigma) on ``(0, inf)``: ``|z| sigma``, ``z ~ Normal(0, 1)``; log bijection.

    ``sigma`` is in the units of ``x``; the mean is ``sigma sqrt(2 / pi)``.
    """


@dataclass(frozen=True)
class Gamma(_GammaLaw, _PositiveLaw):
    """Gamma(a, b) on ``(0, inf)``, shape ``a``, rate ``b``; log bijection.

    Density ``b^a x^(a-1) exp(-b x) / Gamma(a)``; ``b`` is in the inverse units of ``x``
    (mean ``a / b``).
    """


@dataclass(frozen=True)
class LogNormal(_LogNormalLaw, _PositiveLaw):
    """LogNormal(mu, sigma): ``log x ~ Normal(mu, sigma)``; log bijection.

    The default ``sigma = 0.5`` (variance 1/4) is the reference prior of the discrepancy
    length scales on unit-cube inputs (method.md section 3).
    """


# ------------------------------------------------------------------ variances from an sd prior
@dataclass(frozen=True)
class HalfNormalSd(_HalfNormalLaw, _VarianceFromSd):
    """Prior on a variance ``v`` whose sd ``sqrt(v)`` is HalfNormal(sigma); ``u = log v``.

    ``sigma`` is in the units of the sd; :meth:`sample` returns variances.
    """


@dataclass(frozen=True)
class LogNormalSd(_LogNormalLaw, _VarianceFromSd):
    """Prior on a variance ``v`` whose sd ``sqrt(v)`` is LogNormal(mu, sigma); ``u = log v``.

    ``mu`` and ``sigma`` are the mean and sd of ``log sqrt(v)`` (so ``v`` is
    LogNormal(2 mu, 2 sigma)); :meth:`sample` returns variances.
    """


@dataclass(frozen=True)
class GammaSd(_GammaLaw, _VarianceFromSd):
    """Prior on a variance ``v`` whose sd ``sqrt(v)`` is Gamma(a, b) (rate b); ``u = log v``.

    ``b`` is in the inverse units of the sd; :meth:`sample` returns variances.
    """


# ------------------------------------------------------------------ bounded parameters
@dataclass(frozen=True)
class TruncatedHalfNormal(_HalfNormalLaw, _TruncatedLaw):
    """HalfNormal(sigma) on ``[0, inf)`` restricted to ``[lower, upper]``, ``0 <= lower``.

    ``sigma`` is in the parameter's units.
    """


@dataclass(frozen=True)
class TruncatedGamma(_GammaLaw, _TruncatedLaw):
    """Gamma(a, b) (shape a, rate b) restricted to ``[lower, upper]``, ``0 <= lower``.

    ``b`` is in the inverse of the parameter's units.
    """


@dataclass(frozen=True)
class TruncatedLogNormal(_LogNormalLaw, _TruncatedLaw):
    """LogNormal(mu, sigma) restricted to ``[lower, upper]``, ``0 <= lower``.

    ``mu`` and ``sigma`` are the mean and sd of the log of the parameter in its units.
    """


# ------------------------------------------------------------------ from the spec
def _truncated_normal(lower, upper, p):
    return TruncatedNormal(lower, upper, p.mu, p.sigma)


_PARAMETER_PRIORS = {
    "beta": lambda lower, upper, p: Beta(lower, upper, p.a, p.b),
    "uniform": lambda lower, upper, p: Uniform(lower, upper),
    "normal": _truncated_normal,
    "truncnormal": _truncated_normal,
    "lognormal": lambda lower, upper, p: TruncatedLogNormal(lower, upper, p.mu, p.sigma),
    "gamma": lambda lower, upper, p: TruncatedGamma(lower, upper, p.a, p.b),
    "halfnormal": lambda lower, upper, p: TruncatedHalfNormal(lower, upper, p.sigma),
}

_SCALE_PRIORS = {
    "halfnormal": lambda p: HalfNormalSd(p.sigma),
    "lognormal": lambda p: LogNormalSd(p.mu, p.sigma),
    "gamma": lambda p: GammaSd(p.a, p.b),
    "invgamma": lambda p: InverseGamma(p.a, p.b),
}


def parameter_prior(param) -> Prior:
    """The calnet prior of a spec :class:`~calnet.spec.Parameter`, on its bounds.

    Parameters
    ----------
    param : calnet.spec.Parameter
        ``lower``, ``upper`` (parameter units) and ``prior`` (a spec prior with ``dist``).

    Returns
    -------
    Prior
        ``beta``: :class:`Beta`; ``uniform``: :class:`Uniform`; ``normal`` and
        ``truncnormal``: :class:`TruncatedNormal`; ``lognormal``:
        :class:`TruncatedLogNormal`; ``gamma``: :class:`TruncatedGamma`; ``halfnormal``:
        :class:`TruncatedHalfNormal`; all truncated to ``[lower, upper]``.

    Raises
    ------
    CalibrationError
        For another ``dist``, or a prior without mass inside the bounds.
    """
    build = _PARAMETER_PRIORS.get(param.prior.dist)
    if build is None:
        raise CalibrationError(
            f"parameter {param.name!r}: prior dist {param.prior.dist!r} is not a parameter "
            f"prior; use one of {', '.join(_PARAMETER_PRIORS)}"
        )
    try:
        return build(param.lower, param.upper, param.prior)
    except CalibrationError as err:
        raise CalibrationError(f"parameter {param.name!r}: {err}") from None


def scale_prior(spec_prior) -> Prior:
    """The calnet prior of a variance from a spec scale prior (noise or discrepancy).

    Parameters
    ----------
    spec_prior : spec prior with ``dist``
        ``halfnormal``, ``lognormal`` or ``gamma``: a prior on the SD (the output's
        units); ``invgamma``: a prior on the variance itself.

    Returns
    -------
    Prior
        :class:`HalfNormalSd`, :class:`LogNormalSd`, :class:`GammaSd` or
        :class:`InverseGamma`: each a density of the variance, on ``(0, inf)``.

    Raises
    ------
    CalibrationError
        For another ``dist``.
    """
    build = _SCALE_PRIORS.get(spec_prior.dist)
    if build is None:
        raise CalibrationError(
            f"prior dist {spec_prior.dist!r} is not a prior on a scale; use halfnormal, "
            "lognormal or gamma (on the sd) or invgamma (on the variance)"
        )
    return build(spec_prior)




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
