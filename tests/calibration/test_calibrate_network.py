"""Network calibration (segmented and joint) on small analytic two-model networks.

Oracle for the agreement test: the link carries an upstream output that does not depend
on the upstream parameter, so the downstream data carry no information about it and the
joint posterior factorises into p(a | upstream data) p(b | downstream data), which is
exactly what the segmented calibration computes. Joint and segmented must then agree
within Monte Carlo error (tolerances from the effective sample sizes).
"""

from __future__ import annotations

import csv
import re
import textwrap
import warnings
from dataclasses import replace

import numpy as np
import pytest
from network_helpers import fitted_network, on_path, write_csv

from calnet.calibration.calibrate_network import calibrate
from calnet.calibration.persist import load_posterior, save_posterior
from calnet.errors import CalibrationError, CalibrationWarning
from calnet.spec import load_spec, read_all
from calnet.spec.models import SamplerSettings

SIMS = '''
def up(inputs):
    x, a = inputs["x"], inputs["a"]
    return {"y": a * (1.0 + x) + 0.3 * x * x, "z": 1.0 + x}


def down(inputs):
    s, b = inputs["s"], inputs["b"]
    return {"w": b * s * s - 0.5 * s}
'''

SPEC = '''
name: indep
models:
  up:
    simulator: python:indep_sims:up
    inputs: {x: {lower: 0, upper: 1}}
    parameters: {a: {lower: 0.5, upper: 1.5}}
    outputs: {y: {measurable: true}, z: {}}
    campaign: {runs: 30}
  down:
    simulator: python:indep_sims:down
    inputs: {s: {lower: 1, upper: 2}}
    parameters: {b: {lower: 0.5, upper: 1.5}}
    outputs: {w: {measurable: true}}
    campaign: {runs: 20}
links:
  - {from: up.z, to: down.s}
data:
  ydata: {path: y.csv, observes: up.y, columns: {x: x, y: y}}
  wdata: {path: w.csv, observes: down.w, columns: {x: x, w: w}}
settings:
  seed: 11
  surrogate: {cv_folds: 5, restarts: 2}
  sampler: {chains: 2, warmup: 300, draws: 300}
'''

A_TRUE, B_TRUE = 1.1, 0.9


@pytest.fixture(scope="module")
def indep(tmp_path_factory):
    root = tmp_path_factory.mktemp("indep")
    (root / "indep_sims.py").write_text(SIMS)
    (root / "network.yaml").write_text(textwrap.dedent(SPEC))
    rng = np.random.default_rng(5)
    x = np.linspace(0.05, 0.95, 8)
    y = A_TRUE * (1 + x) + 0.3 * x**2 + 0.02 * rng.standard_normal(8)
    s = 1 + x
    w = B_TRUE * s**2 - 0.5 * s + 0.05 * rng.standard_normal(8)
    write_csv(root / "y.csv", x=x, y=y)
    write_csv(root / "w.csv", x=x, w=w)
    with on_path(root):
        network, sur = fitted_network(root)
        yield network, sur, root


SAMPLER = SamplerSettings(chains=2, warmup=500, draws=1000, target_accept=0.95)


@pytest.fixture(scope="module")
def both(indep):
    network, sur, _ = indep
    seg = calibrate(network, sur, mode="segmented", plug="posterior", sampler=SAMPLER, seed=2)
    joint = calibrate(network, sur, mode="joint", sampler=SAMPLER, seed=3)
    return seg, joint


def _ess(draws: np.ndarray) -> float:
    import arviz as az

    return float(az.ess(draws.reshape(SAMPLER.chains, -1)))


def _width(draws: np.ndarray) -> tuple[float, float]:
    """Central 68 % width of draws and its Monte Carlo standard error (ArviZ)."""
    import arviz as az

    chains = draws.reshape(SAMPLER.chains, -1)
    lo, hi = np.percentile(draws, [15.87, 84.13])
    se = np.hypot(float(az.mcse(chains, method="quantile", prob=0.1587)),
                  float(az.mcse(chains, method="quantile", prob=0.8413)))
    return float(hi - lo), se


def test_joint_and_segmented_agree_when_downstream_is_uninformative(both):
    seg, joint = both
    assert len(seg.stages) == 2 and len(joint.stages) == 1
    for model in ("up", "down"):
        j = joint.theta[model][:, 0]
        stage = [st for st in seg.stages if st.models == (model,)][0]
        s_raw = stage.draws(f"theta_{model}")[:, 0]  # before resampling to a common count
        ess_s, ess_j = _ess(s_raw), _ess(j)
        se = np.sqrt(s_raw.var() / ess_s + j.var() / ess_j)
        assert abs(s_raw.mean() - j.mean()) < 4 * se, (model, s_raw.mean(), j.mean(), se)
        # spread: the central 68 % width, with the Monte Carlo error of its two quantiles
        # (the posterior has heavier than normal tails when the noise is unknown)
        (w_s, se_s), (w_j, se_j) = _width(s_raw), _width(j)
        assert abs(w_s - w_j) < 4 * np.hypot(se_s, se_j), (model, w_s, w_j)
        assert seg.theta[model].shape == seg.theta["up"].shape  # draws aligned across models


def test_twin_values_are_recovered(both):
    for post in both:
        for model, true in (("up", A_TRUE), ("down", B_TRUE)):
            lo, hi = np.percentile(post.theta[model][:, 0], [2.5, 97.5])
            assert lo <= true <= hi, (post.mode, model, lo, hi)


def test_posterior_round_trips_through_disk(both, indep, tmp_path):
    network = indep[0]
    seg = replace(both[0], info=("how a stage was set up",))
    save_posterior(seg, tmp_path)
    back = load_posterior(tmp_path, network)
    assert back.mode == "segmented" and back.plug == "posterior"
    assert back.info == seg.info and back.notes == seg.notes
    for m in seg.theta:
        np.testing.assert_array_equal(back.theta[m], seg.theta[m])
    for ds in seg.hyper:
        for h in seg.hyper[ds]:
            np.testing.assert_array_equal(back.hyper[ds][h], seg.hyper[ds][h])
        np.testing.assert_array_equal(back.data[ds].x, seg.data[ds].x)
        np.testing.assert_array_equal(back.data[ds].y, seg.data[ds].y)


def test_a_folder_holds_one_posterior(both, indep, tmp_path):
    """A joint posterior saved where a segmented one was replaces its stage files (the
    folder would otherwise hold both modes' netCDFs); other files are left alone."""
    network = indep[0]
    seg, joint = both
    save_posterior(seg, tmp_path, network)
    assert sorted(p.name for p in tmp_path.glob("*.nc")) == ["down.nc", "up.nc"]
    (tmp_path / "mine.nc").write_text("a user's file")
    save_posterior(joint, tmp_path, network)
    assert sorted(p.name for p in tmp_path.glob("*.nc")) == ["mine.nc", "up+down.nc"]
    assert load_posterior(tmp_path, network).mode == "joint"


def test_loading_a_posterior_checks_the_spec(both, indep, tmp_path):
    network, _, root = indep
    with pytest.raises(CalibrationError, match="no calibrated posterior"):
        load_posterior(tmp_path / "nothing", network)
    save_posterior(both[0], tmp_path)
    changed = root / "changed.yaml"
    changed.write_text(textwrap.dedent(SPEC).replace("ydata:", "yd:"))
    with pytest.raises(CalibrationError, match="ydata"):
        load_posterior(tmp_path, load_spec(changed))


@pytest.mark.parametrize("setting, word", [("discrepancy: none", "discrepancy"),
                                           ("noise: {sd: 0.1}", "noise")])
def test_a_posterior_is_not_read_under_other_noise_or_discrepancy(both, indep, tmp_path,
                                                                  setting, word):
    network, _, root = indep
    save_posterior(both[0], tmp_path, network)
    load_posterior(tmp_path, network)  # the spec it was calibrated with
    changed = root / f"changed_{word}.yaml"
    changed.write_text(textwrap.dedent(SPEC).replace(
        "columns: {x: x, y: y}}", "columns: {x: x, y: y}, " + setting + "}"))
    with pytest.raises(CalibrationError, match=f"calibrated with other {word} settings for "
                       "data set 'ydata'"):
        load_posterior(tmp_path, load_spec(changed))


def test_every_data_set_with_other_settings_is_named(both, indep, tmp_path):
    network, _, root = indep
    save_posterior(both[0], tmp_path, network)
    changed = root / "changed_both.yaml"
    text = textwrap.dedent(SPEC)
    for cols in ("columns: {x: x, y: y}}", "columns: {x: x, w: w}}"):
        text = text.replace(cols, cols[:-1] + ", noise: {sd: 0.1}}")
    changed.write_text(text)
    with pytest.raises(CalibrationError) as err:
        load_posterior(tmp_path, load_spec(changed))
    said = str(err.value)
    assert "noise settings for data set 'ydata'" in said
    assert "and other noise settings for data set 'wdata'" in said
    # in words, not field names: the default prior is named, not "none"
    assert ("(noise sd sampled, prior half-normal (scale: the observations' sd); "
            "discrepancy orthogonal to the model's parameters") in said
    assert "there; noise sd 0.1 (known); discrepancy orthogonal" in said and "none" not in said


@pytest.mark.parametrize("old, new, said", [
    ("parameters: {a: {lower: 0.5, upper: 1.5}}", "parameters: {a: {lower: 0.5, upper: 3}}",
     "model 'up' (parameters)"),
    ("outputs: {w: {measurable: true}}", "outputs: {w: {measurable: true, transform: log}}",
     "model 'down' (outputs)"),
    ("campaign: {runs: 20}", "campaign: {runs: 40}", None),  # the saved surrogates stand
])
def test_a_posterior_is_not_read_with_other_models(both, indep, tmp_path, old, new, said):
    network, _, root = indep
    save_posterior(both[0], tmp_path, network)
    changed = root / "changed_model.yaml"
    changed.write_text(textwrap.dedent(SPEC).replace(old, new))
    if said is None:
        load_posterior(tmp_path, load_spec(changed))
        return
    with pytest.raises(CalibrationError, match=r"calibrated with another spec: "
                       + re.escape(said) + " differ"):
        load_posterior(tmp_path, load_spec(changed))


def test_prediction_matches_calibration_data_scale(both, indep):
    from calnet.predict import predict

    network, sur, _ = indep
    seg = both[0]
    data = read_all(network)["wdata"]
    pred = predict(network, sur, seg, "wdata", data.x, n_draws=100, seed=0)
    # the KOH predictive at the training points follows the data within the noise
    assert np.all((pred.lower < pred.mean) & (pred.mean < pred.upper))
    # A new measurement is a mixture over draws of N(mu_d, v_d + se2_d). If a share 0.95
    # of the components have sd >= s (s^2 = the 5 % quantile of se2), the mixture's
    # central 95 % interval has a half-width >= 1.94 s (P(|Z| <= h / s) >= 0.90 / 0.95);
    # 1.8 s allows for the percentiles of 2000 predictive samples (~0.06 s each).
    s = np.sqrt(np.quantile(np.asarray(seg.hyper["wdata"]["se2"]), 0.05))
    assert np.all(0.5 * (pred.upper - pred.lower) >= 1.8 * s), (pred.upper - pred.lower, s)
    assert np.mean((data.y >= pred.lower) & (data.y <= pred.upper)) >= 0.75
    assert set(pred.budget) == {"parameters", "emulator up.z", "emulator down.w",
                                "discrepancy", "noise"}


@pytest.mark.slow
def test_calibrate_command_writes_posteriors_summary_and_plots(indep, tmp_path):
    import json

    from typer.testing import CliRunner

    from calnet.cli import app

    network, sur, root = indep
    sur.save(tmp_path / "surrogates")
    out = tmp_path / "posterior"
    res = CliRunner().invoke(app, ["calibrate", str(root), "--surrogates",
                                   str(tmp_path / "surrogates"), "--out", str(out),
                                   "--mode", "joint"])
    assert res.exit_code == 0, res.output
    for rel in ("up+down.nc", "network_posterior.json", "network_posterior.npz",
                "summary.json", "posterior_up.png", "posterior_down.png",
                "posterior_draws.csv", "posterior_summary.csv"):
        assert (out / rel).is_file(), rel
    assert "joint calibration" in res.output and "R-hat" in res.output
    # no terminal: progress as plain lines, from the start to the end of each stage
    assert "calibrating ..." in res.output and "calibrating: done in" in res.output
    assert re.search(r"calibrating: up\+down: (compiled in [\d.]+ s; )?sampling 2 chains x "
                     r"\(300 warm-up \+ 300\) iterations \(0 s\)", res.output), res.output
    assert "calibrating: up+down: sampled (" in res.output
    assert "\r" not in res.output
    summary = json.loads((out / "summary.json").read_text())
    row = summary["up"]["parameters"]["a"]
    assert row["lower"] == 0.5 and row["upper"] == 1.5 and row["q2.5"] < row["q97.5"]
    assert summary["seed"] == network.settings.seed  # the chains' seed (--seed changes it)
    post = load_posterior(out, network)
    assert post.mode == "joint"
    # the CSVs hold the same draws and summary as the posterior and summary.json
    with open(out / "posterior_draws.csv", newline="") as fh:
        draws = [float(r["up.a"]) for r in csv.DictReader(fh)]
    assert np.allclose(draws, np.asarray(post.theta["up"])[:, 0])
    with open(out / "posterior_summary.csv", newline="") as fh:
        rows = {(r["model"], r["parameter"]): r for r in csv.DictReader(fh)}
    assert float(rows["up", "a"]["mean"]) == pytest.approx(row["mean"])
    assert "is the posterior of the run" not in res.output
    # into a calnet run folder's posterior: the run's report and metrics are now stale
    (tmp_path / "metrics.json").write_text("{}")
    res = CliRunner().invoke(app, ["calibrate", str(root), "--surrogates",
                                   str(tmp_path / "surrogates"), "--out", str(out),
                                   "--mode", "segmented"], terminal_width=400)
    assert res.exit_code == 0, res.output
    assert (f"warning: {out} is the posterior of the run in '{tmp_path.resolve()}', whose "
            "metrics.json describe the posterior this calibration replaced (calnet predict "
            "--run reads the new one); calnet run SPEC --out "
            f"{tmp_path.resolve()} writes them again") in res.stderr, res.stderr
    assert sorted(p.name for p in out.glob("*.nc")) == ["down.nc", "up.nc"]


@pytest.mark.slow
def test_a_short_run_warns_about_its_diagnostics(indep):
    network, sur, _ = indep
    short = SamplerSettings(chains=2, warmup=10, draws=20)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        calibrate(network, sur, mode="joint", sampler=short, seed=4)
    messages = [str(w.message) for w in caught if issubclass(w.category, CalibrationWarning)]
    assert any("bulk ESS" in m and "< 400" in m for m in messages), messages
    stage = "+".join(m for m in network.order if network.model(m).parameters)
    assert all(m.startswith(f"{stage}: ") for m in messages)  # names the stage
    # in the user's words: model.parameter or the data set's discrepancy/noise, not the
    # sampler's variable names
    assert not any(re.search(r"\b(theta|ell|sd2|se2)_", m) for m in messages), messages


@pytest.mark.slow
@pytest.mark.parametrize("plug", ["posterior", "mode"])
def test_segmented_calibrates_an_upstream_model_without_data_with_the_data_after_it(
        indep, plug):
    """'up' has no data of its own; its parameter acts on 'down''s data through the link,
    so the stage of 'down' calibrates it: with no other data, that stage is the joint
    calibration (the same draws for the same stage seed: segmented stage i samples with
    seed + i, and 'down' is the second model)."""
    network, sur, _ = indep
    train = {"wdata": read_all(network)["wdata"]}
    short = SamplerSettings(chains=2, warmup=50, draws=50)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", CalibrationWarning)
        post = calibrate(network, sur, data=train, mode="segmented", plug=plug,
                         sampler=short, seed=5)
        joint = calibrate(network, sur, data=train, mode="joint", sampler=short, seed=6)
    assert post.prior_only == () and [s.models for s in post.stages] == [("up", "down")]
    assert post.stages[0].moved_by == ()  # nothing upstream is held fixed
    for m in ("up", "down"):
        np.testing.assert_array_equal(post.theta[m], joint.theta[m])
    said = [str(w.message) for w in caught]
    # how the stage was set up is said (post.info), not warned
    assert any(m.startswith("'up' has no data of its own: its parameters ['a'] are "
                            "calibrated in stage 'up+down' with the data of 'down' "
                            "downstream") for m in post.info), post.info
    assert not any("has no data of its own" in m for m in said), said
    assert any(m.startswith("up+down: ") for m in said), said  # the stage's own warnings
    from calnet.calibration.summary import posterior_summary

    row = posterior_summary(network, post)["up"]
    assert row["stage"] == "up+down" and row["datasets"] == ["wdata"]


def test_stage_timings_reach_the_posterior_not_its_summary(both, indep):
    """Timings are in the posterior (and run_info.json), not in the summary that goes to
    metrics.json, which is the same for the same seed."""
    from calnet.calibration.summary import posterior_summary

    seg = both[0]
    assert set(seg.timings) == {"stage_up", "stage_down"}
    assert all(t > 0 for t in seg.timings.values()), seg.timings
    summary = posterior_summary(indep[0], seg)
    assert not any("time" in key for m in ("up", "down") for key in summary[m]), summary


def test_the_summary_reads_the_diagnostics_the_calibration_computed(both, indep):
    """R-hat and ESS are computed once, for the convergence check while calibrating; the
    summary built from them equals one recomputed from the draws. A stage moved by linear
    response (plug="posterior") keeps its sampler's diagnostics, which its warnings gave."""
    from dataclasses import replace

    from calnet.calibration.summary import posterior_summary

    seg, joint = both
    assert all(s.diagnostics is not None for post in both for s in post.stages)
    assert [s.moved_by for s in seg.stages] == [(), ("up.a",)]  # down was moved
    for post in (seg, joint):
        fresh = replace(post, stages=tuple(s if s.moved_by else replace(s, diagnostics=None)
                                           for s in post.stages))
        assert posterior_summary(indep[0], fresh) == posterior_summary(indep[0], post)


def test_the_prior_panels_show_each_parameters_prior_density(both, indep):
    """The prior curve of the prior-vs-posterior figure is the parameter's prior density:
    the default Beta(1.1, 1.1) on its range, against SciPy's."""
    from scipy import stats

    from calnet.calibration.summary import calibration_result

    network = indep[0]
    result = calibration_result(network, both[1])
    for model in ("up", "down"):
        (panel,) = result.panels[model]
        p = network.model(model).parameters[0]
        want = stats.beta(1.1, 1.1, loc=p.lower, scale=p.upper - p.lower).pdf(panel.prior_x)
        assert panel.prior_x[0] == p.lower and panel.prior_x[-1] == p.upper
        np.testing.assert_allclose(panel.prior_y, want, rtol=1e-10, atol=1e-12)
        assert panel.posterior_samples.shape == (both[1].n_draws,)


def test_a_dense_mass_matrix_is_a_sampler_setting(indep, monkeypatch):
    """``settings.sampler.dense_mass`` reaches the sampler (whose dense-mass draws are
    checked against a closed-form posterior in test_cal_sampling.py)."""
    import calnet.calibration.calibrate_network as cn

    network, sur, _ = indep
    seen = []

    class Stop(Exception):
        pass

    def spy(ld, **kwargs):
        seen.append(kwargs["dense_mass"])
        raise Stop

    monkeypatch.setattr(cn, "sample_nuts", spy)
    for dense in (False, True):
        with pytest.raises(Stop):
            calibrate(network, sur, mode="joint", seed=3,
                      sampler=SamplerSettings(chains=2, warmup=20, draws=20, dense_mass=dense))
    assert seen == [False, True]


def test_each_data_set_s_noise_and_discrepancy_are_summarised(both, indep):
    """The noise and discrepancy sds are the square roots of the sampled variances, in
    the data's units, and the length scales are named by the model's inputs."""
    from calnet.calibration.summary import data_set_summary

    network, _, _ = indep
    post = both[1]  # joint: one stage samples both data sets' terms
    out = data_set_summary(network, post)
    assert set(out) == {"ydata", "wdata"}
    p = post.stages[0].idata.posterior
    for ds in ("ydata", "wdata"):
        for name, var in (("noise_sd", "se2"), ("discrepancy_sd", "sd2")):
            sd = np.sqrt(np.asarray(p[f"{var}_{ds}"]).ravel())
            assert out[ds][name]["mean"] == pytest.approx(sd.mean(), rel=1e-12)
            assert out[ds][name]["q97.5"] == pytest.approx(np.percentile(sd, 97.5), rel=1e-12)
        assert out[ds]["scale"] == "linear"
        # the priors in words, the defaults too (the report states them)
        spec, var = network.dataset(ds), network.observed(network.dataset(ds))
        assert out[ds]["priors"] == (f"{spec.noise.text(var.unit, False)}; "
                                     f"{spec.discrepancy.text()}")
        assert "prior" in out[ds]["priors"]
    # the discrepancy lives on the observed model's inputs
    assert list(out["ydata"]["length_scales"]) == ["x"]
    assert list(out["wdata"]["length_scales"]) == ["s"]


def test_check_says_how_segmented_mode_splits_the_network(indep):
    """``calnet check``'s settings line names the segmented stages and their data sets:
    with data on 'down' only, 'up' is calibrated in the stage of 'down'."""
    from calnet.describe import settings_text

    network, _, _ = indep
    seg = network.settings.model_copy(update={"calibration": network.settings.calibration
                                              .model_copy(update={"mode": "segmented"})})
    both = network.model_copy(update={"settings": seg})
    assert "stages: up with ydata, then down with wdata)" in settings_text(both)
    only_w = both.model_copy(update={"data": tuple(d for d in both.data
                                                   if d.name == "wdata")})
    assert "stages: up+down with wdata)" in settings_text(only_w)
