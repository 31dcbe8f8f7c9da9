"""The checks after calibration: a surrogate that sets the answer, a parameter pressed
against its bound, and the notes of shared parameters in segmented mode."""

from __future__ import annotations

import sys
import textwrap
import warnings

import numpy as np
import pytest
from network_helpers import fitted_network, on_path, write_csv

from calnet.calibration.calibrate_network import calibrate
from calnet.errors import CalibrationWarning, SpecWarning
from calnet.spec.models import SamplerSettings

SIMS = '''
import math


def wiggly(inputs):
    x, a = inputs["x"], inputs["a"]
    return {"y": a * x + 0.8 * math.sin(9.0 * x)}
'''

SPEC = '''
models:
  m:
    simulator: python:guard_sims:wiggly
    inputs: {x: {lower: 0, upper: 1}}
    parameters: {a: {lower: LOWER, upper: UPPERPRIOR}}
    outputs: {y: {measurable: true}}
    campaign: {runs: RUNS}
data:
  d: {path: d.csv, observes: m.y, columns: {x: x, y: y}, noise: {sd: 0.02}}
settings:
  seed: 4
  sampler: {chains: 2, warmup: 300, draws: 300}
  calibration: {mode: joint}
'''
SAMPLER = SamplerSettings(chains=2, warmup=300, draws=300, target_accept=0.95)


def _case(root, runs: int, lower=0.5, upper=2.0, a_true=1.3, beyond=(), prior=""):
    root.mkdir()
    (root / "guard_sims.py").write_text(SIMS)
    spec = SPEC.replace("RUNS", str(runs)).replace("LOWER", str(lower))
    spec = spec.replace("PRIOR", f", prior: {prior}" if prior else "")
    (root / "network.yaml").write_text(textwrap.dedent(spec.replace("UPPER", str(upper))))
    x = np.concatenate([np.linspace(0.0, 1.0, 15 - len(beyond)), beyond])
    y = a_true * x + 0.8 * np.sin(9 * x) + 0.02 * np.random.default_rng(1).standard_normal(15)
    write_csv(root / "d.csv", x=x, y=y)
    with on_path(root):
        post, caught = _calibrated(root)
    sys.modules.pop("guard_sims", None)
    return post, [m for c, m in caught if c is CalibrationWarning]


def _calibrated(root):
    """Posterior of the network in ``root`` and the (category, message) of its warnings."""
    network, sur = fitted_network(root)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", CalibrationWarning)
        post = calibrate(network, sur, sampler=SAMPLER, seed=2)
    return post, [(w.category, str(w.message)) for w in caught]


def test_a_poor_surrogate_is_named_with_the_runs_it_needs(tmp_path):
    post, messages = _case(tmp_path / "poor", runs=5)
    (check,) = post.checks
    assert check.ratio > 1.0 and check.runs == {"m.y": 5} and check.needed["m.y"] > 5
    assert any("the surrogate, not the data, sets the answer" in m and "m.y" in m
               and "runs of 'm' (now 5;" in m for m in messages), messages
    assert check.to_dict()["warning"] is not None


def test_a_good_surrogate_passes_quietly(tmp_path):
    post, messages = _case(tmp_path / "good", runs=60)
    (check,) = post.checks
    assert check.ratio < 0.5, check.to_dict()
    assert not [m for m in messages if "sets the answer" in m], messages
    lo, hi = np.percentile(post.theta["m"][:, 0], [2.5, 97.5])
    assert lo < 1.3 < hi


def test_data_outside_the_bounds_are_named_not_more_runs(tmp_path):
    """Two points far outside the input's bounds: the surrogate's variance there, not a
    lack of runs, sets the answer, and the check says so instead of asking for runs."""
    with pytest.warns(UserWarning, match="outside the model's input bounds"):
        post, messages = _case(tmp_path / "beyond", runs=60, beyond=(2.5, 3.0))
    (check,) = post.checks
    assert check.outside == 2 and check.outside_share > 0.9, check.to_dict()
    said = [m for m in messages if "sets the answer" in m]
    assert len(said) == 1 and "at the 2 data point(s) outside the input bounds" in said[0]
    assert "runs of 'm'" not in said[0]


def test_a_parameter_pressed_against_its_bound_is_reported(tmp_path):
    post, messages = _case(tmp_path / "bound", runs=60, lower=0.5, upper=1.1, a_true=1.3)
    assert np.median(post.theta["m"][:, 0]) > 1.05
    said = [m for m in messages if "m.a: the posterior presses against its upper bound 1.1"
            in m]
    assert len(said) == 1 and "the data ask for values outside [0.5, 1.1]" in said[0]


def test_a_prior_beyond_the_bound_pressed_against_is_named(tmp_path):
    """The prior's own mass lies above the upper bound: the message names the prior, not
    only the data, as what asks for values beyond it."""
    with pytest.warns(SpecWarning, match="models.m.parameters.a: prior normal"):
        post, messages = _case(tmp_path / "prior", runs=60, lower=0.5, upper=1.1,
                               a_true=1.3, prior="{dist: normal, mu: 3, sigma: 0.3}")
    said = [m for m in messages if "m.a: the posterior presses against its upper bound 1.1"
            in m]
    assert len(said) == 1, messages
    assert ("the prior or the data ask for values outside [0.5, 1.1]: the prior "
            "normal(mu=3, sigma=0.3) puts 100 % of its mass above 1.1") in said[0], said


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["segmented", "joint"])
def test_a_shared_parameter_is_one_parameter(tmp_path, mode):
    root = tmp_path / mode
    root.mkdir()
    (root / "share_sims.py").write_text(textwrap.dedent('''
        def one(inputs):
            return {"y": inputs["k"] * inputs["x"]}


        def two(inputs):
            return {"z": inputs["k"] + inputs["x"] * inputs["c"]}
    '''))
    (root / "network.yaml").write_text(textwrap.dedent(f'''
        models:
          one:
            simulator: python:share_sims:one
            inputs: {{x: {{lower: 0, upper: 1}}}}
            parameters: {{k: {{lower: 0, upper: 2, shared: true}}}}
            outputs: {{y: {{measurable: true}}}}
            campaign: {{runs: 30}}
          two:
            simulator: python:share_sims:two
            inputs: {{x: {{lower: 0, upper: 1}}}}
            parameters: {{k: {{lower: 0, upper: 2, shared: true}}, c: {{lower: 0, upper: 2}}}}
            outputs: {{z: {{measurable: true}}}}
            campaign: {{runs: 40}}
        data:
          dy: {{path: y.csv, observes: one.y, columns: {{x: x, y: y}}, noise: {{sd: 0.05}},
               discrepancy: none}}
          dz: {{path: z.csv, observes: two.z, columns: {{x: x, z: z}}, noise: {{sd: 0.05}},
               discrepancy: none}}
        settings: {{seed: 5, calibration: {{mode: {mode}}}}}
    '''))
    x = np.linspace(0, 1, 8)
    rng = np.random.default_rng(3)
    write_csv(root / "y.csv", x=x, y=1.2 * x + 0.05 * rng.standard_normal(8))
    write_csv(root / "z.csv", x=x, z=1.2 + 0.7 * x + 0.05 * rng.standard_normal(8))
    with on_path(root):
        post, caught = _calibrated(root)
    sys.modules.pop("share_sims", None)
    k_one, k_two = post.theta["one"][:, 0], post.theta["two"][:, 0]
    np.testing.assert_array_equal(k_one, k_two)  # one parameter, the same draws
    assert 1.0 < np.median(k_one) < 1.4
    messages = [m for _, m in caught]
    # where segmented mode calibrates a shared parameter is said (post.info), not warned
    assert not [m for m in messages if "shared parameter 'k'" in m], messages
    noted = [m for m in post.info if "shared parameter 'k'" in m]
    if mode == "segmented":  # calibrated with the data of 'one', taken by 'two'
        assert noted and noted[0] == (
            "shared parameter 'k' is calibrated in stage 'one' with the data of 'one', the "
            "first model with data that it acts on; 'two' takes its draws (plug: posterior) "
            "(segmented mode)"), post.info
        assert np.ptp(k_one) > 0 and post.plugged["two"][0] == pytest.approx(np.mean(k_one))
    else:
        assert not noted
        assert post.stages[0].idata.posterior["theta_shared"].shape[-1] == 1


def test_the_check_says_what_its_sds_are_in():
    """A log-modelled data set's sds are of ln y, a linear one's in the output's unit."""
    from calnet.calibration.guard import SurrogateCheck

    def check(scale):
        return SurrogateCheck("d", {"m.y": 0.3}, 0.2, {"m.y": 10}, {"m.y": 40}, scale=scale)

    assert "(0.3 on the ln scale) is 1.5 x" in check("ln").message()
    assert "noise and discrepancy sd at the data (0.2 um," in check("um").message()
    assert "(0.3) is 1.5 x" in check("").message() and check("1").to_dict()["scale"] == "1"
    assert "(0.3) is" in check("1").message()


def _latent_var(gp, points):
    """Mean latent variance of ``gp`` at ``points`` (unit cube), from its public predict,
    in standardised units (so that GPs on other runs of one function compare)."""
    import jax.numpy as jnp
    lower, upper = np.asarray(gp.lower), np.asarray(gp.upper)
    z = lower + points * (upper - lower)
    return float(np.mean(np.asarray(gp.predict(jnp.asarray(z))[1])) / float(gp.y_std) ** 2)


def test_the_runs_named_do_divide_the_variance_as_asked():
    """The runs-needed estimate extrapolates the GP's own learning curve: conditioning
    the same GP (same hyperparameters) on that many space-filling runs divides its mean
    variance over the box by the factor asked for, within a factor 1.6."""
    from scipy.stats import qmc

    from calnet.calibration.guard import runs_for, variance_rate
    from calnet.surrogates.gp import condition

    def gp_on(n):
        x = qmc.Halton(2, seed=3).random(n)
        y = np.sin(3 * x[:, 0]) + x[:, 1] ** 2
        return condition(x, y, lower=np.zeros(2), upper=np.ones(2),
                         lengthscales=np.array([0.3, 0.5]), signal_var=1.0, nugget=1e-6)

    points = np.random.default_rng(0).uniform(size=(400, 2))
    n0, factor = 64, 8.0
    gp0 = gp_on(n0)
    rate = variance_rate(gp0)
    assert 3 / 2 * 0.7 < rate < 6, rate  # at least about Matern 3/2's n^(-3/d), d = 2
    n1 = runs_for(n0, factor, rate)
    got = _latent_var(gp0, points) / _latent_var(gp_on(n1), points)
    assert factor / 1.6 < got < factor * 1.6, (n1, got)
    # the rate of a GP whose length scales are far below the runs' spacing: ~0
    rough = condition(qmc.Halton(2, seed=3).random(64), np.zeros(64), lower=np.zeros(2),
                      upper=np.ones(2), lengthscales=np.array([1e-3, 1e-3]),
                      signal_var=1.0, nugget=1e-6)
    assert variance_rate(rough) < 0.05 and runs_for(64, 4.0, 0.0) is None
    # too few runs to measure a rate: None, not a rate of 0 (which would say "rough")
    assert variance_rate(gp_on(7)) is None
    assert runs_for(64, 0.5, rate) == 64  # already below the target


def test_a_rough_surrogate_is_not_given_a_run_count():
    from calnet.calibration.guard import SurrogateCheck

    check = SurrogateCheck("d", {"m.y": 0.3}, 0.2, {"m.y": 50}, {"m.y": 1_000_000},
                           rates={"m.y": 0.01})
    assert "more runs of 'm' (now 50) would barely lower it" in check.message()
    fine = SurrogateCheck("d", {"m.y": 0.3}, 0.2, {"m.y": 50}, {"m.y": 120},
                          rates={"m.y": 1.5})
    assert "about 120 runs of 'm' (now 50; m.y's variance falls as n^-1.5 with its runs)" \
        in fine.message()
    # every surrogate that needs runs is named, the largest sd first
    two = SurrogateCheck("d", {"u.a": 0.1, "m.y": 0.3}, 0.2, {"m.y": 50, "u.a": 30},
                         {"m.y": 120, "u.a": 37}, rates={"m.y": 1.5, "u.a": 1.0})
    assert "about 120 runs of 'm' (now 50; " in two.message()
    assert ") and about 37 runs of 'u' (now 30; u.a's" in two.message()
    assert two.to_dict()["needing_runs"] == ["m.y", "u.a"]  # the report's box reads these
    # a rough dominant surrogate: no count for it, but the others' still
    rough = SurrogateCheck("d", {"u.a": 0.1, "m.y": 0.3}, 0.2, {"m.y": 50, "u.a": 30},
                           {"m.y": None, "u.a": 37}, rates={"m.y": 0.01, "u.a": 1.0})
    said = rough.message()
    assert "more runs of 'm' (now 50) would barely lower it" in said
    assert said.endswith("; about 37 runs of 'u' (now 30; u.a's variance falls as n^-1 with "
                         "its runs) would lower the rest"), said
    assert rough.to_dict()["runs_gain_little"] == ["m.y"]


def test_an_overstated_surrogate_variance_asks_for_no_runs():
    """The dominant surrogate's variance is overstated (its leave-one-out errors far
    below its sd): the warning does not send the user to run more simulations."""
    from calnet.calibration.guard import SurrogateCheck

    check = SurrogateCheck("d", {"m.y": 0.3}, 0.2, {"m.y": 40}, {"m.y": None},
                           overstated={"m.y": 0.17})
    message = check.message()
    assert message.startswith("d: the surrogate, not the data, sets the answer")
    assert message.endswith(
        "; but m.y's variance is overstated (at most runs its leave-one-out error is far "
        "below its sd: median |z| 0.17 where 0.67 is expected), so more runs are not what "
        "it needs: check with 'calnet verify', and if the surrogate agrees with the "
        "simulator, settings.calibration.emulator_variance: false leaves its variance out")
    assert "runs of" not in message
    assert check.to_dict()["variance_overstated"] == {"m.y": 0.17}
