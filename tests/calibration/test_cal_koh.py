"""The KOH model: the koh_anchor reference value on the shipped object, and its
log-density and predictive against independent NumPy/SciPy computations."""

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest
from scipy import stats

from calnet.calibration.calibrate_network import build_koh
from calnet.calibration.koh import JITTER
from calnet.calibration.terms import make_term
from calnet.chain import ChainPlan
from calnet.spec import load_spec, read_all
from calnet.surrogates.fit_network import OutputSurrogate, Surrogates
from calnet.surrogates.gp import FittedGP, condition, constant_mean

DATA = Path(__file__).parent / "data" / "koh_anchor.npz"
# koh_anchor: u = [logit theta (7), log ell (2), log sd2, log se2] and the NumPy reference
U_TEST = np.array([0.1, -0.3, 0.5, -1.0, 0.2, 0.7, 0.0, -0.2, 0.3, -1.5, -2.0])
REF_LOGP = -16.747614

ANCHOR_SPEC = """
models:
  m:
    simulator: python:nowhere:f
    inputs: {x1: {lower: 0, upper: 1}, x2: {lower: 0, upper: 1}}
    parameters: {t0: {lower: 0, upper: 1}, t1: {lower: 0, upper: 1}, t2: {lower: 0, upper: 1},
                 t3: {lower: 0, upper: 1}, t4: {lower: 0, upper: 1}, t5: {lower: 0, upper: 1},
                 t6: {lower: 0, upper: 1}}
    outputs: {y: {measurable: true}}
data:
  obs:
    path: obs.csv
    observes: m.y
    columns: {x1: x1, x2: x2, y: y}
    noise: {prior: {dist: invgamma, a: 2, b: 1}}
    discrepancy: {sd_prior: {dist: invgamma, a: 2, b: 1}, orthogonal: false}
settings:
  calibration: {emulator_variance: false}
"""


def _anchor_gp(P) -> FittedGP:
    """The anchor's surrogate, ``mu0 + k32([x, theta], Xtr; ls) @ c``, as a FittedGP."""
    amp = float(P["amp"])
    d2 = (((P["Xtr"][:, None] - P["Xtr"][None]) / P["ls"]) ** 2).sum(-1)
    r = np.sqrt(3 * d2)
    K = amp * (1 + r) * np.exp(-r) + float(P["noise"]) * np.eye(len(P["Xtr"]))
    f = jnp.asarray
    return FittedGP(x_train=f(P["Xtr"]), alpha=f(P["c"] / amp), chol=f(np.linalg.cholesky(K)),
                    lengthscales=f(P["ls"]), signal_var=f(amp), nugget=f(P["noise"]),
                    lower=f(np.zeros(9)), upper=f(np.ones(9)), y_mean=f(P["mu0"]),
                    y_std=f(1.0), nlml=f(np.nan), name="y", **constant_mean(len(P["Xtr"])))


@pytest.fixture(scope="module")
def anchor(tmp_path_factory):
    P = dict(np.load(DATA))
    folder = tmp_path_factory.mktemp("anchor")
    (folder / "network.yaml").write_text(ANCHOR_SPEC)
    pd.DataFrame({"x1": P["xo"][:, 0], "x2": P["xo"][:, 1], "y": P["yo"]}).to_csv(
        folder / "obs.csv", index=False)
    network = load_spec(folder)
    sur = Surrogates({"m.y": OutputSurrogate("m", "y", _anchor_gp(P), None, 240, 0)})
    data = {k: v.train for k, v in read_all(network).items()}
    free = [f"m.t{i}" for i in range(7)]
    ld = build_koh(network, sur, free=free, datasets=data, emulator_variance=False)
    return P, ld


def test_anchor_value_on_the_shipped_object(anchor):
    _, ld = anchor
    assert ld.dim == 11
    assert float(ld.logdensity(jnp.asarray(U_TEST))) == pytest.approx(REF_LOGP, abs=1e-6)


def test_anchor_gradient_matches_finite_differences(anchor):
    _, ld = anchor
    g = np.asarray(jax.grad(ld.logdensity)(jnp.asarray(U_TEST)))
    # central differences: h = 1e-4 balances truncation (h^2) against the round-off of
    # surrogate weights of order 1e4 cancelling
    h, f = 1e-4, jax.jit(ld.logdensity)
    fd = [(float(f(U_TEST + h * e)) - float(f(U_TEST - h * e))) / (2 * h) for e in np.eye(11)]
    np.testing.assert_allclose(g, fd, rtol=1e-5, atol=2e-6)


def test_anchor_constrain_and_init(anchor):
    _, ld = anchor
    c = ld.constrain(jnp.asarray(U_TEST))
    np.testing.assert_allclose(c["theta_m"], 1 / (1 + np.exp(-U_TEST[:7])))
    np.testing.assert_allclose(c["ell_obs"], np.exp(U_TEST[7:9]))
    assert float(c["sd2_obs"]) == pytest.approx(np.exp(-1.5))
    u0 = ld.init(0, 4)
    assert u0.shape == (4, 11) and np.all(np.isfinite(u0))
    np.testing.assert_array_equal(u0, ld.init(0, 4))


# ------------------------------------------------------------------ a two-model chain
CHAIN_SPEC = """
models:
  up:
    simulator: python:nowhere:f
    inputs: {x: {lower: 0, upper: 1}}
    parameters: {a: {lower: -2, upper: 2}}
    outputs: {g: {}}
  down:
    simulator: python:nowhere:f
    inputs: {g: {lower: -3, upper: 5}, z: {lower: 0, upper: 2}}
    parameters: {b: {lower: 0, upper: 1}, c: {lower: -1, upper: 1}}
    outputs: {y: {measurable: true}}
links: [{from: up.g, to: down.g}]
data:
  obs:
    path: obs.csv
    observes: down.y
    columns: {x: x, z: z, y: y}
    noise: {sd_column: err}
    discrepancy: {sd_prior: {dist: halfnormal, sigma: 0.7}}
"""


def _gp(rng, d, name):
    X = rng.uniform(size=(25, d))
    y = np.sin(3 * X).sum(1) + X[:, 0] * X[:, -1]
    return condition(X, y, lower=np.zeros(d), upper=np.ones(d), lengthscales=np.full(d, 0.6),
                     signal_var=1.3, nugget=1e-4, name=name)


@pytest.fixture(scope="module")
def chain(tmp_path_factory):
    rng = np.random.default_rng(5)
    folder = tmp_path_factory.mktemp("chain")
    (folder / "network.yaml").write_text(CHAIN_SPEC)
    n = 7
    pd.DataFrame({"x": rng.uniform(size=n), "z": rng.uniform(0, 2, n),
                  "y": rng.normal(1.0, 0.5, n), "err": rng.uniform(0.05, 0.2, n)}).to_csv(
        folder / "obs.csv", index=False)
    network = load_spec(folder)
    g_up = _gp(rng, 2, "g")
    g_dn = _gp(rng, 4, "y")
    # the GPs work on the unit cube of their own bounds: rescale to the declared ones
    g_up = g_up.__class__(**{**g_up.__dict__, "lower": jnp.array([0.0, -2.0]),
                             "upper": jnp.array([1.0, 2.0])})
    g_dn = g_dn.__class__(**{**g_dn.__dict__, "lower": jnp.array([-3.0, 0.0, 0.0, -1.0]),
                             "upper": jnp.array([5.0, 2.0, 1.0, 1.0])})
    sur = Surrogates({"up.g": OutputSurrogate("up", "g", g_up, None, 25, 0),
                      "down.y": OutputSurrogate("down", "y", g_dn, None, 25, 0)})
    data = {k: v.train for k, v in read_all(network).items()}
    return network, sur, data


def _np_gp(gp, z):
    """Mean (m,) and covariance (m, m) of a FittedGP at ``z`` with NumPy only."""
    zs = (z - np.asarray(gp.lower)) / (np.asarray(gp.upper) - np.asarray(gp.lower))
    X, ls, s2 = np.asarray(gp.x_train), np.asarray(gp.lengthscales), float(gp.signal_var)

    def k32(a, b):
        r = np.sqrt(3 * (((a[:, None] - b[None]) / ls) ** 2).sum(-1))
        return s2 * (1 + r) * np.exp(-r)

    L = np.asarray(gp.chol)
    ks = k32(zs, X)
    v = np.linalg.solve(L, ks.T)
    sd = float(gp.y_std)
    return (float(gp.y_mean) + sd * ks @ np.asarray(gp.alpha),
            sd**2 * (k32(zs, zs) - v.T @ v))


def _numpy_pieces(network, sur, d, a, bc, ell, sd2, upstream: bool = False):
    """Mean (n,), surrogate covariance incl. the first-order upstream share (n, n), the
    discrepancy covariance, orthogonalised, and unit inputs, all with NumPy only.
    ``upstream``: the upstream parameter a is sampled too, so the discrepancy is also
    orthogonal to the mean's response to a through the link."""
    up, dn = sur["up.g"].gp, sur["down.y"].gp

    def g_of(x, aa):
        return _np_gp(up, np.column_stack([x, np.full(len(x), aa)]))

    def y_of(g, z, th):
        return _np_gp(dn, np.column_stack([g, z, np.tile(th, (len(g), 1))]))

    x, z = d.x[:, 0], d.x[:, 1]
    g, g_cov = g_of(x, a)
    m, cov = y_of(g, z, bc)
    h = 1e-6
    dm_dg = (y_of(g + h, z, bc)[0] - y_of(g - h, z, bc)[0]) / (2 * h)
    cov = cov + np.outer(dm_dg, dm_dg) * g_cov
    G = np.column_stack([(y_of(g, z, bc + h * e)[0] - y_of(g, z, bc - h * e)[0]) / (2 * h)
                         for e in np.eye(2)])
    if upstream:
        dm_da = (y_of(g_of(x, a + h)[0], z, bc)[0] - y_of(g_of(x, a - h)[0], z, bc)[0]) / (2 * h)
        G = np.column_stack([dm_da, G])
    u = np.column_stack([(g + 3) / 8, z / 2])
    C = sd2 * np.exp(-0.5 * (((u[:, None] - u[None]) / ell) ** 2).sum(-1))
    # calnet regularises G^T C G by 1e-9 of its mean eigenvalue (koh.py): with the
    # upstream column, whose response is small here, that moves the answer by 1e-4
    M = G.T @ C @ G
    M = M + 1e-9 * np.trace(M) / M.shape[0] * np.eye(M.shape[0])
    C_orth = C - C @ G @ np.linalg.solve(M, G.T @ C)
    return m, cov, C, C_orth, G, u, (g_of, y_of)


@pytest.mark.parametrize("upstream", ["sampled", "fixed"])
def test_chain_loglik_matches_numpy(chain, upstream):
    """With the upstream parameter fixed (a segmented stage) the inputs and the control
    part of the surrogate's distances are precomputed: the same value. Sampled, the
    orthogonal discrepancy is orthogonal to its direction through the link as well."""
    network, sur, data = chain
    if upstream == "fixed":
        ld = build_koh(network, sur, free=["down.b", "down.c"], datasets=data,
                       fixed={"up.a": 0.3})
        assert "gp_fixed" in ld.data["terms"][0] and "corr_fixed" in ld.data["terms"][0]
    else:
        ld = build_koh(network, sur, free=["up.a", "down.b", "down.c"], datasets=data)
    a, bc, ell, sd2 = 0.3, np.array([0.4, -0.2]), np.array([0.5, 0.8]), 0.09
    d = data["obs"]
    m, cov, _, C_orth, _, _, _ = _numpy_pieces(network, sur, d, a, bc, ell, sd2,
                                               upstream=upstream == "sampled")
    K = C_orth + cov + np.diag(d.noise_sd**2)
    ref = stats.multivariate_normal(m, K, allow_singular=True).logpdf(d.y)
    spec = ld.spec
    params = [a, *bc] if upstream == "sampled" else list(bc)
    values = {"params": jnp.asarray(params), "ell_obs": jnp.asarray(ell),
              "sd2_obs": jnp.asarray(sd2)}
    thetas = spec.thetas(ld.data, values["params"])
    got = spec.term_loglik(ld.data, spec.terms[0], ld.data["terms"][0], thetas,
                           spec.hyper(spec.terms[0], None, values))
    # differences: the jitter (1e-10 sd^2) and the finite differences of the reference
    assert float(got) == pytest.approx(ref, rel=1e-7)


def test_chain_predictive_matches_conditioning_by_hand(chain):
    network, sur, data = chain
    d = data["obs"]
    a, bc, ell, sd2 = -0.4, np.array([0.7, 0.1]), np.array([0.6, 0.4]), 0.05
    m, cov, C, C_orth, G, u, (g_of, y_of) = _numpy_pieces(network, sur, d, a, bc, ell, sd2)
    xn = np.array([[0.2, 0.5], [0.8, 1.7], [0.5, 1.0]])
    gn, _ = g_of(xn[:, 0], a)
    mn, cn = y_of(gn, xn[:, 1], bc)
    vn = np.diag(cn)
    un = np.column_stack([(gn + 3) / 8, xn[:, 1] / 2])
    # joint covariance of (delta(new), delta(X)) and the constraint G^T delta(X) = 0
    allu = np.vstack([un, u])
    Ca = sd2 * np.exp(-0.5 * (((allu[:, None] - allu[None]) / ell) ** 2).sum(-1))
    Ga = np.vstack([np.zeros((3, 2)), G])
    Co = Ca - Ca @ Ga @ np.linalg.solve(Ga.T @ Ca @ Ga, Ga.T @ Ca)
    K = Co[3:, 3:] + cov + np.diag(d.noise_sd**2)
    w = np.linalg.solve(K, d.y - m)
    mean_ref = mn + Co[:3, 3:] @ w
    var_ref = np.diag(Co[:3, :3] - Co[:3, 3:] @ np.linalg.solve(K, Co[3:, :3]))

    plan = ChainPlan.from_network(network)
    term, tdata = make_term(network, d, emulator_variance=True, plan=plan)
    from calnet.calibration.koh import KOHModel

    spec = KOHModel(plan, (), (), (), (term,))
    gps = {k: s.gp for k, s in sur.items.items()}
    thetas = {"up": jnp.asarray([a]), "down": jnp.asarray(bc)}
    hyper = {"ell": jnp.asarray(ell), "sd2": jnp.asarray(sd2), "se2": jnp.asarray(0.0)}
    xp = {"up.x": jnp.asarray(xn[:, 0]), "down.z": jnp.asarray(xn[:, 1])}
    mean, var_d, var_e, noise = spec.term_predict({"gps": gps}, term, tdata, thetas, hyper, xp,
                                                  {}, jnp.full(3, 0.01))
    s, mu = float(tdata["y_sd"]), float(tdata["y_mean"])
    np.testing.assert_allclose(np.asarray(mean) * s + mu, mean_ref, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(np.asarray(var_d) * s**2, var_ref, rtol=1e-5, atol=1e-8)
    np.testing.assert_allclose(np.asarray(var_e) * s**2, vn, rtol=1e-8)
    np.testing.assert_allclose(np.asarray(noise) * s**2, 0.01)
    assert JITTER < 1e-8
