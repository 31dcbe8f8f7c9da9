"""Priors: densities against scipy.stats, normalisation, bijections and their Jacobians."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import integrate, stats

from calnet.calibration.priors import (
    Beta,
    InverseGamma,
    LogNormal,
    Normal,
    TruncatedNormal,
    Uniform,
    stack_priors,
)
from calnet.errors import CalibrationError

jax.config.update("jax_enable_x64", True)

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
