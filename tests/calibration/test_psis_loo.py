"""PSIS leave-one-out (calnet.validation.psis_loo) against independent answers.

1. One model linear in its parameters, known noise, no discrepancy, flat priors: the
   exact leave-one-out predictive of point i is Gaussian, N(J_i b_-i, s^2 (1 + J_i
   (J_-i^T J_-i)^-1 J_i^T)) with b_-i the least-squares fit without the point; PSIS
   must give its mean and 95 % interval within Monte Carlo error, and the ELPD.
2. The same model with calnet's default (orthogonal) discrepancy, where the points are
   correlated and the pointwise likelihood is the conditional p(y_i | y_-i): PSIS
   against exact refits (the observing stage re-sampled without each point).
3. Refitted points enter the ELPD with their refit's exact density (closed form of 1).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats
from test_exact_posterior import SAMPLER, build, defaults_spec, true_pq, write_case

from calnet.calibration.calibrate_network import calibrate
from calnet.spec.models import SamplerSettings
from calnet.validation import psis_loo

SD = 0.1
X3 = np.linspace(0.0, 1.0, 30)
Y3 = true_pq(X3, 0.8, 1.2) + SD * np.random.default_rng(5).standard_normal(len(X3))


def exact_loo():
    """Mean, sd (n,) of the exact LOO predictive and the exact pointwise log density."""
    J = np.column_stack([np.ones_like(X3), X3])
    r = Y3 - true_pq(X3, 0.0, 0.0)
    mean, sd = np.empty(len(X3)), np.empty(len(X3))
    for i in range(len(X3)):
        keep = np.arange(len(X3)) != i
        b = np.linalg.lstsq(J[keep], r[keep], rcond=None)[0]
        v = J[i] @ np.linalg.inv(J[keep].T @ J[keep]) @ J[i]
        mean[i] = J[i] @ b + true_pq(X3[i], 0.0, 0.0)
        sd[i] = SD * np.sqrt(1.0 + v)
    return mean, sd, stats.norm.logpdf(Y3, mean, sd)


def test_exact_loo_matches_brute_force_refit():
    mean, sd, _ = exact_loo()
    # brute force: posterior of (p, q) on a grid without point 0, then its predictive
    p = np.linspace(0.3, 1.3, 401)[:, None]
    q = np.linspace(0.4, 2.0, 401)[None, :]
    logp = sum(stats.norm.logpdf(Y3[j], true_pq(X3[j], p, q), SD) for j in range(1, len(X3)))
    w = np.exp(logp - logp.max())
    w /= w.sum()
    m = np.sum(w * true_pq(X3[0], p, q))
    v = np.sum(w * (true_pq(X3[0], p, q) - m) ** 2) + SD**2
    assert abs(m - mean[0]) < 1e-4 and abs(np.sqrt(v) / sd[0] - 1) < 1e-3


def _case(tmp_path_factory, discrepancy, x=X3, y=Y3):
    spec = defaults_spec()
    spec["data"]["obs"]["noise"] = {"sd": SD}
    if discrepancy is None:
        spec["data"]["obs"]["discrepancy"] = "none"
    root = tmp_path_factory.mktemp(f"psis_{discrepancy}")
    write_case(root, spec, {"obs.csv": {"x": x, "y": y}})
    network, sur = build(root, seed=0)
    return network, sur, calibrate(network, sur, mode="joint", seed=21, sampler=SAMPLER)


@pytest.mark.slow
def test_psis_loo_matches_the_exact_leave_one_out(tmp_path_factory):
    network, sur, post = _case(tmp_path_factory, None)
    got = psis_loo(network, sur, post, "obs", seed=3)
    mean, sd, ll = exact_loo()
    assert max(got["pareto_k"]) < 0.7 and got["refit"] == [] and got["n_unreliable"] == 0
    assert got["max_pareto_k"] == max(got["pareto_k"]) and got["k_threshold"] == 0.7
    # Monte Carlo error of a PSIS mean: about sd_post / sqrt(ESS); the posterior-only
    # part of the LOO sd is sqrt(sd^2 - SD^2), and the ESS is >= 1000 here
    err = np.sqrt(sd**2 - SD**2) / np.sqrt(1000)
    np.testing.assert_array_less(np.abs(np.asarray(got["mean"]) - mean), 4 * err + 2e-3)
    lo, hi = stats.norm.ppf([0.025, 0.975], mean[:, None], sd[:, None]).T
    # a 2.5 % quantile of 4000 mixture samples: Monte Carlo sd ~0.004 here
    np.testing.assert_allclose(got["lower95"], lo, atol=0.015)
    np.testing.assert_allclose(got["upper95"], hi, atol=0.015)
    # the sampled posterior's sd has ~2 % Monte Carlo error (ESS ~2000), which moves the
    # ELPD of 30 points by ~0.05 (a 4 % wider posterior: -0.12); PSIS's own error with
    # exact iid draws is ~0.02
    assert abs(got["elpd_loo"] - ll.sum()) < 0.2 and got["elpd_se"] > 0
    assert got["calnet"]["n"] == len(X3) and 0.5 < got["p_loo"] < 4  # two parameters
    # LOO-PIT and CRPS against the exact Gaussian LOO predictive
    z = (Y3 - mean) / sd
    np.testing.assert_allclose(got["pit"], stats.norm.cdf(z), atol=0.02)
    crps = sd * (z * (2 * stats.norm.cdf(z) - 1) + 2 * stats.norm.pdf(z) - 1 / np.sqrt(np.pi))
    assert abs(got["calnet"]["crps"] / crps.mean() - 1) < 0.03


@pytest.mark.slow
def test_refitted_points_count_with_their_exact_density_in_the_elpd(tmp_path_factory):
    """Points refitted exactly enter the ELPD, its se and p_loo with the log density of
    their refit's predictive, not the importance-sampled one: against the closed-form
    leave-one-out densities of the linear model."""
    network, sur, post = _case(tmp_path_factory, None)
    refit_sampler = SamplerSettings(chains=2, warmup=300, draws=1000)
    got = psis_loo(network, sur, post, "obs", seed=3, sampler=refit_sampler, k_max=-1.0,
                   refit_max=3)
    _, _, ll = exact_loo()
    pointwise = np.asarray(got["elpd_pointwise"])
    assert len(got["refit"]) == 3 and pointwise.shape == (len(X3),)
    # a refit's density, a mixture over 100 draws of a posterior 5x narrower than the
    # noise: within a few hundredths of the exact Gaussian's
    np.testing.assert_allclose(pointwise[got["refit"]], ll[got["refit"]], atol=0.05)
    assert got["elpd_loo"] == pytest.approx(pointwise.sum(), abs=1e-9)
    assert got["elpd_se"] == pytest.approx(np.sqrt(len(X3) * np.var(pointwise)), abs=1e-9)
    assert abs(got["elpd_loo"] - ll.sum()) < 0.2 and 0.5 < got["p_loo"] < 4
    # every point is over k_max = -1: listed highest k first, by its input and measurement
    infl = got["influential"]
    assert [p["point"] for p in infl] == list(np.argsort(-np.asarray(got["pareto_k"]),
                                                         kind="stable"))
    assert {p["point"] for p in infl if p["refit"]} == set(got["refit"])
    assert all(p["inputs"]["x"] == X3[p["point"]] and p["y"] == Y3[p["point"]] for p in infl)


@pytest.mark.slow
def test_psis_loo_with_discrepancy_agrees_with_exact_refits(tmp_path_factory):
    # the simulator misses a wave that the discrepancy must carry: the points are
    # correlated through it, and a point's LOO predictive leans on its neighbours
    x = np.linspace(0.0, 1.0, 12)
    y = (true_pq(x, 0.8, 1.2) + 0.3 * np.sin(2 * np.pi * x)
         + SD * np.random.default_rng(6).standard_normal(12))
    network, sur, post = _case(tmp_path_factory, "default", x, y)
    psis = psis_loo(network, sur, post, "obs", seed=3)
    refit_sampler = SamplerSettings(chains=2, warmup=300, draws=1000)
    exact = psis_loo(network, sur, post, "obs", seed=3, sampler=refit_sampler, k_max=-1.0)
    assert exact["refit"] == list(range(12))  # every point re-sampled without it
    width = np.asarray(exact["upper95"]) - np.asarray(exact["lower95"])
    # the two LOO means differ by Monte Carlo error only: a few % of the LOO band
    np.testing.assert_array_less(np.abs(np.asarray(psis["mean"]) - exact["mean"]),
                                 0.05 * width)
    np.testing.assert_allclose(np.asarray(psis["upper95"]) - psis["lower95"], width,
                               rtol=0.15)


@pytest.mark.slow
def test_compare_says_whether_the_discrepancy_is_needed(tmp_path_factory):
    """A simulator that misses a wave: the discrepancy model predicts the left-out points
    far better than the same model without it (an ELPD difference of more than two
    standard errors, nearly all the stacking weight);
    a correct simulator: the two are within a few standard errors."""
    from calnet.validation import compare_variants

    x = np.linspace(0.0, 1.0, 20)
    noise = SD * np.random.default_rng(8).standard_normal(20)
    fast = SamplerSettings(chains=2, warmup=300, draws=1000)
    results = {}
    for wave in (0.4, 0.0):
        y = true_pq(x, 0.8, 1.2) + wave * np.sin(2 * np.pi * x) + noise
        network, sur, post = _case(tmp_path_factory, "default", x, y)
        results[wave] = compare_variants(network, sur, post, ("no_discrepancy",),
                                         sampler=fast, seed=2)["obs"]
    wave = results[0.4]
    assert wave["spec"].elpd_diff == 0.0 and wave["spec"].weight > 0.9
    assert wave["no_discrepancy"].elpd_diff > 2 * wave["no_discrepancy"].dse
    flat = results[0.0]
    worse = max(flat["spec"].elpd_diff, flat["no_discrepancy"].elpd_diff)
    assert worse < 3 * max(flat["spec"].dse, flat["no_discrepancy"].dse, 0.5)


@pytest.mark.slow
def test_pit_check_flags_a_known_wrong_model(tmp_path_factory):
    """No discrepancy and a simulator that misses a wave five noise sds high: the LOO
    predictive is far too narrow and the PIT check says so; the correct model of the
    first test passes it."""
    x = np.linspace(0.0, 1.0, 20)
    y = (true_pq(x, 0.8, 1.2) + 0.5 * np.sin(2 * np.pi * x)
         + SD * np.random.default_rng(9).standard_normal(20))
    network, sur, post = _case(tmp_path_factory, None, x, y)
    wrong = psis_loo(network, sur, post, "obs", seed=3)["pit_check"]
    assert wrong["flagged"] and "too narrow" in wrong["message"], wrong
    network, sur, post = _case(tmp_path_factory, None)
    right = psis_loo(network, sur, post, "obs", seed=3)["pit_check"]
    assert not right["flagged"] and right["ks_pvalue"] > 0.05, right


def test_pit_check_on_known_pit_values():
    from calnet.validation import PIT_P_MIN, pit_check

    rng = np.random.default_rng(0)
    assert not pit_check("d", rng.uniform(size=200))["flagged"]
    narrow = pit_check("d", np.concatenate([rng.uniform(0, 0.01, 30), rng.uniform(0.99, 1, 30)]))
    assert narrow["flagged"] and "too narrow" in narrow["message"]
    # flagged by the count outside the band: the message quotes that test's p-value
    four = pit_check("d", np.r_[0.01, 0.99, 0.005, 0.98, np.linspace(0.1, 0.9, 8)])
    assert four["flagged"] and four["ks_pvalue"] > 0.1 and four["outside_pvalue"] < 0.01
    assert (f"4 of 12 points outside its 95 % band where 0.6 are expected, "
            f"p = {four['outside_pvalue']:.2g}; PIT uniformity p = "
            f"{four['ks_pvalue']:.2g}") in four["message"], four["message"]
    wide = pit_check("d", rng.uniform(0.4, 0.6, 60))
    assert wide["flagged"] and "too wide" in wide["message"]
    # 26 of 30 in the central half (the case study's widths): too wide by the count
    # inside the 50 % band, which the KS test alone misses
    half = pit_check("d", np.r_[np.linspace(0.26, 0.74, 26), 0.1, 0.2, 0.8, 0.9])
    assert half["ks_pvalue"] > PIT_P_MIN and half["inside50"] == 26 and half["too_wide"]
    assert half["inside50_pvalue"] == pytest.approx(stats.binom.sf(25, 30, 0.5))
    assert half["flagged"] and half["message"].startswith(
        "d: the leave-one-out predictive is too wide (26 of 30 points inside its central "
        "50 % band where 15.0 are expected"), half["message"]
    assert "priors may be too generous" in half["message"]
    # a known noise and no discrepancy: no prior to blame
    known = pit_check("d", np.r_[np.linspace(0.26, 0.74, 26), 0.1, 0.2, 0.8, 0.9], fixed=True)
    assert known["too_wide"] and "priors" not in known["message"]
    assert "the declared noise sd may be larger than these data's scatter" in known["message"]


def test_fit_check_on_known_pit_values():
    """The in-sample check: a binomial test of the calibration points outside the
    posterior predictive's 95 % band (a well-specified model's band covers at least 95 %
    of the points it has seen)."""
    from calnet.validation import fit_check

    nine = fit_check("d", np.r_[np.full(5, 0.001), np.full(4, 0.999), np.full(7, 0.5)])
    assert nine["flagged"] and (nine["outside95"], nine["n"]) == (9, 16)
    assert nine["outside_pvalue"] == pytest.approx(stats.binom.sf(8, 16, 0.05))
    assert nine["message"].startswith("d: the posterior predictive misses its own "
                                      "calibration points (9 of 16 outside its 95 % band")
    one = fit_check("d", np.r_[0.001, np.full(15, 0.5)])
    assert not one["flagged"] and one["message"] == ""
    assert not fit_check("d", np.zeros(0))["flagged"]  # no calibration points: no test


def test_the_comparison_scores_the_spec_with_its_refitted_pointwise_elpd():
    """The comparison takes the spec's pointwise ELPD with its refits (the leave-one-out
    table's numbers), and the standard error of a pair's difference is ArviZ's."""
    import arviz as az

    from calnet.validation import _pair_se, _with_pointwise

    rng = np.random.default_rng(0)
    loos = [az.loo(az.from_dict(log_likelihood={"d": rng.normal(m, 1.0, (1, 400, 9))}),
                   pointwise=True, reff=1.0) for m in (0.0, -0.3)]
    refitted = np.asarray(loos[0]["loo_i"]).copy()
    refitted[4] -= 7.0  # an outlier's exact density, far below its PSIS value
    new = _with_pointwise(loos[0], refitted)
    assert new["elpd_loo"] == pytest.approx(refitted.sum())
    assert new["se"] == pytest.approx(np.sqrt(9 * np.var(refitted)))
    lppd = float(loos[0]["elpd_loo"] + loos[0]["p_loo"])
    assert new["p_loo"] == pytest.approx(lppd - refitted.sum())
    table = az.compare({"spec": new, "other": loos[1]}, ic="loo")
    worse = table.index[1]
    assert table.loc[worse, "dse"] == pytest.approx(
        _pair_se(np.asarray(new["loo_i"]), np.asarray(loos[1]["loo_i"])))


def test_a_refitted_points_pareto_k_no_longer_counts():
    from calnet.validation import _max_k

    khat = np.array([0.2, 1.3, 0.5, 0.9])
    assert _max_k(khat, []) == 1.3 and _max_k(khat, [1]) == 0.9
    assert _max_k(khat, [1, 3]) == 0.5 and _max_k(khat[:1], [0]) == 0.0


def test_the_loo_band_is_the_mixtures_own_quantiles():
    """The LOO band's ends are the mixture's 2.5 and 97.5 % quantiles, so a point lies
    outside the band exactly when its LOO-PIT is in the tails."""
    from calnet.validation import _mixture_quantile

    one = _mixture_quantile(np.array([1.0]), np.array([2.0]), np.array([0.5]), 0.975)
    assert one == pytest.approx(stats.norm.ppf(0.975, 2.0, 0.5), abs=1e-10)
    w, m, s = np.array([0.3, 0.7]), np.array([0.0, 3.0]), np.array([1.0, 0.2])
    for p in (0.025, 0.5, 0.975):
        q = _mixture_quantile(w, m, s, p)
        assert w @ stats.norm.cdf((q - m) / s) == pytest.approx(p, abs=1e-10)


def test_the_refits_of_a_data_set_warn_each_kind_once():
    """Each exact refit is a calibration of its own, and their warnings are alike but for
    the chain and the numbers: one of each kind, with how many refits gave it."""
    import warnings

    from calnet.errors import CalibrationWarning
    from calnet.validation import _once_per_kind

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with _once_per_kind("exact leave-one-out refits of obs"):
            for chain, gap in ((1, 81), (2, 176), (1, 95)):
                warnings.warn(f"C LOO: chain {chain} of 2 stuck in a local mode (mean log "
                              f"density {gap} below the best chain's)", CalibrationWarning,
                              stacklevel=1)
            warnings.warn("C LOO: R-hat 1.02 > 1.01 for C.c", CalibrationWarning, stacklevel=1)
            warnings.warn("something else", UserWarning, stacklevel=1)
    said = [(w.category, str(w.message)) for w in caught]
    assert said == [
        (CalibrationWarning, "C LOO: chain 1 of 2 stuck in a local mode (mean log density 81 "
                             "below the best chain's) (3 of the exact leave-one-out refits "
                             "of obs said so)"),
        (CalibrationWarning, "C LOO: R-hat 1.02 > 1.01 for C.c"),
        (UserWarning, "something else")]


def test_the_misfit_hint_names_what_to_try():
    from pathlib import Path

    from calnet.spec import load_spec
    from calnet.validation import misfit_hint, variant

    twodata = load_spec(Path(__file__).parents[1] / "integration" / "twodata")
    said = misfit_hint(twodata, "d1", surrogate_warned=False)
    assert said == ("; d2 also observes 'M': data sets that pull its parameters apart each "
                    "show misfit (the one that fits may be flagged too); calibrating with "
                    "each alone shows which"), said
    said = misfit_hint(variant(twodata, "no_discrepancy"), "d2", surrogate_warned=True)
    assert said.startswith("; its spec sets discrepancy: none; the default discrepancy (or "
                           "settings.compare: [reference]) would show whether one is needed; "
                           "the surrogate check warns for it too"), said
    said = misfit_hint(twodata, "d1", surrogate_warned=False, unconverged=1.527)
    assert said.startswith("; its calibration did not converge (R-hat 1.53): these checks "
                           "inherit that, so fix the sampling first; d2 also observes"), said


def test_held_out_check_on_known_pit_values():
    """The held-out check: the count outside the 95 % band and Bonferroni's bound on the
    most extreme point, whose p-value is the point's two-sided tail probability times
    the number of points (at least half a sample's share: a PIT from samples)."""
    from calnet.validation import PIT_P_MIN, held_out_check

    S = 4000
    # one point beyond every sample among four: p = 4 x 2 x (0.5 / S)
    far = held_out_check("d", np.r_[0.0, 0.3, 0.5, 0.7], ["x=0.1", "x=0.4", "x=0.6", "x=0.9"],
                         n_samples=S)
    assert far["flagged"] and far["extreme_index"] == 0
    assert far["extreme_pvalue"] == pytest.approx(4 * 2 * 0.5 / S)
    assert far["outside95"] == 1 and far["outside_pvalue"] > PIT_P_MIN  # the count misses it
    assert ("the test point at x=0.1 lies below every sample of its predictive, "
            f"p = {4 / S:.2g} for the most extreme of 4") in far["message"], far["message"]
    high = held_out_check("d", np.r_[0.9995, 0.3, 0.5], n_samples=S)
    assert high["extreme_pvalue"] == pytest.approx(3 * 2 * 0.0005)
    assert "at 1 lies above 0.9995 of its predictive's samples" in high["message"]
    assert not held_out_check("d", np.r_[0.02, 0.5, 0.97], n_samples=S)["flagged"]
    assert not held_out_check("d", np.zeros(0), n_samples=S)["flagged"]
    # an exact PIT (the predictive mixture's distribution function) has no floor: with
    # 40 points, one at z = 4.5 (two-sided tail 6.8e-6) is flagged by Bonferroni's bound,
    # which a PIT from 4000 samples could not do (its floor alone gives p = 0.01)
    tail = 2 * stats.norm.sf(4.5)
    pit = np.r_[stats.norm.cdf(4.5), np.linspace(0.1, 0.9, 39)]
    exact = held_out_check("d", pit)
    assert exact["flagged"] and exact["extreme_index"] == 0
    assert exact["extreme_pvalue"] == pytest.approx(40 * tail, rel=1e-6)
    assert f"at 1 lies above all but {tail / 2:.2g} of its predictive" in exact["message"]
    assert not held_out_check("d", pit, n_samples=S)["flagged"]


def test_held_out_check_keeps_its_false_alarm_rate():
    """Under a calibrated predictive (uniform PIT values, resolved to 1 / S) the check
    flags at most about the sum of its two tests' levels, 2 %, at every size; a
    predictive three times too narrow is flagged most of the time from 10 points."""
    from calnet.validation import held_out_check

    rng = np.random.default_rng(1)
    S, reps = 4000, 3000
    for n in (1, 4, 10, 40):
        pits = np.floor(rng.uniform(size=(reps, n)) * (S + 1)) / S
        rate = np.mean([held_out_check("d", p, n_samples=S)["flagged"] for p in pits])
        assert rate < 0.02 + 3 * np.sqrt(0.02 / reps), (n, rate)
    narrow = stats.norm.cdf(3.0 * rng.standard_normal((300, 10)))
    assert np.mean([held_out_check("d", p, n_samples=S)["flagged"] for p in narrow]) > 0.8
    for n in (1, 10, 40):  # exact PIT values
        rate = np.mean([held_out_check("d", p)["flagged"]
                        for p in rng.uniform(size=(reps, n))])
        assert rate < 0.02 + 3 * np.sqrt(0.02 / reps), (n, rate)


def test_a_variants_note_does_not_advise_more_draws_than_it_can_take():
    """The compared variants sample at most 2 chains of 500 draws: a low ESS of a variant
    does not send the user to settings.sampler.draws when they are past that cap."""
    from calnet.calibration.diagnostics import MORE_DRAWS
    from calnet.validation import _variant_note

    note = f"m: bulk ESS 328 < 400 for m.a; {MORE_DRAWS}"
    capped = _variant_note(note, SamplerSettings(chains=4, warmup=500, draws=1000))
    assert capped == ("m: bulk ESS 328 < 400 for m.a; the variants compared sample 2 chains "
                      "of 500 draws whatever settings.sampler says, so its ELPD carries more "
                      "Monte Carlo error than the spec's")
    at_cap = _variant_note(note, SamplerSettings(chains=4, warmup=500, draws=500))
    assert at_cap == capped  # 500 draws are the variants' cap already
    few = SamplerSettings(chains=4, warmup=500, draws=200)
    assert _variant_note(note, few) == note  # more draws would reach the variants too
    assert _variant_note("m: 3 divergent transitions", few) == "m: 3 divergent transitions"
