"""FittedGP: interpolation, split predictions, transforms, pytree use, recovery, io."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from calnet.surrogates import FittedGP, condition, fit_gp, load_gp, save_gp
from calnet.surrogates.gp import ARRAY_FIELDS
from calnet.surrogates.kernels import matern32

LOWER = np.array([80.0, 0.05, 60.0, 0.25])  # physical units: (P, v, K_S, A_0)
UPPER = np.array([250.0, 2.0, 100.0, 0.4])


def _physical(n, seed):
    u = np.random.default_rng(seed).random((n, 4))
    return LOWER + u * (UPPER - LOWER), u


def _f(u):
    return 50.0 + 10 * np.sin(3 * u[:, 0]) + 5 * u[:, 1] * u[:, 2] + 3 * u[:, 3] ** 2


@pytest.fixture(scope="module")
def fixed_gp():
    x, u = _physical(30, 0)
    return condition(x, _f(u), lower=LOWER, upper=UPPER, lengthscales=[0.5, 0.6, 0.7, 0.8],
                     signal_var=1.0, nugget=1e-10, name="W"), x, _f(u)


@pytest.fixture(scope="module")
def fitted():
    x, u = _physical(30, 1)  # n = 30 everywhere: one compilation
    return fit_gp(x, _f(u), lower=LOWER, upper=UPPER, n_restarts=1, name="W"), x, _f(u)


def test_interpolates_training_points_with_near_zero_variance(fixed_gp):
    gp, x, y = fixed_gp
    mean, var = gp.predict(x)
    np.testing.assert_allclose(np.asarray(mean), y, rtol=0, atol=1e-6 * np.std(y))
    assert np.max(np.asarray(var)) < 1e-6 * np.var(y)
    z, _ = _physical(5, 99)
    assert np.min(np.asarray(gp.predict(z)[1])) > 1e-4 * np.var(y)  # away from the data


def test_split_predictions_and_fast_closures_agree(fitted):
    gp, _, _ = fitted
    z, _ = _physical(7, 5)
    xc, theta = z[:, :2], z[0, 2:]
    ref_mean, ref_var = gp.predict(np.column_stack([xc, np.tile(theta, (7, 1))]))
    mean, var = gp.predict_split(xc, theta)
    np.testing.assert_allclose(mean, ref_mean, rtol=1e-12)
    np.testing.assert_allclose(jax.jit(gp.mean_fn_at(xc))(theta), ref_mean, rtol=1e-12)
    np.testing.assert_allclose(jax.jit(gp.var_fn_at(xc))(theta), ref_var, rtol=1e-9,
                               atol=1e-12)
    m2, _ = gp.predict_split(xc, z[:, 2:])  # (m, d_theta) parameters, one row each
    np.testing.assert_allclose(m2, gp.predict(z)[0], rtol=1e-12)


def test_mean_gradient_in_theta_matches_finite_differences(fitted):
    gp, _, _ = fitted
    z, _ = _physical(3, 6)
    f = gp.mean_fn_at(z[:, :2])
    theta = jnp.asarray(z[0, 2:])
    jac = np.asarray(jax.jit(jax.jacfwd(f))(theta))
    h = 1e-6 * (UPPER[2:] - LOWER[2:])
    fd = np.stack([(f(theta + h[i] * e) - f(theta - h[i] * e)) / (2 * h[i])
                   for i, e in enumerate(np.eye(2))], axis=1)
    np.testing.assert_allclose(jac, fd, rtol=1e-5, atol=1e-8)


@pytest.mark.parametrize("mean", ["constant", "quadratic"])
def test_predict_mean_and_its_written_out_derivatives_match_autodiff(mean):
    """predict_mean is predict's mean; its first derivatives (forward and reverse) and
    second derivatives equal those of the mean differentiated through the kernel, also
    at a training point (r = 0) and with a trend."""
    x, u = _physical(30, 2)
    gp = condition(x, _f(u), lower=LOWER, upper=UPPER, lengthscales=[0.5, 0.6, 0.7, 0.8],
                   signal_var=1.3, nugget=1e-8, mean=mean)
    z = np.vstack([_physical(4, 7)[0], x[:1]])  # the last: a training point

    def plain(zz):
        return gp.predict(zz)[0]

    np.testing.assert_allclose(gp.predict_mean(z), plain(z), rtol=1e-12)
    for transform in (jax.jacfwd, jax.jacrev):
        np.testing.assert_allclose(transform(gp.predict_mean)(z), transform(plain)(z),
                                   rtol=1e-8, atol=1e-10)
    row = jnp.asarray(z)

    def summed(f):
        return lambda zz: jnp.sum(f(zz) ** 2)

    np.testing.assert_allclose(jax.hessian(summed(gp.predict_mean))(row),
                               jax.hessian(summed(plain))(row), rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(gp.mean_gradient(z), jnp.stack(
        [jax.grad(lambda r: plain(r[None])[0])(jnp.asarray(r)) for r in z]), rtol=1e-8,
        atol=1e-10)


def test_fitted_gp_is_a_pytree_usable_under_jit(fitted):
    gp, x, _ = fitted
    predict = jax.jit(lambda g, z: g.predict(z))
    np.testing.assert_allclose(predict(gp, x[:3])[0], gp.predict(x[:3])[0], rtol=1e-12)
    assert jax.tree_util.tree_structure(gp).num_leaves == len(ARRAY_FIELDS)


def test_log_transform_models_log_scale_and_to_natural():
    x, u = _physical(30, 2)
    y = np.exp(2.0 + u[:, 0] + 0.5 * u[:, 1])  # log-linear: easy on the log scale
    gp = fit_gp(x, y, lower=LOWER, upper=UPPER, transform="log", n_restarts=1)
    z, uz = _physical(5, 3)
    mean, var = gp.predict(z)
    np.testing.assert_allclose(mean, 2.0 + uz[:, 0] + 0.5 * uz[:, 1], atol=1e-2)
    nat_mean, nat_var = gp.to_natural(mean, var)
    np.testing.assert_allclose(nat_mean, np.exp(mean + var / 2), rtol=1e-12)
    np.testing.assert_allclose(nat_var, np.expm1(var) * np.exp(2 * mean + var), rtol=1e-12)


def test_nlml_attribute_is_the_optimum(fitted):
    gp, _, _ = fitted
    value = -float(gp.log_marginal_likelihood())
    assert float(gp.nlml) == pytest.approx(value, rel=1e-8)
    for step in (-0.05, 0.05):  # a local minimum in every log hyperparameter
        for i in range(gp.log_params.shape[0]):
            p = gp.log_params.at[i].add(step)
            at_bound = (i < 4 and abs(float(gp.log_params[i]) - np.log(100.0)) < 1e-6) or \
                (i == 5 and abs(float(gp.log_params[i]) - np.log(1e-8)) < 1e-6)
            if not at_bound:
                assert -float(gp.log_marginal_likelihood(p)) >= value - 1e-6


def test_recovers_known_length_scales():
    # Data sampled from a GP with ell = (0.15, 0.6), s2 = 1, nugget 1e-6, n = 100 uniform
    # points in 2-D. A Monte Carlo study over 40 data sets (seeds 0..39, same code) gave
    # per-data-set sd of log(ell_hat) of 0.23 and 0.21 and a mean bias of -0.03 and -0.01.
    # Averaging R = 10 replicates gives a standard error of about 0.07; we allow 0.25
    # (about 3.5 standard errors) on the mean log ratio for each length scale.
    ell = np.array([0.15, 0.6])
    logs = []
    for s in range(10):
        rng = np.random.default_rng(s)
        x = rng.random((100, 2))
        k = np.asarray(matern32(jnp.asarray(x), jnp.asarray(x), jnp.asarray(ell), 1.0))
        y = np.linalg.cholesky(k + 1e-6 * np.eye(100)) @ rng.standard_normal(100)
        gp = fit_gp(x, y, lower=[0, 0], upper=[1, 1], n_restarts=2, seed=s)
        logs.append(np.log(np.asarray(gp.lengthscales)))
    bias = np.mean(logs, axis=0) - np.log(ell)
    assert np.all(np.abs(bias) < 0.25), bias


def test_save_load_round_trip_is_exact(fitted, tmp_path):
    gp, x, _ = fitted
    path = save_gp(gp, tmp_path / "sub" / "W")
    assert path.name == "W.npz" and (tmp_path / "sub" / "W.json").is_file()
    back = load_gp(path)
    assert isinstance(back, FittedGP) and back.name == "W" and back.transform is None
    for leaf_a, leaf_b in zip(jax.tree_util.tree_leaves(gp), jax.tree_util.tree_leaves(back),
                              strict=True):
        np.testing.assert_array_equal(np.asarray(leaf_a), np.asarray(leaf_b))
    np.testing.assert_array_equal(back.predict(x[:4])[0], gp.predict(x[:4])[0])
    assert load_gp(tmp_path / "sub" / "W.npz").n_train == gp.n_train


def test_split_prediction_rejects_bad_control_shapes(fitted):
    from calnet.errors import SurrogateError

    gp, x, _ = fitted
    with pytest.raises(SurrogateError, match=r"'W'.*0 < d_x < 4, got \(3, 4\)"):
        gp.mean_fn_at(x[:3])


def test_warm_start_from_an_optimum_stays_there():
    import numpy as np
    import pytest

    from calnet.errors import SurrogateError
    from calnet.surrogates import fit_gp

    rng = np.random.default_rng(4)
    X = rng.uniform(0, 1, (40, 3))
    y = np.sin(3 * X[:, 0]) + X[:, 1] ** 2 + 0.01 * rng.standard_normal(40)
    kw = dict(lower=[0, 0, 0], upper=[1, 1, 1])
    full = fit_gp(X, y, n_restarts=3, seed=1, **kw)
    warm = fit_gp(X, y, n_restarts=0, init=np.asarray(full.log_params), **kw)
    assert float(warm.nlml) <= float(full.nlml) + 1e-6
    np.testing.assert_allclose(np.asarray(warm.lengthscales), np.asarray(full.lengthscales),
                               rtol=1e-3)
    with pytest.raises(SurrogateError, match="init must be 5 finite"):
        fit_gp(X, y, n_restarts=0, init=[0.0, 0.0], **kw)


def test_an_overstated_variance_is_recognised():
    """A very smooth output (2 sqrt(T) on 15 runs): the likelihood drives the signal
    variance to its upper bound and the predictive sd is many times the actual error
    between the runs; a rough output's GP is not flagged."""
    from calnet.surrogates.fit import overstated_variance

    t = np.linspace(10.0, 500.0, 15)[:, None]
    smooth = fit_gp(t, 2.0 * np.sqrt(t[:, 0]), lower=[10.0], upper=[500.0], mean="quadratic")
    median = overstated_variance(smooth)
    assert median is not None and median < 0.25
    grid = np.linspace(10.0, 500.0, 400)[:, None]
    m, v = (np.asarray(a) for a in smooth.predict(grid))
    err = np.abs(m - 2.0 * np.sqrt(grid[:, 0]))
    assert np.median(err / np.sqrt(v)) < 0.25  # what the flag says, on fresh points
    rng = np.random.default_rng(2)
    x = rng.uniform(0.0, 1.0, (40, 1))
    rough = fit_gp(x, np.sin(12.0 * x[:, 0]) + 0.1 * rng.standard_normal(40), lower=[0.0],
                   upper=[1.0])
    assert overstated_variance(rough) is None
