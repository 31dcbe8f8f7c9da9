"""Prediction.log_density against the closed form: draws of a Gaussian posterior mean,
each with Gaussian noise, make a Gaussian predictive."""

from __future__ import annotations

import numpy as np
from scipy import stats

from calnet.predict import Prediction


def _prediction(draw_mean, draw_sd, log=False):
    n = draw_mean.shape[1]
    z = np.zeros(n)
    return Prediction("d", "m.y", ("m.x",), z[:, None], z, z, z, draw_mean=draw_mean,
                      draw_sd=draw_sd, log=log)


def test_the_log_density_is_the_mixtures_and_an_outliers_is_the_gaussians():
    rng = np.random.default_rng(0)
    post_sd, noise = 0.085, 0.1
    m = rng.normal(0.0, post_sd, (400, 1)) * np.ones((1, 3))
    pred = _prediction(m, np.full((400, 3), noise))
    exact_sd = np.hypot(post_sd, noise)
    y = np.array([0.0, 0.2, 2.0])  # 0, 1.5 and 15 predictive sds out
    lpd, mixture = pred.log_density(y)
    exact = stats.norm.logpdf(y, 0.0, exact_sd)
    assert mixture.tolist() == [True, True, False]
    np.testing.assert_allclose(lpd[:2], exact[:2], atol=0.06)  # 400 draws
    # the outlier: the 400 draws' mixture would say about -170; the moment-matched
    # Gaussian is within the Monte Carlo error of its variance
    naive = stats.norm.logpdf(2.0, m[:, 2], noise).max() - np.log(400)
    assert naive < exact[2] - 20 and abs(lpd[2] - exact[2]) < 2.5


def test_a_log_output_is_scored_on_the_log_scale():
    m = np.log(np.array([[2.0], [2.0]]))
    lpd, _ = _prediction(m, np.full((2, 1), 0.1), log=True).log_density(np.array([2.0]))
    assert lpd[0] == stats.norm.logpdf(0.0, 0.0, 0.1)


def test_the_pit_is_the_mixtures_distribution_function_far_into_its_tails():
    # three draws' Gaussians: the PIT is their mean distribution function, exactly, also
    # where no finite set of samples reaches (z = 9)
    m = np.array([[0.0, 1.0], [0.5, 1.0], [-0.2, 1.0]])
    sd = np.array([[1.0, 0.1], [2.0, 0.1], [0.5, 0.1]])
    y = np.array([0.3, 1.9])
    want = np.mean(stats.norm.cdf(y[None], m, sd), axis=0)
    np.testing.assert_allclose(_prediction(m, sd).pit(y), want, rtol=1e-12)
    low = _prediction(m, sd).pit(np.array([0.0, 0.1]))[1]
    assert low == stats.norm.cdf(-9.0)  # 9 sds below every draw's mean
    # a log output: the distribution function of ln y under the draws' Gaussians
    pit = _prediction(np.log([[2.0], [3.0]]), np.full((2, 1), 0.2), log=True).pit(
        np.array([2.5]))
    want = np.mean(stats.norm.cdf(np.log(2.5), np.log([2.0, 3.0]), 0.2))
    assert pit[0] == want
