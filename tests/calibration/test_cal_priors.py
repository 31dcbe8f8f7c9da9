"""Priors: densities against scipy.stats, normalisation, bijections and their Jacobians."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from pydantic import TypeAdapter, ValidationError
from scipy import integrate, stats

from calnet.calibration.priors import (
    Beta,
    Gamma,
    GammaSd,
    HalfNormal,
    HalfNormalSd,
    InverseGamma,
    LogNormal,
    LogNormalSd,
    Normal,
    TruncatedGamma,
    TruncatedHalfNormal,
    TruncatedLogNormal,
    TruncatedNormal,
    Uniform,
    parameter_prior,
    scale_prior,
    stack_priors,
)
from calnet.errors import CalibrationError
from calnet.spec.variables import (
    BetaPrior,
    GammaPrior,
    HalfNormalPrior,
    InverseGammaPrior,
    LogNormalPrior,
    NormalPrior,
    Parameter,
    ScalePrior,
    TruncNormalPrior,
)


class _Truncated:
    """SciPy reference: ``base`` restricted to ``[lower, upper]``, logpdf - log(mass)."""

    def __init__(self, base, lower, upper):
        self.base, self.lower, self.upper = base, lower, upper
        self.upper_tail = base.cdf(lower) > 0.5  # survival function keeps the digits there
        if self.upper_tail:
            self.mass = base.sf(lower) - base.sf(upper)
        else:
            self.mass = base.cdf(upper) - base.cdf(lower)

    def logpdf(self, x):
        return self.base.logpdf(x) - np.log(self.mass)

    def cdf(self, x):
        x = np.clip(x, self.lower, self.upper)
        if self.upper_tail:
            return (self.base.sf(self.lower) - self.base.sf(x)) / self.mass
        return (self.base.cdf(x) - self.base.cdf(self.lower)) / self.mass

    def ppf(self, q):
        if self.upper_tail:
            return self.base.isf(self.base.sf(self.lower) - q * self.mass)
        return self.base.ppf(self.base.cdf(self.lower) + q * self.mass)


class _Squared:
    """SciPy reference of ``v = s^2`` for ``s ~ base``: density ``f_s(sqrt v) / (2 sqrt v)``."""

    def __init__(self, base):
        self.base = base

    def logpdf(self, v):
        return self.base.logpdf(np.sqrt(v)) - np.log(2.0 * np.sqrt(v))

    def cdf(self, v):
        return self.base.cdf(np.sqrt(np.maximum(v, 0.0)))

    def ppf(self, q):
        return self.base.ppf(q) ** 2

PRIORS_AND_SCIPY = [
    (Beta(60.0, 100.0), stats.beta(1.1, 1.1, loc=60.0, scale=40.0)),
    (Beta(0.25, 0.4, a=2.0, b=5.0), stats.beta(2.0, 5.0, loc=0.25, scale=0.15)),
    (Uniform(-1.0, 3.0), stats.uniform(-1.0, 4.0)),
    (TruncatedNormal(0.0, 2.0, mu=0.5, sigma=0.7),
     stats.truncnorm((0.0 - 0.5) / 0.7, (2.0 - 0.5) / 0.7, loc=0.5, scale=0.7)),
    (TruncatedNormal(5.0, 6.0, mu=0.0, sigma=1.0),  # far upper tail: survival branch
     stats.truncnorm(5.0, 6.0)),
    (Normal(1.0, 3.0), stats.norm(1.0, 3.0)),
    (LogNormal(), stats.lognorm(s=0.5, scale=1.0)),
    (LogNormal(0.3, 1.2), stats.lognorm(s=1.2, scale=np.exp(0.3))),
    (InverseGamma(), stats.invgamma(2.0, scale=1.0)),
    (InverseGamma(3.0, 0.5), stats.invgamma(3.0, scale=0.5)),
    (HalfNormal(2.0), stats.halfnorm(scale=2.0)),
    (Gamma(3.0, 2.0), stats.gamma(3.0, scale=0.5)),
    (Gamma(0.6, 0.5), stats.gamma(0.6, scale=2.0)),  # a < 1: density infinite at 0
    (HalfNormalSd(1.5), _Squared(stats.halfnorm(scale=1.5))),
    (LogNormalSd(0.2, 0.4), _Squared(stats.lognorm(s=0.4, scale=np.exp(0.2)))),
    (GammaSd(2.0, 3.0), _Squared(stats.gamma(2.0, scale=1.0 / 3.0))),
    (TruncatedHalfNormal(0.0, 2.0, 1.5), _Truncated(stats.halfnorm(scale=1.5), 0.0, 2.0)),
    (TruncatedHalfNormal(0.5, 3.0, 0.4),  # lower above the median: survival branch
     _Truncated(stats.halfnorm(scale=0.4), 0.5, 3.0)),
    (TruncatedGamma(0.0, 4.0, 0.7, 1.0), _Truncated(stats.gamma(0.7), 0.0, 4.0)),
    (TruncatedGamma(2.0, 5.0, 3.0, 2.0), _Truncated(stats.gamma(3.0, scale=0.5), 2.0, 5.0)),
    (TruncatedGamma(30.0, 40.0, 2.0, 1.0), _Truncated(stats.gamma(2.0), 30.0, 40.0)),
    (TruncatedLogNormal(0.5, 3.0, 0.2, 0.5),
     _Truncated(stats.lognorm(s=0.5, scale=np.exp(0.2)), 0.5, 3.0)),
    (TruncatedLogNormal(0.0, 1.0, 0.0, 1.0), _Truncated(stats.lognorm(s=1.0), 0.0, 1.0)),
]
IDS = [type(p).__name__ + str(i) for i, (p, _) in enumerate(PRIORS_AND_SCIPY)]


@pytest.mark.parametrize("prior,ref", PRIORS_AND_SCIPY, ids=IDS)
def test_log_prob_matches_scipy(prior, ref):
    x = ref.ppf(np.linspace(0.02, 0.98, 9))
    np.testing.assert_allclose(prior.log_prob(jnp.asarray(x)), ref.logpdf(x), rtol=1e-10,
                               atol=1e-10)


@pytest.mark.parametrize("prior,ref", PRIORS_AND_SCIPY, ids=IDS)
def test_unconstrained_density_is_normalised_and_consistent(prior, ref):
    f = jax.jit(prior.log_prob_unconstrained)
    mass, err = integrate.quad(lambda u: float(jnp.exp(f(u))), -np.inf, np.inf, limit=200)
    assert mass == pytest.approx(1.0, abs=1e-6)
    u = jnp.linspace(-3.0, 3.0, 13)
    direct = prior.log_prob(prior.to_constrained(u)) + prior.log_abs_det_jacobian(u)
    np.testing.assert_allclose(prior.log_prob_unconstrained(u), direct, rtol=1e-10,
                               atol=1e-10)


@pytest.mark.parametrize("prior,ref", PRIORS_AND_SCIPY, ids=IDS)
def test_jacobian_matches_numerical_derivative(prior, ref):
    u = np.linspace(-2.5, 2.5, 11)
    h = 1e-5
    fd = (np.asarray(prior.to_constrained(u + h)) - np.asarray(prior.to_constrained(u - h))) / (
        2 * h)
    np.testing.assert_allclose(np.asarray(prior.log_abs_det_jacobian(u)), np.log(np.abs(fd)),
                               atol=1e-7)
    # the bijection is inverted by to_unconstrained and maps into the support
    x = prior.to_constrained(u)
    np.testing.assert_allclose(prior.to_unconstrained(x), u, atol=1e-8)
    lo, hi = prior.support
    assert np.all((np.asarray(x) > lo) & (np.asarray(x) < hi))


@pytest.mark.parametrize("prior,ref", PRIORS_AND_SCIPY, ids=IDS)
def test_samples_follow_the_prior(prior, ref):
    draws = np.asarray(prior.sample(0, (2000,)))
    # KS test at a fixed seed; p > 1e-3 is a loose, deterministic check
    assert stats.kstest(draws, ref.cdf).pvalue > 1e-3
    u = np.asarray(prior.sample_unconstrained(1, (500,)))
    assert np.all(np.isfinite(u))


def test_beta_is_stable_far_in_the_tails():
    prior = Beta(0.0, 1.0)
    lp = prior.log_prob_unconstrained(jnp.asarray([-800.0, 800.0]))
    assert np.all(np.isfinite(np.asarray(lp)))
    g = jax.grad(prior.log_prob_unconstrained)(50.0)
    assert np.isfinite(float(g))


def test_out_of_support_is_minus_inf():
    assert float(Beta(0.0, 1.0).log_prob(1.5)) == -np.inf
    assert float(InverseGamma().log_prob(-1.0)) == -np.inf
    assert float(LogNormal().log_prob(0.0)) == -np.inf


def test_stacked_priors_evaluate_like_single_ones():
    priors = [Beta(0, 1), Beta(2, 5, a=2, b=3), LogNormal(), LogNormal(0.1, 0.3),
              InverseGamma(), Normal(0, 2), InverseGamma(3, 2)]
    u = jnp.linspace(-1.5, 2.0, len(priors))
    runs = stack_priors(priors)
    assert [(a, b) for a, b, _ in runs] == [(0, 2), (2, 4), (4, 5), (5, 6), (6, 7)]
    lp = sum(float(jnp.sum(s.log_prob_unconstrained(u[a:b]))) for a, b, s in runs)
    ref = sum(float(p.log_prob_unconstrained(u[i])) for i, p in enumerate(priors))
    assert lp == pytest.approx(ref, rel=1e-12)


@pytest.mark.parametrize("make", [lambda: Beta(1.0, 0.0), lambda: Uniform(0.0, np.inf),
                                  lambda: Beta(0, 1, a=-1.0), lambda: LogNormal(0.0, 0.0),
                                  lambda: InverseGamma(0.0, 1.0),
                                  lambda: TruncatedNormal(0, 1, sigma=-1)])
def test_invalid_priors_raise(make):
    with pytest.raises(CalibrationError, match="prior"):
        make()


def test_priors_are_hashable_values():
    assert Beta(0, 1) == Beta(0.0, 1.0)
    assert hash(Beta(0, 1)) == hash(Beta(0.0, 1.0))
    assert Beta(0, 1) != Uniform(0, 1)


@pytest.mark.parametrize("prior,ref", PRIORS_AND_SCIPY, ids=IDS)
def test_every_prior_is_hashable(prior, ref):
    assert hash(prior) == hash(type(prior)(*[getattr(prior, k) for k in vars(prior)]))


def test_new_priors_are_distinct_values():
    assert HalfNormal(1.0) != HalfNormalSd(1.0)
    assert hash(TruncatedGamma(0, 1, 2, 3)) == hash(TruncatedGamma(0.0, 1.0, 2.0, 3.0))
    assert len({Gamma(2, 1), GammaSd(2, 1), Gamma(2.0, 1.0)}) == 2


@pytest.mark.parametrize("prior,sd_law", [
    (HalfNormalSd(0.7), stats.halfnorm(scale=0.7)),
    (LogNormalSd(-0.3, 0.8), stats.lognorm(s=0.8, scale=np.exp(-0.3))),
    (GammaSd(0.8, 2.5), stats.gamma(0.8, scale=1 / 2.5)),
])
def test_variance_from_sd_is_the_change_of_variables(prior, sd_law):
    u = np.linspace(-6.0, 3.0, 19)
    s = np.exp(u / 2)
    ref = sd_law.logpdf(s) + u / 2 - np.log(2.0)  # log p_s(e^(u/2)) + u/2 - log 2
    np.testing.assert_allclose(prior.log_prob_unconstrained(jnp.asarray(u)), ref, rtol=1e-10,
                               atol=1e-10)
    v = np.exp(u)
    np.testing.assert_allclose(prior.log_prob(jnp.asarray(v)),
                               np.log(sd_law.pdf(np.sqrt(v)) / (2 * np.sqrt(v))), rtol=1e-9)
    draws = np.asarray(prior.sample(3, (20000,)))  # variances: E[v] = E[s^2]
    assert draws.mean() == pytest.approx(sd_law.moment(2), rel=0.05)


def test_lognormal_sd_is_lognormal_on_the_variance():
    u = jnp.linspace(-4.0, 4.0, 9)
    np.testing.assert_allclose(LogNormalSd(0.3, 0.6).log_prob_unconstrained(u),
                               LogNormal(0.6, 1.2).log_prob_unconstrained(u), rtol=1e-12)


@pytest.mark.parametrize("prior", [HalfNormal(1.0), Gamma(0.5, 2.0), HalfNormalSd(0.5),
                                   LogNormalSd(), GammaSd(3.0, 1.0)], ids=repr)
def test_positive_priors_are_stable_in_the_tails(prior):
    u = jnp.asarray([-50.0, 50.0])
    lp = np.asarray(prior.log_prob_unconstrained(u))
    assert np.all(np.isfinite(lp))
    grads = [float(jax.grad(prior.log_prob_unconstrained)(v)) for v in (-50.0, 50.0)]
    assert np.all(np.isfinite(grads))
    assert not np.any(np.isnan(np.asarray(prior.log_prob_unconstrained(jnp.asarray(800.0)))))


@pytest.mark.parametrize("prior", [TruncatedHalfNormal(0.0, 2.0, 1.0),
                                   TruncatedGamma(0.0, 3.0, 0.5, 1.0),
                                   TruncatedGamma(1.0, 3.0, 4.0, 1.0),
                                   TruncatedLogNormal(0.0, 2.0, 0.0, 1.0)], ids=repr)
def test_truncated_priors_are_stable_in_the_tails(prior):
    lp = np.asarray(prior.log_prob_unconstrained(jnp.asarray([-800.0, 800.0])))
    assert np.all(np.isfinite(lp))
    for v in (-800.0, 800.0):
        assert np.isfinite(float(jax.grad(prior.log_prob_unconstrained)(v)))


def test_truncated_log_prob_at_a_zero_lower_bound_is_the_limit():
    assert float(TruncatedLogNormal(0.0, 1.0).log_prob(0.0)) == -np.inf
    assert float(TruncatedGamma(0.0, 1.0, 0.5, 1.0).log_prob(0.0)) == np.inf
    ref = _Truncated(stats.gamma(1.0, scale=0.5), 0.0, 1.0).logpdf(0.0)
    assert float(TruncatedGamma(0.0, 1.0, 1.0, 2.0).log_prob(0.0)) == pytest.approx(ref)
    ref = _Truncated(stats.halfnorm(scale=0.5), 0.0, 1.0).logpdf(0.0)
    assert float(TruncatedHalfNormal(0.0, 1.0, 0.5).log_prob(0.0)) == pytest.approx(ref)


def test_new_priors_are_minus_inf_out_of_support():
    assert float(HalfNormal(1.0).log_prob(-1.0)) == -np.inf
    assert float(Gamma(2.0, 1.0).log_prob(0.0)) == -np.inf
    assert float(HalfNormalSd(1.0).log_prob(0.0)) == -np.inf
    assert float(TruncatedGamma(1.0, 2.0).log_prob(0.5)) == -np.inf
    assert float(TruncatedLogNormal(1.0, 2.0).log_prob(-0.5)) == -np.inf
    assert float(TruncatedHalfNormal(0.0, 2.0, 1.0).log_prob(2.5)) == -np.inf


def test_gamma_draws_stay_finite_on_the_unconstrained_scale():
    u = Gamma(0.01, 1.0).sample_unconstrained(0, (5000,))  # many draws underflow to 0
    assert np.all(np.isfinite(u))


def test_stacked_mixed_priors_evaluate_like_single_ones():
    priors = [HalfNormal(1.0), HalfNormal(0.3), Gamma(2, 1), Gamma(0.7, 3), HalfNormalSd(1),
              LogNormalSd(0.1, 0.2), LogNormalSd(), GammaSd(2, 2), GammaSd(0.5, 1),
              TruncatedHalfNormal(0, 2, 1), TruncatedHalfNormal(0.5, 3, 0.4),
              TruncatedGamma(0, 4, 0.7, 1), TruncatedGamma(30, 40, 2, 1),
              TruncatedLogNormal(0, 1, 0, 1), TruncatedLogNormal(0.5, 3, 0.2, 0.5),
              TruncatedNormal(-1, 1, 0, 2), Beta(0, 1), InverseGamma()]
    u = jnp.linspace(-2.0, 2.5, len(priors))
    runs = stack_priors(priors)
    assert [(a, b) for a, b, _ in runs] == [(0, 2), (2, 4), (4, 5), (5, 7), (7, 9), (9, 11),
                                            (11, 13), (13, 15), (15, 16), (16, 17), (17, 18)]
    for fn in ("log_prob_unconstrained", "to_constrained", "log_abs_det_jacobian"):
        stacked = np.concatenate([np.atleast_1d(getattr(s, fn)(u[a:b])) for a, b, s in runs])
        single = np.array([float(getattr(p, fn)(u[i])) for i, p in enumerate(priors)])
        np.testing.assert_allclose(stacked, single, rtol=1e-12, atol=1e-12)
    x = np.array([float(p.to_constrained(u[i])) for i, p in enumerate(priors)])
    stacked = np.concatenate([np.atleast_1d(s.log_prob(x[a:b])) for a, b, s in runs])
    single = np.array([float(p.log_prob(x[i])) for i, p in enumerate(priors)])
    np.testing.assert_allclose(stacked, single, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("make,match", [
    (lambda: HalfNormal(0.0), "sigma > 0"),
    (lambda: Gamma(1.0, -1.0), "b > 0"),
    (lambda: GammaSd(0.0, 1.0), "a > 0"),
    (lambda: LogNormalSd(np.nan, 1.0), "finite mu"),
    (lambda: Normal(np.inf, 1.0), "finite mu"),
    (lambda: TruncatedHalfNormal(-1.0, 1.0, 1.0), "lower bound to 0"),
    (lambda: TruncatedLogNormal(-1.0, 1.0), "lower bound to 0"),
    (lambda: TruncatedGamma(1000.0, 1001.0, 2.0, 1.0), "no mass inside"),
    (lambda: TruncatedLogNormal(1e300, 1.1e300, 0.0, 0.1), "no mass inside"),
    (lambda: TruncatedNormal(1000.0, 1001.0, 0.0, 1.0), "no mass inside"),
])
def test_invalid_new_priors_raise(make, match):
    with pytest.raises(CalibrationError, match=match):
        make()


def _param(prior, lower=0.5, upper=3.0):
    return Parameter(name="k", lower=lower, upper=upper, prior=prior)


@pytest.mark.parametrize("spec,expected", [
    ({}, Beta(0.5, 3.0, 1.1, 1.1)),
    ({"dist": "beta", "a": 2, "b": 3}, Beta(0.5, 3.0, 2.0, 3.0)),
    ({"dist": "uniform"}, Uniform(0.5, 3.0)),
    ({"dist": "normal", "mu": 1, "sigma": 2}, TruncatedNormal(0.5, 3.0, 1.0, 2.0)),
    ({"dist": "truncnormal", "mu": 1, "sigma": 2}, TruncatedNormal(0.5, 3.0, 1.0, 2.0)),
    ({"dist": "lognormal", "mu": 0.2, "sigma": 0.5}, TruncatedLogNormal(0.5, 3.0, 0.2, 0.5)),
    ({"dist": "gamma", "a": 2, "b": "1.5"}, TruncatedGamma(0.5, 3.0, 2.0, 1.5)),
    ({"dist": "halfnormal", "sigma": 1.0}, TruncatedHalfNormal(0.5, 3.0, 1.0)),
], ids=lambda v: v.get("dist", "default") if isinstance(v, dict) else "")
def test_parameter_prior_maps_every_dist(spec, expected):
    prior = parameter_prior(_param(spec) if spec else Parameter(name="k", lower=0.5, upper=3.0))
    assert prior == expected and type(prior) is type(expected)


def test_parameter_prior_errors_name_the_parameter():
    with pytest.raises(CalibrationError, match="parameter 'k'.*lower bound to 0"):
        parameter_prior(_param({"dist": "halfnormal", "sigma": 1.0}, lower=-1.0))
    with pytest.raises(CalibrationError, match="parameter 'k'.*no mass inside"):
        parameter_prior(_param({"dist": "gamma", "a": 2, "b": 1}, lower=1e3, upper=1e3 + 1))


@pytest.mark.parametrize("spec,expected", [
    (HalfNormalPrior(sigma=0.5), HalfNormalSd(0.5)),
    (LogNormalPrior(), LogNormalSd(0.0, 0.5)),
    (GammaPrior(a=2, b=4), GammaSd(2.0, 4.0)),
    (InverseGammaPrior(), InverseGamma(2.0, 1.0)),
], ids=lambda v: getattr(v, "dist", ""))
def test_scale_prior_maps_every_dist(spec, expected):
    prior = scale_prior(spec)
    assert prior == expected and type(prior) is type(expected)


def test_scale_prior_rejects_a_parameter_prior():
    with pytest.raises(CalibrationError, match="not a prior on a scale"):
        scale_prior(BetaPrior())


def test_scale_prior_spec_is_discriminated_by_dist():
    adapter = TypeAdapter(ScalePrior)
    assert adapter.validate_python({"dist": "gamma", "a": 2, "b": 1}) == GammaPrior(a=2, b=1)
    with pytest.raises(ValidationError):
        adapter.validate_python({"dist": "beta"})


@pytest.mark.parametrize("model,field", [
    (BetaPrior, "a"), (NormalPrior, "mu"), (NormalPrior, "sigma"), (TruncNormalPrior, "mu"),
    (LogNormalPrior, "mu"), (LogNormalPrior, "sigma"), (GammaPrior, "a"), (GammaPrior, "b"),
    (HalfNormalPrior, "sigma"), (InverseGammaPrior, "b"),
])
@pytest.mark.parametrize("bad,match", [(float("nan"), "must be a finite number, got nan"),
                                       (float("inf"), "must be a finite number, got inf"),
                                       ("-inf", "must be a finite number"),
                                       (True, "must be a number, got true")])
def test_spec_priors_reject_non_finite_and_boolean_numbers(model, field, bad, match):
    good = {"a": 2.0, "b": 1.0, "mu": 0.5, "sigma": 1.0}
    kwargs = {k: v for k, v in good.items() if k in model.model_fields}
    kwargs[field] = bad
    with pytest.raises(ValidationError, match=f"{field} {match}"):
        model(**kwargs)


def test_spec_priors_accept_numbers_written_as_yaml_strings():
    assert GammaPrior(a="2", b="1e-3").b == pytest.approx(1e-3)  # PyYAML reads 1e-3 as text
    assert Parameter(name="k", lower=0, upper=1, prior={"dist": "halfnormal", "sigma": 1}
                     ).prior == HalfNormalPrior(sigma=1.0)
