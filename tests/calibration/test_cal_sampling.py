"""NUTS sampling: the linear-Gaussian analytic oracle, reproducibility, compiled-sampler
reuse, InferenceData layout, diagnostics and their warnings."""

import re
from dataclasses import dataclass, field

import jax.numpy as jnp
import numpy as np
import pytest

from calnet.calibration.diagnostics import stuck_chains, summarize, unvisited_mode
from calnet.calibration.sampling import cache_info, sample_nuts
from calnet.errors import CalibrationError, CalibrationWarning
from calnet.progress import Lines

FIXED = {"ell": 0.3, "sd2": 0.05, "se2": 0.04}
PRIOR_SD = 1.5
SETTINGS = dict(num_chains=4, num_warmup=300, num_draws=500)


@dataclass(frozen=True)
class _GaussianSpec:
    """``y ~ N(A theta, K)``, ``theta ~ N(0, PRIOR_SD^2 I)``: the sampler's protocol."""

    broken: bool = False
    kinked: bool = False  # + |u_1|: finite everywhere, its gradient NaN at u_1 = 0

    def logdensity(self, data, u):
        r = data["y"] - data["A"] @ u
        lp = -0.5 * r @ data["K_inv"] @ r - 0.5 * jnp.sum(u**2) / PRIOR_SD**2
        lp = lp - (jnp.sqrt(u[1] ** 2) if self.kinked else 0.0)
        return lp + (jnp.sqrt(u[0] - 50.0) if self.broken else 0.0)

    def constrain(self, data, u):
        return {"theta": u}


@dataclass(frozen=True)
class _Gaussian:
    spec: _GaussianSpec
    data: dict = field(repr=False)
    name: str = "linear"
    dim: int = 3
    sampled_vars: tuple = ("theta",)
    dims: dict = field(default_factory=lambda: {"theta": ["theta_dim"]})
    coords: dict = field(default_factory=lambda: {"theta_dim": ["a", "b", "c"]})

    def logdensity(self, u):
        return self.spec.logdensity(self.data, u)

    def init(self, seed, n_chains):
        return np.random.default_rng(seed).normal(0.0, PRIOR_SD, (n_chains, self.dim))


def _problem(seed):
    rng = np.random.default_rng(seed)
    n = 15
    x = np.sort(rng.uniform(size=n))[:, None]
    A = np.column_stack([np.ones(n), x[:, 0], np.sin(3 * x[:, 0])])
    K = FIXED["sd2"] * np.exp(-0.5 * (x - x.T) ** 2 / FIXED["ell"] ** 2) + FIXED["se2"] * np.eye(n)
    y = A @ np.array([0.3, -0.8, 0.5]) + np.linalg.cholesky(K) @ rng.normal(size=n)
    return x, A, K, y


def _build(seed, name="linear"):
    x, A, K, y = _problem(seed)
    data = {"y": jnp.asarray(y), "A": jnp.asarray(A), "K_inv": jnp.asarray(np.linalg.inv(K))}
    ld = _Gaussian(_GaussianSpec(), data, name)
    # closed-form Gaussian posterior: precision A^T K^-1 A + I / s^2, mean Sigma A^T K^-1 y
    Ki = np.linalg.inv(K)
    cov = np.linalg.inv(A.T @ Ki @ A + np.eye(3) / PRIOR_SD**2)
    return ld, cov @ A.T @ Ki @ y, np.sqrt(np.diag(cov))


@pytest.fixture(scope="module")
def oracle_run():
    ld, mean, sd = _build(0)
    return ld, mean, sd, sample_nuts(ld, seed=3, **SETTINGS)


def test_linear_gaussian_posterior_matches_closed_form(oracle_run):
    import arviz as az

    _, mean, sd, idata = oracle_run
    post = idata.posterior["theta"]
    # Monte Carlo standard errors from the chains' ESS (ArviZ): the estimate of the mean
    # has sd mcse_mean = sd / sqrt(ESS_bulk), that of the sd has mcse_sd; 5 of them is a
    # 5-sigma band (false-alarm rate ~1e-6 per check; deterministic at a fixed seed).
    mcse_mean = az.mcse(idata.posterior, method="mean")["theta"].values
    mcse_sd = az.mcse(idata.posterior, method="sd")["theta"].values
    ess = az.ess(idata.posterior, method="bulk")["theta"].values
    assert np.all(ess > 500)  # 2000 draws of a 3-d Gaussian: NUTS is efficient here
    est_mean = post.mean(("chain", "draw")).values
    est_sd = post.std(("chain", "draw")).values
    assert np.all(np.abs(est_mean - mean) < 5 * mcse_mean), (est_mean, mean, mcse_mean)
    assert np.all(np.abs(est_sd - sd) < 5 * mcse_sd), (est_sd, sd, mcse_sd)


@pytest.mark.parametrize("kwargs", [dict(chain_method="sequential"),
                                    dict(chain_method="vectorized"),
                                    dict(dense_mass=True),
                                    dict(num_warmup=15)])  # below Stan's smallest schedule
def test_every_sampler_setting_matches_closed_form(kwargs):
    """Chains one after another or in lock-step, a dense mass matrix, a warm-up too short
    for the mass-matrix windows: the same closed-form posterior, within 5 Monte Carlo
    standard errors."""
    import arviz as az

    ld, mean, sd = _build(1)
    idata = sample_nuts(ld, seed=5, **{**SETTINGS, **kwargs})
    post = idata.posterior["theta"]
    mcse_mean = az.mcse(idata.posterior, method="mean")["theta"].values
    mcse_sd = az.mcse(idata.posterior, method="sd")["theta"].values
    est_mean = post.mean(("chain", "draw")).values
    est_sd = post.std(("chain", "draw")).values
    assert np.all(np.abs(est_mean - mean) < 5 * mcse_mean), (est_mean, mean, mcse_mean)
    assert np.all(np.abs(est_sd - sd) < 5 * mcse_sd), (est_sd, sd, mcse_sd)
    assert not idata.sample_stats["diverging"].values.any()
    assert np.all(az.ess(idata.posterior, method="bulk")["theta"].values > 500)
    assert idata.posterior.attrs["chain_method"] == kwargs.get("chain_method", "parallel")


def test_inference_data_layout(oracle_run):
    ld, _, _, idata = oracle_run
    post = idata.posterior
    assert list(post.data_vars) == ["theta"]  # ell, sd2, se2 were fixed
    assert post["theta"].dims == ("chain", "draw", "theta_dim")
    assert post["theta"].shape == (4, 500, 3)
    assert list(post.coords["theta_dim"].values) == ["a", "b", "c"]
    for v in ("diverging", "energy", "n_steps", "tree_depth", "acceptance_rate", "lp",
              "step_size"):
        assert idata.sample_stats[v].shape == (4, 500)
    assert idata.observed_data["y"].shape == (15,)
    assert post.attrs["model"] == "linear" and post.attrs["num_warmup"] == 300
    assert post.attrs["sampling_time"] > 0


def test_same_seed_same_draws_and_no_recompilation(oracle_run):
    ld, _, _, first = oracle_run
    before = cache_info()
    again = sample_nuts(ld, seed=3, **SETTINGS)
    np.testing.assert_array_equal(again.posterior["theta"].values,
                                  first.posterior["theta"].values)
    assert cache_info()["hits"] == before["hits"] + 1
    assert again.posterior.attrs["compile_time"] == 0.0
    other = sample_nuts(ld, seed=4, **SETTINGS)
    assert not np.array_equal(other.posterior["theta"].values, first.posterior["theta"].values)


def test_compiled_is_called_once_before_the_chains_run_also_from_the_cache(oracle_run):
    ld = oracle_run[0]
    events = []
    for _ in range(2):  # compiled, then found in the cache
        sample_nuts(ld, seed=0, num_chains=2, num_warmup=20, num_draws=40,
                    compiled=lambda: events.append("compiled"),
                    progress=lambda chain, i, total: events.append("iteration"))
    assert events[0] == "compiled" and events.count("compiled") == 2
    second = events.index("compiled", 1)
    assert "iteration" in events[1:second] and events[second + 1] == "iteration"


def test_new_data_of_same_shapes_reuses_the_compiled_sampler(oracle_run):
    # leave-one-out style: a new log-density with new data but the same spec and shapes
    ld2, mean2, _ = _build(1, name="linear")
    before = cache_info()
    idata = sample_nuts(ld2, seed=0, **SETTINGS)
    assert cache_info()["misses"] == before["misses"]
    est = idata.posterior["theta"].mean(("chain", "draw")).values
    assert np.allclose(est, mean2, atol=0.1)  # loose: the oracle test is the precise one


def test_summary_and_metrics(oracle_run):
    _, mean, _, idata = oracle_run
    s = summarize(idata)
    d = s.to_dict()
    assert d["model"] == "linear" and d["divergences"] == 0 and d["converged"]
    assert set(d["parameters"]) == {"theta[a]", "theta[b]", "theta[c]"}
    p = s["theta[b]"]
    assert p.hdi[0.94][0] < p.mean < p.hdi[0.94][1]
    # a Gaussian posterior: the KDE mode is near the mean (within ~0.1 sd on 2000 draws)
    assert abs(p.mode - mean[1]) < 0.25 * p.sd


def test_summary_hdis_match_the_analytic_intervals(oracle_run):
    """The posterior is Gaussian, N(mean, sd^2): its HDI of mass q is mean -+ z sd with
    z = Phi^-1((1 + q) / 2). Each reported end must lie within 5 Monte Carlo standard
    errors of the tail quantile it estimates (ArviZ's quantile MCSE from the chains), and
    the reported mean and sd within 5 MCSE of the closed form."""
    import arviz as az
    from scipy.stats import norm

    _, mean, sd, idata = oracle_run
    s = summarize(idata)
    theta = idata.posterior["theta"].values  # (chain, draw, 3)
    for j, name in enumerate("abc"):
        p = s[f"theta[{name}]"]
        draws = theta[..., j]
        assert abs(p.mean - mean[j]) < 5 * float(az.mcse(draws)), (name, p.mean, mean[j])
        assert abs(p.sd - sd[j]) < 5 * float(az.mcse(draws, method="sd")), (name, p.sd, sd[j])
        for q in (0.94, 0.95):
            z = norm.ppf(0.5 + q / 2)
            for end, exact, tail in ((0, mean[j] - z * sd[j], (1 - q) / 2),
                                     (1, mean[j] + z * sd[j], (1 + q) / 2)):
                mcse = float(az.mcse(draws, method="quantile", prob=tail))
                assert abs(p.hdi[q][end] - exact) < 5 * mcse, (name, q, end, p.hdi[q], exact,
                                                               mcse)


def test_poor_diagnostics_warn_with_caller_stacklevel(oracle_run):
    idata = oracle_run[3].isel(draw=slice(0, 20))  # 80 draws: bulk ESS < 400
    with pytest.warns(CalibrationWarning, match="bulk ESS|R-hat") as rec:
        s = summarize(idata)
    assert not s.converged
    assert any("bulk ESS" in str(r.message) for r in rec)
    assert all(r.filename == __file__ for r in rec)


def test_progress_callback_and_thinning():
    ld, _, _ = _build(0)
    calls = []
    idata = sample_nuts(ld, seed=0, num_chains=2, num_warmup=20, num_draws=40, thin=4,
                        progress=lambda chain, it, total: calls.append((chain, it, total)))
    assert idata.posterior["theta"].shape == (2, 10, 3)
    assert {c for c, _, _ in calls} == {0, 1}
    assert max(it for _, it, _ in calls) == 60 and calls[0][2] == 60


def test_progress_without_a_terminal_is_plain_lines(capfd):
    """stderr is not a terminal here (captured): lines at every 10 % of the iterations,
    no carriage-return bar."""
    ld, _, _ = _build(0)
    sample_nuts(ld, seed=0, num_chains=2, num_warmup=20, num_draws=40, progress=True)
    err = capfd.readouterr().err
    assert "\r" not in err
    lines = err.splitlines()
    assert lines[0].startswith("linear: ") and "warm-up, 20 iterations x 2 chains" in lines[0]
    assert lines[-1].startswith("linear: 100 % of the iterations (")
    assert 3 <= len(lines) <= 12, lines


def test_progress_through_lines_runs_the_program_without_progress():
    """Lines (calnet run's progress) compile no callbacks in, so the program is the one
    without progress (JAX keeps it on disk) and the draws are the same."""
    ld, _, _ = _build(0)
    plain = sample_nuts(ld, seed=0, num_chains=2, num_warmup=20, num_draws=40)
    hits = cache_info()["hits"]
    out = []
    shown = sample_nuts(ld, seed=0, num_chains=2, num_warmup=20, num_draws=40,
                        progress=Lines("stage", out.append))
    assert cache_info()["hits"] == hits + 1
    np.testing.assert_array_equal(plain.posterior["theta"], shown.posterior["theta"])
    assert out[0].startswith("stage: sampling 2 chains x (20 warm-up + 40) iterations (0 s)")
    assert out[-1].startswith("stage: sampled (")


def test_non_finite_start_raises_before_sampling():
    ld, _, _ = _build(0, name="pdas")
    ld = _Gaussian(_GaussianSpec(broken=True), ld.data, "pdas")
    with pytest.raises(CalibrationError, match="pdas: the log-density is not finite"):
        sample_nuts(ld, seed=0, num_chains=2, num_warmup=10, num_draws=10)


def test_non_finite_gradient_at_some_starts_names_those_chains():
    ld, _, _ = _build(0, name="pdas")
    ld = _Gaussian(_GaussianSpec(kinked=True), ld.data, "pdas")
    init = np.array([[0.1, 0.5, 0.0], [0.1, 0.0, 0.0], [0.2, -0.3, 0.1], [0.0, 0.0, 1.0]])
    with pytest.raises(CalibrationError, match=r"pdas: the gradient of the log-density is not "
                                               r"finite at the initial point\(s\) of chain\(s\) "
                                               r"\[1, 3\]"):
        sample_nuts(ld, seed=0, num_chains=4, num_warmup=10, num_draws=10, init=init)
    # the same density from starts where it is smooth samples
    idata = sample_nuts(ld, seed=0, num_chains=4, num_warmup=10, num_draws=10,
                        init=init + np.array([0.0, 0.2, 0.0]))
    assert np.isfinite(idata.posterior["theta"].values).all()


@pytest.mark.parametrize("kwargs", [dict(num_chains=0), dict(thin=0),
                                    dict(num_draws=3, thin=5), dict(target_accept=1.0),
                                    dict(chain_method="threads"), dict(init=np.zeros((2, 3)))])
def test_bad_settings_raise(kwargs):
    ld, _, _ = _build(0)
    with pytest.raises(CalibrationError):
        sample_nuts(ld, **kwargs)


@pytest.mark.parametrize("name, label", [
    ("theta_M2[b]", "M2.b"), ("theta_melt_pool[A_0]", "melt_pool.A_0"),
    ("theta_shared[c]", "c (shared)"),
    ("ell_width[v]", "the discrepancy length scale of width along v"),
    ("sd2_pdas", "the discrepancy variance of pdas"), ("se2_pdas", "the noise variance of pdas"),
    ("theta", "theta")])
def test_diagnostics_name_parameters_as_the_spec_does(name, label):
    from calnet.calibration.diagnostics import readable

    assert readable(name) == label


@dataclass(frozen=True)
class _TwoModesSpec:
    """Two narrow modes, at 0 and at 10 (sd 0.1), the second 30 log units lower and
    separated from the first by a valley some 1200 log units deep: NUTS cannot cross."""

    def logdensity(self, data, u):
        a = -0.5 * (u[0] / 0.1) ** 2
        b = -30.0 - 0.5 * ((u[0] - 10.0) / 0.1) ** 2
        return jnp.logaddexp(a, b)

    def constrain(self, data, u):
        return {"theta": u}


@dataclass(frozen=True)
class _TwoModes:
    spec: _TwoModesSpec = _TwoModesSpec()
    data: dict = field(default_factory=lambda: {"y": jnp.zeros(1)})
    name: str = "two_modes"
    dim: int = 1
    sampled_vars: tuple = ("theta",)
    dims: dict = field(default_factory=lambda: {"theta": ["theta_dim"]})
    coords: dict = field(default_factory=lambda: {"theta_dim": ["a"]})

    def init(self, seed, n_chains):
        raise AssertionError("the test gives the initial points")


def test_a_chain_stuck_in_a_far_lower_mode_runs_again_from_the_others():
    init = np.array([[0.05], [10.0], [-0.05], [0.0]])  # the second chain starts in the trap
    with pytest.warns(CalibrationWarning, match=r"chain 2 of 4 stuck in a local mode .* "
                      r"every chain ran again, the stuck ones from the others' last draws\. "
                      ) as caught:
        idata = sample_nuts(_TwoModes(), seed=0, num_chains=4, num_warmup=200,
                            num_draws=1000, init=init)
    said = str(caught[0].message)
    assert "(mean log density 30 below the best chain's; chain 2 at a = 10" in said, said
    assert re.search(r"against a = -?0\.0\d* for chain [134]\)", said), said
    theta = idata.posterior["theta"].values[..., 0]
    assert theta.shape == (4, 1000) and idata.posterior.attrs["chains_restarted"] == "1"
    # the posterior is the main mode, N(0, 0.1^2): no draw near the trap
    assert abs(theta.mean()) < 0.02 and 0.08 < theta.std() < 0.12 and np.abs(theta).max() < 1
    summary = summarize(idata, warn=False)
    assert summary.n_chains == 4 and summary.max_r_hat < 1.01


def test_without_warn_a_stuck_chain_is_noted_not_warned():
    """A calibration in a thread (a compared variant) keeps the stuck-chain message for
    its own notes: warned, it would be read as the spec's own calibration's."""
    import warnings

    init = np.array([[0.05], [10.0], [-0.05], [0.0]])
    with warnings.catch_warnings():
        warnings.simplefilter("error", CalibrationWarning)
        idata = sample_nuts(_TwoModes(), seed=0, num_chains=4, num_warmup=200,
                            num_draws=300, init=init, warn=False)
    note = idata.posterior.attrs["stuck_note"]
    assert note.startswith("two_modes: chain 2 of 4 stuck in a local mode"), note


@dataclass(frozen=True)
class _NeedleSpec:
    """A narrow mode at -2 (sd 0.02) beside a broad one at 5 (sd 1) 200 log units lower:
    a chain started outside the narrow mode's basin (about +-0.4) settles in the broad
    one, where a prior draw lands 11 times out of 12."""

    def logdensity(self, data, u):
        narrow = -0.5 * ((u[0] + 2.0) / 0.02) ** 2
        broad = -200.0 - 0.5 * (u[0] - 5.0) ** 2
        return jnp.logaddexp(narrow, broad)

    def constrain(self, data, u):
        return {"theta": u}


@dataclass(frozen=True)
class _Needle(_TwoModes):
    spec: _NeedleSpec = _NeedleSpec()
    name: str = "needle"

    def init(self, seed, n_chains):  # a prior N(0, 3^2)
        return np.random.default_rng(seed).normal(0.0, 3.0, (n_chains, 1))


def test_each_chain_starts_from_the_best_of_many_prior_draws():
    ld = _Needle()
    starts = ld.init(0, 4)
    assert np.all(np.abs(starts + 2.0) > 0.4)  # one draw per chain: all in the broad mode
    idata = sample_nuts(ld, seed=0, num_chains=4, num_warmup=300, num_draws=300)
    theta = idata.posterior["theta"].values[..., 0]
    assert abs(theta.mean() + 2.0) < 0.004 and 0.016 < theta.std() < 0.024, (
        theta.mean(axis=1), theta.std())
    # the same chains from single draws stay in the broad mode
    idata = sample_nuts(ld, seed=0, num_chains=4, num_warmup=300, num_draws=300, init=starts)
    assert abs(idata.posterior["theta"].values.mean() - 5.0) < 0.3


def _one_mode_draws(seed=0):
    """4 chains x 500 draws of N(1, 0.01^2) in the first of two parameters, N(0, 1) in
    the second, with their log densities."""
    rng = np.random.default_rng(seed)
    pos = np.stack([1.0 + 0.01 * rng.standard_normal((4, 500)),
                    rng.standard_normal((4, 500))], axis=-1)
    lp = -0.5 * (((pos[..., 0] - 1.0) / 0.01) ** 2 + pos[..., 1] ** 2)
    return pos, lp


def test_a_plausible_point_far_from_every_chain_is_an_unvisited_mode():
    """A candidate with a log density as high as the draws' (the mirror mode at -1 of a
    symmetric density) but 200 sds from every chain is found; one in the chains' own mode,
    or one far away but less plausible than all but the rarest draws, is not."""
    pos, lp = _one_mode_draws()
    cands = np.array([[1.005, 0.3], [-1.0, 0.2], [-1.0, 0.1], [0.2, 0.0]])
    lp_c = np.array([-0.2, -0.5, -0.3, -3000.0])  # the mirror mode's as the draws'
    assert unvisited_mode(pos, lp, cands, lp_c) == 2  # the higher of the two at -1
    assert unvisited_mode(pos, lp, cands[[0, 3]], lp_c[[0, 3]]) is None
    lower = np.array([-0.2, lp.min() - 1.0, lp.min() - 2.0, -3000.0])
    assert unvisited_mode(pos, lp, cands, lower) is None
    # a far point as unlikely as the chains' rarest draws is a tail, not a mode: above
    # their lowest log density but below their 1 % quantile
    tail = np.array([-0.2, 0.5 * (lp.min() + np.quantile(lp, 0.01)), -3000.0, -3000.0])
    assert lp.min() < tail[1] < np.quantile(lp, 0.01)
    assert unvisited_mode(pos, lp, cands, tail) is None
    # the same point is no unvisited mode once a chain sits there
    pos[3, :, 0] = -1.0 + 0.01 * np.random.default_rng(1).standard_normal(500)
    assert unvisited_mode(pos, lp, cands, lp_c) is None


def test_chains_in_separate_modes_are_said_to_be_so():
    """Three chains at t = 0.6 and one at -0.6 (sd 0.004 each): R-hat fails, and the
    message says the chains sit in separate modes that more draws will not join; chains
    that merely drift (one mode) get the advice to sample longer."""
    import arviz as az

    from calnet.calibration.diagnostics import convergence_problems

    rng = np.random.default_rng(0)
    split = np.array([0.6, 0.6, 0.6, -0.6])[:, None] + 0.004 * rng.standard_normal((4, 500))
    drift = np.linspace(0, 1, 500)[None, :] * np.array([0.0, 0.1, 0.2, 0.3])[:, None] \
        + 0.05 * rng.standard_normal((4, 500))
    said = {}
    for name, draws in (("split", split), ("drift", drift)):
        idata = az.from_dict(posterior={"theta": draws[..., None]},
                             sample_stats={"diverging": np.zeros((4, 500), bool)},
                             dims={"theta": ["theta_dim"]}, coords={"theta_dim": ["t"]},
                             attrs={"model": "M"})
        said[name] = " ".join(convergence_problems(summarize(idata, warn=False)))
    apart = np.ptp(split.mean(axis=1)) / split.std(axis=1).max()  # about 1.2 / 0.004
    assert 250 < apart < 350
    assert (f"the chains sit in separate modes (their means lie {apart:.0f} within-chain "
            "sds apart)") in said["split"], said["split"]
    assert "raise settings.sampler.warmup" not in said["split"]
    assert "chains disagree - raise settings.sampler.warmup and draws" in said["drift"], \
        said["drift"]


def test_chains_of_one_mode_are_not_run_again(oracle_run):
    assert oracle_run[3].posterior.sizes["chain"] == 4
    assert oracle_run[3].posterior.attrs["chains_restarted"] == ""


def test_one_chain_gets_a_split_r_hat(caplog):
    """R-hat of a single chain compares its two halves (ArviZ alone logs that one chain
    is too few and gives NaN)."""
    idata = sample_nuts(_TwoModes(), seed=1, num_chains=1, num_warmup=200, num_draws=1000,
                        init=np.array([[0.0]]))
    summary = summarize(idata, warn=False)
    # finite and near 1 (quarters of one chain of 1000 draws: about 0.01 of Monte Carlo
    # spread), where ArviZ alone gives NaN
    assert summary.n_chains == 1 and 1.0 <= summary.max_r_hat < 1.05
    assert "Shape validation failed" not in caplog.text


def test_a_single_chain_that_has_not_converged_is_not_called_chains():
    """The R-hat warning of one chain speaks of its halves and asks for more chains."""
    from dataclasses import replace

    from calnet.calibration.diagnostics import convergence_problems

    idata = sample_nuts(_TwoModes(), seed=1, num_chains=1, num_warmup=20, num_draws=40,
                        init=np.array([[0.0]]))
    summary = summarize(idata, warn=False)
    worst = replace(summary.parameters[0], r_hat=1.05)
    (said,) = [m for m in convergence_problems(replace(summary, parameters=(worst,)))
               if "R-hat" in m]
    assert "the two halves of the only chain disagree" in said and "chains disagree" not in said
    assert "run several chains (settings.sampler.chains)" in said


@pytest.mark.parametrize(("gap", "sd", "stuck"), [
    (19.0, 1.0, [2]),  # a 2-parameter stage's trap: 19 below, 19 of its sds
    (11.0, 1.0, [2]),
    (8.0, 0.5, []),  # 16 sds, but a density ratio of only 3e3
    (25.0, 3.0, []),  # 8 sds of a 20-parameter posterior's fluctuations: one mode
    (35.0, 3.0, [2])])
def test_a_chain_is_stuck_beyond_10_log_units_and_10_sds_below_the_best(gap, sd, stuck):
    rng = np.random.default_rng(0)
    lp = rng.normal(0.0, sd, (4, 500))
    lp[2] -= gap
    assert stuck_chains(lp) == stuck


def test_a_chain_that_leaves_its_trap_late_is_stuck():
    """68 % of its draws 21 log units down, then with the others: its mean is 14 below
    theirs, its own sd (10) wide from the jump; the yardstick is the best chain's."""
    rng = np.random.default_rng(1)
    lp = rng.normal(29.0, 1.0, (4, 500))
    lp[1, :340] -= 21.0
    assert stuck_chains(lp) == [1]


@pytest.mark.parametrize("lines", [False, True])
def test_ctrl_c_while_the_chains_run_waits_for_them_then_stops(monkeypatch, capsys, lines):
    """A running XLA program cannot be stopped, and a process that ends while one runs
    can crash in its clean-up (exit 139): after Ctrl-C the sampler says so, waits for
    the program, also through a second Ctrl-C, and then raises KeyboardInterrupt. With
    progress lines that raise once Ctrl-C has arrived (calnet run's), it says so on
    stderr."""
    import jax

    from calnet.progress import Lines

    hit = []

    def write(text):  # calnet run's notes: they raise once Ctrl-C has arrived
        if hit:
            raise KeyboardInterrupt

    waits = []
    real = jax.block_until_ready

    def block(x):
        waits.append(1)
        if len(waits) <= 2:  # Ctrl-C, then Ctrl-C again while it waits
            hit.append(1)
            raise KeyboardInterrupt
        return real(x)

    monkeypatch.setattr(jax, "block_until_ready", block)
    init = np.array([[0.05], [0.0]])
    with pytest.raises(KeyboardInterrupt):
        sample_nuts(_TwoModes(), seed=0, num_chains=2, num_warmup=20, num_draws=20,
                    init=init, progress=Lines("two_modes", write) if lines else False)
    assert len(waits) == 3  # waited until the program ended
    err = capsys.readouterr().err
    assert "two_modes: stopping once the chains in flight end" in err, err


def test_a_second_ctrl_c_while_the_note_is_written_still_waits(monkeypatch):
    """A second Ctrl-C that lands while the sampler writes its "stopping once the chains
    in flight end" line is the second Ctrl-C of a wait: outside a command the sampler
    still waits for the program, then raises KeyboardInterrupt."""
    import jax

    from calnet.calibration import sampling

    waits, written = [], []
    real = jax.block_until_ready

    def block(x):
        waits.append(1)
        if len(waits) == 1:
            raise KeyboardInterrupt
        return real(x)

    def write(*args, **kwargs):
        written.append(args)
        raise KeyboardInterrupt

    monkeypatch.setattr(jax, "block_until_ready", block)
    monkeypatch.setattr(sampling, "print", write, raising=False)
    with pytest.raises(KeyboardInterrupt):
        sample_nuts(_TwoModes(), seed=0, num_chains=2, num_warmup=20, num_draws=20,
                    init=np.array([[0.05], [0.0]]), progress=False)
    assert len(written) == 1 and "stopping once the chains in flight end" in written[0][0]
    assert len(waits) == 2  # the program was waited for
