"""KOH log-density: the koh_anchor reference value, gradients, switches and errors."""

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

from calnet.calibration.emulator import fixed_input_gp, matern32_var
from calnet.calibration.koh import build_logdensity, check_initial
from calnet.calibration.priors import Beta, InverseGamma, LogNormal, Normal
from calnet.errors import CalibrationError, CalibrationWarning

jax.config.update("jax_enable_x64", True)

DATA = Path(__file__).parent / "data" / "koh_anchor.npz"
# koh_anchor: u = [logit theta (7), log ell (2), log sd2, log se2] and the NumPy reference
U_TEST = np.array([0.1, -0.3, 0.5, -1.0, 0.2, 0.7, 0.0, -0.2, 0.3, -1.5, -2.0])
REF_LOGP = -16.747614


@pytest.fixture(scope="module")
def anchor():
    P = dict(np.load(DATA))
    mean_fn, args = fixed_input_gp(P["xo"], P["Xtr"], P["ls"], P["c"], P["mu0"])
    ld = build_logdensity(mean_fn, P["yo"], P["xo"], theta_priors=[Beta(0.0, 1.0)] * 7,
                          mean_args=args, name="anchor")
    return P, ld


def _direct_mean(P):
    """The anchor surrogate without the precomputation trick (closure, no mean_args)."""
    xo, Xtr, ls = P["xo"], P["Xtr"], P["ls"]

    def mean(theta):
        Z = jnp.concatenate([xo, jnp.broadcast_to(theta, (xo.shape[0], 7))], 1) / ls
        d2 = jnp.sum((Z[:, None, :] - (Xtr / ls)[None]) ** 2, -1)
        r = jnp.sqrt(3.0 * (d2 + 1e-12))
        return P["mu0"] + ((1.0 + r) * jnp.exp(-r)) @ P["c"]
    return mean


def test_anchor_value_matches_numpy_reference(anchor):
    P, ld = anchor
    assert float(ld.logdensity(jnp.asarray(U_TEST))) == pytest.approx(REF_LOGP, abs=1e-6)
    plain = build_logdensity(_direct_mean(P), P["yo"], P["xo"], theta_priors=[Beta(0, 1)] * 7)
    assert float(plain.logdensity(jnp.asarray(U_TEST))) == pytest.approx(REF_LOGP, abs=1e-6)
    assert ld.dim == 11 and ld.n_obs == 30


def test_gradient_matches_finite_differences(anchor):
    _, ld = anchor
    g = np.asarray(jax.grad(ld.logdensity)(jnp.asarray(U_TEST)))
    # central differences: h = 1e-4 balances truncation (h^2) against the round-off of
    # surrogate weights of order 1e4 cancelling (measured error ~3e-7 at h = 1e-4)
    h, f = 1e-4, jax.jit(ld.logdensity)
    fd = [(float(f(U_TEST + h * e)) - float(f(U_TEST - h * e))) / (2 * h) for e in np.eye(11)]
    np.testing.assert_allclose(g, fd, rtol=1e-5, atol=2e-6)


def test_constrain_unconstrain_roundtrip_and_names(anchor):
    _, ld = anchor
    c = ld.constrain(jnp.asarray(U_TEST))
    assert c["theta"].shape == (7,) and c["ell"].shape == (2,) and c["sd2"].shape == ()
    np.testing.assert_allclose(c["ell"], np.exp(U_TEST[7:9]))
    np.testing.assert_allclose(ld.unconstrain(c), U_TEST, atol=1e-10)
    assert ld.names[0] == "theta[theta_0]" and ld.names[-2:] == ("sd2", "se2")
    u0 = ld.init(0, 4)
    assert u0.shape == (4, 11) and np.all(np.isfinite(u0))
    np.testing.assert_array_equal(u0, ld.init(0, 4))


def _linear_problem(n=6, seed=0):
    rng = np.random.default_rng(seed)
    x = np.linspace(0, 1, n)[:, None]
    A = rng.normal(size=(n, 2))
    return x, A, A @ np.array([0.5, -1.0]) + 0.1 * rng.normal(size=n)


def test_emulator_variance_switch_and_fixed_hyperparameters():
    x, A, y = _linear_problem()
    var = np.linspace(0.01, 0.05, len(y))
    kw = dict(theta_priors=[Normal(0, 1)] * 2, fixed={"ell": 0.4, "sd2": 0.3, "se2": 0.02})
    off = build_logdensity(lambda th: jnp.asarray(A) @ th, y, x, **kw)
    on = build_logdensity(lambda th: jnp.asarray(A) @ th, y, x,
                          emulator_var_fn=lambda th: jnp.asarray(var), **kw)
    assert on.dim == off.dim == 2 and on.sampled_vars == ("theta",)
    th = np.array([0.2, -0.7])
    K = 0.3 * np.exp(-0.5 * (x - x.T) ** 2 / 0.4**2) + 0.02 * np.eye(len(y))
    prior = stats.norm.logpdf(th).sum()
    for ld, cov in ((off, K), (on, K + np.diag(var))):
        ref = stats.multivariate_normal(A @ th, cov).logpdf(y) + prior
        assert float(ld.logdensity(jnp.asarray(th))) == pytest.approx(ref, rel=1e-10)
    assert float(on.constrain(jnp.asarray(th))["sd2"]) == 0.3


def test_gp_variance_at_fixed_inputs():
    rng = np.random.default_rng(1)
    Z, x = rng.uniform(size=(15, 3)), rng.uniform(size=(4, 1))
    ls, amp, noise = np.array([0.4, 0.5, 0.6]), 1.3, 1e-4
    k = lambda A, B: amp * np.exp(  # noqa: E731
        -np.sqrt(3 * (((A[:, None] - B[None]) / ls) ** 2).sum(-1))) * (
        1 + np.sqrt(3 * (((A[:, None] - B[None]) / ls) ** 2).sum(-1)))
    K = k(Z, Z) + noise * np.eye(15)
    _, args = fixed_input_gp(x, Z, ls, np.zeros(15), 0.0, amp=amp, k_inv=np.linalg.inv(K))
    theta = np.array([0.3, 0.8])
    zq = np.hstack([x, np.tile(theta, (4, 1))])
    ref = amp - np.einsum("ij,jk,ik->i", k(zq, Z), np.linalg.inv(K), k(zq, Z))
    np.testing.assert_allclose(matern32_var(jnp.asarray(theta), args), ref, atol=1e-8)


def test_fewer_points_than_parameters_warns():
    x, A, y = _linear_problem(n=3)
    with pytest.warns(CalibrationWarning, match="3 data points for 5 sampled") as rec:
        build_logdensity(lambda th: jnp.asarray(A) @ th, y, x,
                         theta_priors=[Normal(0, 1)] * 2, name="tiny")
    assert rec[0].filename == __file__  # stacklevel points at the caller


def test_non_finite_initial_point_names_the_model():
    x, A, y = _linear_problem()
    ld = build_logdensity(lambda th: jnp.log(th[0] - 10.0) * jnp.ones(len(y)), y, x,
                          theta_priors=[Normal(0, 1)], name="melt_pool")
    with pytest.raises(CalibrationError, match="model 'melt_pool'.*not finite"):
        check_initial(ld, ld.init(0, 2))


@pytest.mark.parametrize("kwargs,match", [
    (dict(theta_priors=[]), "theta_priors"),
    (dict(theta_priors=[Normal()] * 2, ell_prior=Normal()), "ell_prior"),
    (dict(theta_priors=[Normal()] * 2, fixed={"rho": 1.0}), "unknown hyperparameter"),
    (dict(theta_priors=[Normal()] * 2, fixed={"se2": -1.0}), "positive"),
    (dict(theta_priors=[Normal()] * 2, ell_prior=[LogNormal()] * 3), "sequence of 1"),
    (dict(theta_priors=[Normal()] * 2, sd2_prior=InverseGamma(), theta_names=["a"]), "names"),
])
def test_bad_arguments_raise(kwargs, match):
    x, A, y = _linear_problem()
    with pytest.raises(CalibrationError, match=match):
        build_logdensity(lambda th: jnp.asarray(A) @ th, y, x, **kwargs)


def test_wrong_mean_shape_and_bad_data_raise():
    x, A, y = _linear_problem()
    with pytest.raises(CalibrationError, match=r"must return shape \(6,\)"):
        build_logdensity(lambda th: th, y, x, theta_priors=[Normal()] * 2)
    with pytest.raises(CalibrationError, match="x_disc"):
        build_logdensity(lambda th: jnp.asarray(A) @ th, y, x[:3], theta_priors=[Normal()] * 2)
    with pytest.raises(CalibrationError, match="finite observations"):
        build_logdensity(lambda th: jnp.asarray(A) @ th, y * np.nan, x,
                         theta_priors=[Normal()] * 2)
