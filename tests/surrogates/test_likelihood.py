"""Analytic oracles for the kernel and the log marginal likelihood."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from calnet.surrogates import matern32, neg_log_marginal_likelihood, nlml_value_and_grad


def _data(n=30, d=3, seed=0):
    rng = np.random.default_rng(seed)
    x = rng.random((n, d))
    y = np.sin(4 * x[:, 0]) + x[:, 1] ** 2 - 0.5 * x[:, 2]
    return x, (y - y.mean()) / y.std()


LOG_PARAMS = np.log([0.3, 0.8, 2.0, 1.7, 1e-3])  # [ell (3), s2, nugget]


def _dense_nlml(log_params, x, y):
    """Textbook formula with NumPy: 0.5 y'K^-1y + 0.5 log det K + n/2 log 2 pi."""
    p = np.exp(log_params)
    ell, s2, nug = p[:-2], p[-2], p[-1]
    r = np.sqrt((((x[:, None, :] - x[None, :, :]) / ell) ** 2).sum(-1))
    k = s2 * (1 + np.sqrt(3) * r) * np.exp(-np.sqrt(3) * r) + nug * np.eye(len(x))
    sign, logdet = np.linalg.slogdet(k)
    assert sign > 0
    return 0.5 * y @ np.linalg.solve(k, y) + 0.5 * logdet + 0.5 * len(x) * np.log(2 * np.pi)


def test_kernel_matches_closed_form_and_is_l2():
    a = jnp.array([[0.0, 0.0]])
    b = jnp.array([[0.3, 0.4]])  # L2 distance 0.5 (L1 would be 0.7)
    r = 0.5 / 0.25
    expected = 2.0 * (1 + np.sqrt(3) * r) * np.exp(-np.sqrt(3) * r)
    assert float(matern32(a, b, jnp.array([0.25, 0.25]), 2.0)[0, 0]) == pytest.approx(expected)


def test_kernel_gradient_finite_at_zero_distance():
    x = jnp.array([[0.2, 0.7]])
    g = jax.grad(lambda z: matern32(z, x, jnp.array([0.3, 0.5]), 1.0).sum())(x)
    assert np.all(np.isfinite(np.asarray(g))) and np.allclose(g, 0.0)


def test_nlml_matches_dense_numpy_formula():
    x, y = _data()
    got = float(jax.jit(neg_log_marginal_likelihood)(jnp.asarray(LOG_PARAMS), x, y))
    assert got == pytest.approx(_dense_nlml(LOG_PARAMS, x, y), rel=1e-10)


def test_closed_form_gradient_matches_finite_differences_and_autodiff():
    x, y = _data()
    p = jnp.asarray(LOG_PARAMS)
    value, grad = jax.jit(nlml_value_and_grad)(p, x, y)
    assert float(value) == pytest.approx(_dense_nlml(LOG_PARAMS, x, y), rel=1e-10)
    h = 1e-6  # central differences: truncation O(h^2) ~ 1e-12, rounding ~ 1e-16 * f / h
    fd = np.array([(_dense_nlml(LOG_PARAMS + h * e, x, y) - _dense_nlml(LOG_PARAMS - h * e, x, y))
                   / (2 * h) for e in np.eye(len(LOG_PARAMS))])
    np.testing.assert_allclose(np.asarray(grad), fd, rtol=1e-6, atol=1e-7)
    autodiff = jax.jit(jax.grad(neg_log_marginal_likelihood))(p, x, y)
    np.testing.assert_allclose(np.asarray(grad), np.asarray(autodiff), rtol=1e-9, atol=1e-10)


def test_nlml_is_inf_not_nan_when_k_is_singular():
    x, y = _data(n=10)
    x = np.vstack([x, x])
    y = np.concatenate([y, y + 1.0])
    p = jnp.asarray(np.log([0.3, 0.8, 2.0, 1.0, 1e-300]))
    value, grad = jax.jit(nlml_value_and_grad)(p, x, y)
    assert float(value) == np.inf and np.all(np.asarray(grad) == 0.0)


def test_same_log_marginal_likelihood_as_scikit_learn():
    from sklearn.gaussian_process import GaussianProcessRegressor
    from sklearn.gaussian_process.kernels import ConstantKernel, Matern, WhiteKernel

    rng = np.random.default_rng(3)
    x = rng.random((40, 3))
    y_raw = 5.0 + 2.0 * np.cos(3 * x[:, 0]) * x[:, 1] + x[:, 2]
    kernel = (ConstantKernel(1.0) * Matern(np.ones(3), nu=1.5) + WhiteKernel(1e-3))
    sk = GaussianProcessRegressor(kernel, normalize_y=True, optimizer=None, alpha=0.0)
    sk.fit(x, y_raw)
    ell, s2, nug = np.array([0.4, 1.3, 0.7]), 1.9, 2e-4
    sk_theta = np.log(np.r_[s2, ell, nug])  # sklearn's order: constant, length scales, noise
    ys = (y_raw - y_raw.mean()) / y_raw.std()
    ours = -float(neg_log_marginal_likelihood(jnp.log(jnp.r_[ell, s2, nug]), x, ys))
    assert ours == pytest.approx(sk.log_marginal_likelihood(sk_theta), rel=1e-6)


@pytest.mark.parametrize("mean", ["constant", "linear"])
def test_masked_likelihood_is_the_kept_points_likelihood(mean):
    # the mask decouples points in arrays of the full shape: the value and the gradient
    # must be those of the kept points' own arrays (what a cross-validation fold fits)
    from calnet.surrogates.likelihood import basis

    x, y = _data(n=30)
    keep = np.ones(30, bool)
    keep[[2, 7, 8, 19, 29]] = False
    p = jnp.asarray(LOG_PARAMS)
    H = None if mean == "constant" else basis(jnp.asarray(x), mean)
    want = jax.jit(nlml_value_and_grad)(p, x[keep], y[keep],
                                        None if H is None else H[keep])
    mask = keep.astype(float)
    got = jax.jit(nlml_value_and_grad)(p, x, np.where(keep, y, 0.0),
                                       None if H is None else H * mask[:, None], mask)
    assert float(got[0]) == pytest.approx(float(want[0]), rel=1e-10)
    np.testing.assert_allclose(np.asarray(got[1]), np.asarray(want[1]), rtol=1e-8, atol=1e-10)
    if mean == "constant":  # and the textbook formula on the kept points
        assert float(got[0]) == pytest.approx(_dense_nlml(LOG_PARAMS, x[keep], y[keep]),
                                              rel=1e-10)
