"""The GP's mean function: a linear trend by generalised least squares, its coefficients'
uncertainty in the predictive (universal kriging), the restricted likelihood, and
``mean="auto"``; checked against dense NumPy formulas written out here, brute-force
leave-one-out refits and functions with known structure."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from calnet.errors import SurrogateError
from calnet.surrogates import condition, fit_gp, load_gp, save_gp
from calnet.surrogates.fit import loo_log_density
from calnet.surrogates.likelihood import (
    basis,
    neg_log_marginal_likelihood,
    nlml_value_and_grad,
)

LOWER = np.array([0.0, 1.0, -2.0])
UPPER = np.array([1.0, 3.0, 2.0])
ELL, S2, NUG = np.array([0.4, 0.7, 1.5]), 1.7, 1e-4


def _data(n, seed, f):
    u = np.random.default_rng(seed).random((n, 3))
    x = LOWER + u * (UPPER - LOWER)
    return x, u, f(x)


def _smooth(x):
    return 2.0 + 3.0 * x[:, 0] - x[:, 1] + 0.5 * x[:, 2] + 0.4 * np.sin(2.0 * x[:, 0])


def _linear(x):
    return 2.0 + 3.0 * x[:, 0] - x[:, 1] + 0.5 * x[:, 2]


def _wiggly(x):
    return np.sin(6.0 * x[:, 0]) + np.cos(3.0 * x[:, 1])


def _k(a, b):
    """Matern 3/2 on unit-cube inputs, written out."""
    r = np.sqrt(3.0 * (((a[:, None] - b[None]) / ELL) ** 2).sum(-1))
    return S2 * (1.0 + r) * np.exp(-r)


def _h(u, quadratic=False):
    """The basis written out: ``[1, u]``, and the centred products ``(u_i - 1/2)(u_j - 1/2)``,
    ``i <= j``, for a quadratic trend; (p, n), the book's ``H``."""
    cols = [np.ones(len(u)), *u.T]
    if quadratic:
        d = u.shape[1]
        cols += [(u[:, i] - 0.5) * (u[:, j] - 0.5) for i in range(d) for j in range(i, d)]
    return np.array(cols)


def _universal_kriging(u, ys, ut, quadratic=False):
    """Rasmussen and Williams (2006) eqs. 2.41-2.42 in dense NumPy: mean and latent
    variance at ``ut`` with a flat prior on the coefficients of the basis ``h``."""
    K = _k(u, u) + NUG * np.eye(len(u))
    Ki = np.linalg.inv(K)
    H, Hs = _h(u, quadratic), _h(ut, quadratic)
    A = H @ Ki @ H.T
    beta = np.linalg.solve(A, H @ Ki @ ys)
    Ks = _k(u, ut)
    R = Hs - H @ Ki @ Ks
    mean = Ks.T @ Ki @ ys + R.T @ beta
    cov = _k(ut, ut) - Ks.T @ Ki @ Ks + R.T @ np.linalg.solve(A, R)
    return mean, cov, beta


def test_restricted_likelihood_matches_the_dense_formula_and_its_gradient():
    x, u, y = _data(25, 0, _smooth)
    ys = (y - y.mean()) / y.std()
    lp = jnp.log(jnp.r_[ELL, S2, NUG])
    xs, yj = jnp.asarray(u), jnp.asarray(ys)
    H = basis(xs, "linear")
    K = _k(u, u) + NUG * np.eye(len(u))
    Ki = np.linalg.inv(K)
    Hn = np.asarray(H)
    A = Hn.T @ Ki @ Hn
    P = Ki - Ki @ Hn @ np.linalg.solve(A, Hn.T @ Ki)
    n, p = Hn.shape
    dense = (0.5 * ys @ P @ ys + 0.5 * np.linalg.slogdet(K)[1] + 0.5 * np.linalg.slogdet(A)[1]
             + 0.5 * (n - p) * np.log(2 * np.pi))
    value, grad = nlml_value_and_grad(lp, xs, yj, H)
    assert float(value) == pytest.approx(dense, rel=1e-10)
    assert float(neg_log_marginal_likelihood(lp, xs, yj, H)) == pytest.approx(dense, rel=1e-10)
    auto = jax.grad(neg_log_marginal_likelihood)(lp, xs, yj, H)
    np.testing.assert_allclose(grad, auto, rtol=1e-7, atol=1e-9)
    # no basis column: the plain marginal likelihood
    v0, _ = nlml_value_and_grad(lp, xs, yj, basis(xs, "constant"))
    assert float(v0) == pytest.approx(float(neg_log_marginal_likelihood(lp, xs, yj)), rel=1e-14)


@pytest.mark.parametrize("mean, n, seeds, p, rtol_beta, rtol_cov", [
    ("linear", 30, (1, 2), 4, 1e-8, 1e-7),
    ("quadratic", 40, (11, 12), 10, 1e-7, 1e-6),
])
def test_trend_predictive_is_universal_kriging(mean, n, seeds, p, rtol_beta, rtol_cov):
    x, u, y = _data(n, seeds[0], _smooth)
    gp = condition(x, y, lower=LOWER, upper=UPPER, lengthscales=ELL, signal_var=S2,
                   nugget=NUG, mean=mean)
    assert gp.mean == mean and gp.beta.shape == (p,)
    xt, ut, _ = _data(7, seeds[1], _smooth)
    m_ref, c_ref, beta_ref = _universal_kriging(u, (y - y.mean()) / y.std(), ut,
                                                mean == "quadratic")
    np.testing.assert_allclose(gp.beta, beta_ref, rtol=rtol_beta)
    sd = float(gp.y_std)
    mean_p, var = gp.predict(xt)
    np.testing.assert_allclose(mean_p, float(gp.y_mean) + sd * m_ref, rtol=1e-9)
    np.testing.assert_allclose(var, sd**2 * np.diag(c_ref), rtol=rtol_cov)
    mean_c, cov = gp.predict_cov(xt)
    np.testing.assert_allclose(mean_c, mean_p, rtol=1e-12)
    np.testing.assert_allclose(cov, sd**2 * c_ref, rtol=rtol_cov, atol=1e-12)
    # the coefficients' uncertainty is part of it: the plain GP formula gives less
    plain = np.diag(_k(ut, ut) - _k(u, ut).T @ np.linalg.solve(_k(u, u) + NUG * np.eye(n),
                                                                _k(u, ut)))
    assert np.all(np.asarray(var) > sd**2 * plain)


def test_an_interaction_of_input_and_parameter_gets_the_quadratic_trend():
    """``w = 1 + a x + 0.2 x^2`` (a parameter that scales a control input): no linear
    trend fits it, the quadratic one does exactly, and ``auto`` finds it."""
    lo, hi = np.zeros(2), np.ones(2)
    rng = np.random.default_rng(13)
    x, xt = rng.random((30, 2)), rng.random((500, 2))

    def w(z):
        return 1.0 + z[:, 1] * z[:, 0] + 0.2 * z[:, 0] ** 2

    gp = fit_gp(x, w(x), lower=lo, upper=hi, n_restarts=2, mean="auto")
    assert gp.mean == "quadratic"
    err = np.asarray(gp.predict(xt)[0]) - w(xt)
    assert np.max(np.abs(err)) < 1e-8


def test_split_predictions_agree_with_predict_for_a_linear_mean():
    """The fast paths at fixed control inputs (first input a control, two parameters)."""
    x, _, y = _data(30, 3, _smooth)
    gp = condition(x, y, lower=LOWER, upper=UPPER, lengthscales=ELL, signal_var=S2,
                   nugget=NUG, mean="linear")
    xc = x[:5, :1]
    theta = jnp.asarray([2.2, -0.7])
    full = jnp.concatenate([jnp.asarray(xc), jnp.broadcast_to(theta, (5, 2))], axis=1)
    mean, var = gp.predict(full)
    mean_c, cov = gp.predict_cov(full)
    np.testing.assert_allclose(gp.mean_fn_at(xc)(theta), mean, rtol=1e-12)
    np.testing.assert_allclose(gp.var_fn_at(xc)(theta), var, rtol=1e-9)
    m_at, c_at = gp.moments_at(gp.at_controls(jnp.asarray(xc)), theta, cov=True)
    np.testing.assert_allclose(m_at, mean, rtol=1e-12)
    np.testing.assert_allclose(c_at, cov, rtol=1e-8, atol=1e-12)
    g_fast = jax.grad(lambda t: jnp.sum(gp.mean_fn_at(xc)(t)))(theta)
    g_full = jax.grad(lambda t: jnp.sum(gp.predict_split(xc, t)[0]))(theta)
    np.testing.assert_allclose(g_fast, g_full, rtol=1e-9)


def test_loo_log_density_matches_refits_without_each_point():
    x, u, y = _data(20, 4, _smooth)
    for mean in ("constant", "linear"):
        gp = condition(x, y, lower=LOWER, upper=UPPER, lengthscales=ELL, signal_var=S2,
                       nugget=NUG, mean=mean)
        ys = (y - float(gp.y_mean)) / float(gp.y_std)
        total = 0.0
        for i in range(len(y)):
            keep = np.arange(len(y)) != i
            if mean == "constant":  # the standardisation of all points, zero mean
                K = _k(u[keep], u[keep]) + NUG * np.eye(19)
                ks = _k(u[keep], u[i:i + 1])[:, 0]
                mu = ks @ np.linalg.solve(K, ys[keep])
                var = S2 - ks @ np.linalg.solve(K, ks)
            else:  # coefficients re-estimated without the point
                mu, cov, _ = _universal_kriging(u[keep], ys[keep], u[i:i + 1])
                mu, var = mu[0], cov[0, 0]
            var += NUG  # the density of an observation
            total += -0.5 * np.log(2 * np.pi * var) - 0.5 * (ys[i] - mu) ** 2 / var
        assert loo_log_density(gp) == pytest.approx(total, rel=1e-7)


def test_a_linear_output_gets_an_exact_mean_and_a_small_honest_variance():
    x, _, y = _data(30, 5, _linear)
    xt, _, yt = _data(200, 6, _linear)
    const = fit_gp(x, y, lower=LOWER, upper=UPPER, n_restarts=2, mean="constant")
    lin = fit_gp(x, y, lower=LOWER, upper=UPPER, n_restarts=2, mean="linear")
    err_c = np.asarray(const.predict(xt)[0]) - yt
    err_l = np.asarray(lin.predict(xt)[0]) - yt
    sd_c, sd_l = (float(np.sqrt(np.mean(g.predict(xt)[1]))) for g in (const, lin))
    assert np.max(np.abs(err_l)) < 1e-8 * np.ptp(y)
    # the stationary kernel carries the trend as a huge signal variance: its sd is about
    # ten times its own error; the trend's sd is orders of magnitude below it
    assert sd_c > 3 * float(np.sqrt(np.mean(err_c**2)))
    assert sd_l < 0.05 * sd_c
    auto = fit_gp(x, y, lower=LOWER, upper=UPPER, n_restarts=2, mean="auto")
    assert auto.mean == "linear"


def test_auto_keeps_the_mean_of_highest_loo_density():
    x, _, y = _data(60, 7, _wiggly)  # 60 runs: 5 per coefficient of every mean in 3 inputs
    gps = {m: fit_gp(x, y, lower=LOWER, upper=UPPER, n_restarts=2, mean=m)
           for m in ("constant", "linear", "quadratic", "auto")}
    scores = {m: loo_log_density(gps[m]) for m in ("constant", "linear", "quadratic")}
    best = max(scores, key=scores.get)
    assert gps["auto"].mean == best
    np.testing.assert_allclose(gps["auto"].predict(x[:3])[0], gps[best].predict(x[:3])[0])


def test_auto_tries_a_trend_only_with_five_runs_per_coefficient():
    """18 runs in 5 inputs: a linear trend has 6 coefficients, 3 runs each; auto keeps
    the constant mean whatever the leave-one-out density says."""
    u = np.random.default_rng(14).random((18, 5))
    y = 1.0 + u @ np.arange(1.0, 6.0)  # linear: the trend would win on density
    lo, hi = np.zeros(5), np.ones(5)
    assert fit_gp(u, y, lower=lo, upper=hi, n_restarts=1, mean="auto").mean == "constant"
    assert fit_gp(u[:12, :2], y[:12], lower=lo[:2], upper=hi[:2], n_restarts=1,
                  mean="auto").mean == "constant"  # 12 runs, 3 coefficients: 4 each
    assert fit_gp(u[:15, :2], u[:15, :2] @ [1.0, 2.0], lower=lo[:2], upper=hi[:2],
                  n_restarts=1, mean="auto").mean == "linear"  # 15 runs: 5 each


def test_mean_function_errors_and_too_few_points_for_a_trend():
    x, _, y = _data(6, 8, _linear)
    with pytest.raises(SurrogateError, match="mean must be one of"):
        fit_gp(x, y, lower=LOWER, upper=UPPER, mean="cubic")
    with pytest.raises(SurrogateError, match="a linear mean in 3 inputs has 4 coefficients "
                       "and needs at least 6 runs, got 5; run more simulations, or set the "
                       "model's surrogate: {mean: auto} or {mean: constant}"):
        fit_gp(x[:5], y[:5], lower=LOWER, upper=UPPER, mean="linear")
    assert fit_gp(x[:5], y[:5], lower=LOWER, upper=UPPER, mean="auto",
                  n_restarts=1).mean == "constant"


def test_a_linear_mean_survives_save_and_load_and_old_files_load(tmp_path):
    x, _, y = _data(30, 9, _smooth)
    gp = condition(x, y, lower=LOWER, upper=UPPER, lengthscales=ELL, signal_var=S2,
                   nugget=NUG, mean="linear")
    back = load_gp(save_gp(gp, tmp_path / "g.npz"))
    assert back.mean == "linear"
    np.testing.assert_array_equal(back.predict(x[:4])[1], gp.predict(x[:4])[1])
    # a file of format version 1 (no mean-function arrays) is a constant-mean GP
    const = condition(x, y, lower=LOWER, upper=UPPER, lengthscales=ELL, signal_var=S2,
                      nugget=NUG)
    path = save_gp(const, tmp_path / "old.npz")
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files if k not in ("beta", "basis_solve",
                                                              "basis_chol")}
    np.savez(path, **arrays)
    side = path.with_suffix(".json")
    side.write_text(side.read_text().replace('"version": 2', '"version": 1'))
    old = load_gp(path)
    assert old.mean == "constant"
    np.testing.assert_array_equal(old.predict(x[:4])[0], const.predict(x[:4])[0])
    # a trend whose coefficients match no mean function: one line, not a traceback
    bad = save_gp(gp, tmp_path / "bad.npz")
    with np.load(bad) as data:
        arrays = {k: data[k] for k in data.files}
    np.savez(bad, **{**arrays, "beta": arrays["beta"][:3]})
    with pytest.raises(SurrogateError, match="array shapes do not match"):
        load_gp(bad)
