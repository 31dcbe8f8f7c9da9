"""calnet verify: the surrogates against the real simulators at posterior points.

Oracle: the simulators are closed-form Python functions, so every value the check reports
as the simulator's can be recomputed from the inputs it records; a surrogate fitted on
enough runs of a smooth function agrees with it within 3 sd, one fitted on 4 runs of a
wiggly function does not.
"""

from __future__ import annotations

import json
import math
import re
import textwrap
import warnings

import numpy as np
import pytest
from network_helpers import fitted_network, on_path, write_csv

from calnet.calibration.calibrate_network import NetworkPosterior, calibrate
from calnet.calibration.persist import save_posterior
from calnet.campaign import run_campaign
from calnet.errors import CalibrationWarning
from calnet.spec import load_spec, read_all
from calnet.spec.models import SamplerSettings
from calnet.surrogates.fit_network import fit_surrogates
from calnet.verify import VerifyResult, verify

SIMS = '''
import math


def up(inputs):
    x, a = inputs["x"], inputs["a"]
    return {"y": a * (1.0 + x) + 0.4 * math.sin(9.0 * x), "z": math.exp(0.5 * x + 0.2 * a)}


def up_flaky(inputs):
    if inputs["x"] > 0.5:
        raise ValueError("diverged")
    return up(inputs)


def up_broken(inputs):
    raise RuntimeError("license server down")


def down(inputs):
    s, b = inputs["s"], inputs["b"]
    return {"w": b * s * s - 0.5 * s}
'''

SPEC = '''
name: verify_net
models:
  up:
    simulator: python:verify_sims:up
    inputs: {x: {lower: 0, upper: 1}}
    parameters: {a: {lower: 0.5, upper: 1.5}}
    outputs: {y: {measurable: true}, z: {transform: log}}
    campaign: {runs: 40}
  down:
    simulator: python:verify_sims:down
    inputs: {s: {lower: 1, upper: 2.5}}
    parameters: {b: {lower: 0.5, upper: 1.5}}
    outputs: {w: {measurable: true}}
    campaign: {runs: 20}
links:
  - {from: up.z, to: down.s}
data:
  ydata: {path: y.csv, observes: up.y, columns: {x: x, y: y}}
  wdata: {path: w.csv, observes: down.w, columns: {x: x, w: w}}
settings:
  seed: 3
  surrogate: {restarts: 2}
'''

A_TRUE, B_TRUE = 1.1, 0.9
SAMPLER = SamplerSettings(chains=2, warmup=200, draws=200)


def up_y(x, a):
    return a * (1 + x) + 0.4 * np.sin(9 * x)


def up_z(x, a):
    return np.exp(0.5 * x + 0.2 * a)


def down_w(s, b):
    return b * s**2 - 0.5 * s


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    """The network, its surrogates and a posterior around the twin's values, saved as a
    run folder. The posterior is made here, not sampled, so that these tests check the
    verification alone (and stay fast); test_verify_after_a_real_calibration samples one."""
    root = tmp_path_factory.mktemp("verify")
    (root / "verify_sims.py").write_text(SIMS)
    (root / "network.yaml").write_text(textwrap.dedent(SPEC))
    rng = np.random.default_rng(5)
    x = np.linspace(0.05, 0.95, 8)
    y = up_y(x, A_TRUE) + 0.02 * rng.standard_normal(8)
    w = down_w(up_z(x, A_TRUE), B_TRUE) + 0.05 * rng.standard_normal(8)
    write_csv(root / "y.csv", x=x, y=y)
    write_csv(root / "w.csv", x=x, w=w)
    with on_path(root):
        network, sur = fitted_network(root)
        theta = {"up": A_TRUE + 0.02 * rng.standard_normal((400, 1)),
                 "down": B_TRUE + 0.02 * rng.standard_normal((400, 1))}
        data = {k: v.train for k, v in read_all(network).items()}
        post = NetworkPosterior("joint", "-", (), theta, {k: {} for k in data}, data)
        run = root / "out"
        sur.save(run / "surrogates")
        save_posterior(post, run / "posterior")
        yield network, sur, post, root


@pytest.fixture(scope="module")
def good(calibrated, tmp_path_factory) -> VerifyResult:
    network, sur, post, _ = calibrated
    return verify(network, sur, post, k=6, seed=0, workdir=tmp_path_factory.mktemp("work"))


def test_a_good_surrogate_agrees_with_its_simulator(good):
    assert good.agrees, {k: c.to_dict() for k, c in good.checks.items()}
    assert set(good.checks) == {"up.y", "up.z", "down.w"}
    for c in good.checks.values():
        assert c.n == 6 and c.n_failed == 0 and c.max_abs_z <= 3 and c.share_beyond == 0
        assert c.verdict == "agrees" and c.rmse < 0.1
    assert len(good.points) == 3 * 6


def test_a_surrogate_sd_far_above_its_error_is_noted_not_failed():
    from calnet.verify import VerifyPoint, summarise

    def points(zs):
        return [VerifyPoint("M.y", i, 0, {}, {}, "ok", "", 1.0 + 0.1 * z, 1.0, 0.1, z)
                for i, z in enumerate(zs)]

    wide = summarise("M.y", None, points(0.18 * np.array([1, -1] * 8)))  # RMS z 0.18
    assert wide.agrees and wide.rms_z == pytest.approx(0.18)
    assert wide.note.startswith("its sd overstates its error about 6 times here (RMS z 0.18 "
                                "over 16 points")
    assert wide.to_dict()["note"] == wide.note
    # a sd that states the error (RMS z 1), or too few points to tell: no note
    assert summarise("M.y", None, points([1.0, -1.0] * 8)).note == ""
    assert summarise("M.y", None, points([0.1, -0.1] * 3)).note == ""


def test_simulator_values_are_the_true_function_at_posterior_points(calibrated, good):
    network, _, post, _ = calibrated
    data_x = set(np.round(post.data["ydata"].x[:, 0], 12))
    for p in good.points:
        # the parameters are the draw's, the setting a calibration data row
        model = p.surrogate.split(".")[0]
        param = "a" if model == "up" else "b"
        assert p.inputs[param] == pytest.approx(post.theta[model][p.draw, 0], abs=0, rel=1e-15)
        assert round(p.setting["up.x"], 12) in data_x
        if p.surrogate == "up.y":
            assert p.inputs["x"] == p.setting["up.x"]
            assert p.simulator == pytest.approx(up_y(p.inputs["x"], p.inputs["a"]), rel=1e-12)
        elif p.surrogate == "up.z":  # modelled on the log scale
            assert p.simulator == pytest.approx(0.5 * p.inputs["x"] + 0.2 * p.inputs["a"],
                                                rel=1e-12)
        else:  # s came through the chain: the upstream surrogate's median of z
            assert p.inputs["s"] == pytest.approx(up_z(p.setting["up.x"],
                                                       post.theta["up"][p.draw, 0]), rel=1e-3)
            assert p.simulator == pytest.approx(down_w(p.inputs["s"], p.inputs["b"]), rel=1e-12)
        assert p.z == pytest.approx((p.simulator - p.mean) / p.sd)


def test_draws_and_settings_are_seeded(calibrated, good, tmp_path):
    network, sur, post, _ = calibrated
    again = verify(network, sur, post, k=6, seed=0, workdir=tmp_path)
    assert again.draws == good.draws
    assert [p.setting for p in again.points] == [p.setting for p in good.points]
    other = verify(network, sur, post, k=6, seed=1, workdir=tmp_path)
    assert other.draws != good.draws


def test_a_poor_surrogate_is_flagged(calibrated, tmp_path):
    network, _, post, root = calibrated
    store = tmp_path / "poor.sqlite"
    run_campaign(network, "up", runs=4, store=store, executor="in-process", progress=False)
    poor = fit_surrogates(network, stores={"up": store}, seed=1, cv=False)
    result = verify(network, poor, post, k=16, seed=0, workdir=tmp_path)
    check = result.checks["up.y"]
    assert not result.agrees and not check.agrees
    assert check.max_abs_z > 3 and check.share_beyond > 0
    beyond = round(check.share_beyond * check.n)
    assert check.verdict == ("surrogate off where the posterior puts its mass: "
                             f"{beyond} of {check.n} points beyond 3 sd; add runs near the "
                             "posterior")


def _posterior_of_ydata(post, a: float, sd: float) -> NetworkPosterior:
    """A posterior of ydata alone (so every point's setting is one of its rows), every
    draw at ``a``, its noise variance sampled at ``sd**2``."""
    n = 400
    theta = {"up": np.full((n, 1), a), "down": np.full((n, 1), B_TRUE)}
    return NetworkPosterior("joint", "-", (), theta, {"ydata": {"se2": np.full(n, sd**2)}},
                            {"ydata": post.data["ydata"]})


@pytest.mark.parametrize("a", [A_TRUE, A_TRUE + 0.15])
def test_the_simulator_at_the_posterior_against_the_observations(calibrated, tmp_path, a):
    """Each point's setting is a row of ydata: the simulator's value there against the
    row's observation, in sds of the noise at the draw. The RMS of those residuals is
    recomputed here from the closed-form simulator; at the parameter the data were made
    with it is about 1 (fits), 0.15 away the simulator misses every observation by some
    10 noise sds."""
    network, sur, post, _ = calibrated
    sd = 0.02
    result = verify(network, sur, _posterior_of_ydata(post, a, sd), k=8, seed=0,
                    workdir=tmp_path)
    data = post.data["ydata"]
    r = []
    for p in result.points:
        if p.surrogate == "up.y":
            j = int(np.flatnonzero(np.isclose(data.x[:, 0], p.setting["up.x"]))[0])
            r.append((data.y[j] - up_y(p.setting["up.x"], a)) / sd)
    fit = result.fits["ydata"]
    assert set(result.fits) == {"ydata"} and fit.n == len(r) == 8
    assert fit.rms == pytest.approx(np.sqrt(np.mean(np.square(r))), rel=1e-9)
    assert fit.max_abs == pytest.approx(np.max(np.abs(r)), rel=1e-9)
    if a == A_TRUE:
        assert fit.fits and fit.rms < 2
    else:
        assert not fit.fits and fit.rms > 5
        assert fit.verdict.startswith("the simulator at the posterior misses these "
                                      f"observations: RMS {fit.rms:.1f} sds")
    assert result.to_dict()["data_fits"]["ydata"]["rms"] == pytest.approx(fit.rms)


def test_a_fit_within_a_large_discrepancy_says_how_large():
    """A fit whose residuals were scaled mostly by the discrepancy says so: the model
    alone misses the data by about the discrepancy's sd."""
    from calnet.verify import DataFit

    plain = DataFit("d", "M.y", 8, 0.9, 1.5, "fits", noise_sd=0.02, discrepancy_sd=0.03)
    assert plain.summary() == ("the simulator fits its observations at the posterior (RMS "
                               "0.90 sds of noise and discrepancy over 8 points)")
    wide = DataFit("d", "M.y", 8, 0.6, 1.1, "fits", noise_sd=0.02, discrepancy_sd=0.48,
                   rms_noise=14.4)
    assert wide.summary().endswith(", within a discrepancy 24 times the noise (sd 0.48 "
                                   "against 0.02): the model alone misses these data by "
                                   "about that much (RMS 14.4 noise sds)")
    assert wide.to_dict()["discrepancy_sd"] == 0.48
    # a large discrepancy the data do not need (the simulator fits within the noise): its
    # size is its prior's, and the line says so rather than blaming the model
    unneeded = DataFit("d", "M.y", 8, 0.05, 0.1, "fits", noise_sd=0.02,
                       discrepancy_sd=0.48, rms_noise=1.1)
    assert unneeded.summary().endswith(
        "; it fits within the noise alone too (RMS 1.10 noise sds), so these data do not "
        "ask for a discrepancy 24 times the noise (sd 0.48 against 0.02): its size comes "
        "from its prior (few points, or a generous prior)"), unneeded.summary()


def test_residuals_in_noise_sds_come_from_the_noise_share():
    """``rms_noise`` rescales each residual from noise-and-discrepancy sds to noise sds."""
    from calnet.verify import _fit

    # residuals 1 and -1 sds of sqrt(0.04 + 0.12) = 0.4: 0.4 and -0.4 in units, i.e.
    # 2 noise sds (noise sd 0.2)
    found = np.array([[1.0, 0.04, 0.12], [-1.0, 0.04, 0.12]])
    fit = _fit("d", "M.y", found, no_discrepancy=False)
    assert fit.rms == pytest.approx(1.0) and fit.rms_noise == pytest.approx(2.0)


def test_a_data_set_without_a_noise_level_is_not_fitted(good):
    """The module's posterior carries no noise draws: nothing to scale a residual by."""
    assert all(not f.n and f.verdict.startswith("not checked") for f in good.fits.values())


def _with_up(root, function: str, name: str):
    """The spec with ``up`` simulated by ``verify_sims.<function>``, written to
    ``root/name``."""
    path = root / name
    path.write_text(textwrap.dedent(SPEC).replace("python:verify_sims:up\n",
                                                  f"python:verify_sims:{function}\n"))
    return path


def test_failed_runs_are_recorded_not_raised(calibrated, tmp_path):
    _, sur, post, root = calibrated
    network = load_spec(_with_up(root, "up_flaky", "flaky.yaml"))
    result = verify(network, sur, post, k=8, seed=0, workdir=tmp_path)
    up_points = [p for p in result.points if p.surrogate == "up.y"]
    failed = [p for p in up_points if p.status != "ok"]
    assert failed and len(failed) < len(up_points)  # the data rows span x = 0.05 .. 0.95
    for p in failed:
        assert p.setting["up.x"] > 0.5 and p.status == "failed"
        assert "ValueError: diverged" in p.message
        assert math.isnan(p.simulator) and math.isnan(p.z)
    check = result.checks["up.y"]
    assert check.n_failed == len(failed) and check.n == len(up_points) - len(failed)
    assert result.checks["down.w"].n_failed == 0  # down runs on its own simulator
    json.dumps(result.to_dict(), allow_nan=False)  # failures serialise as null, not NaN


def test_verify_command_writes_verify_json(calibrated):
    from typer.testing import CliRunner

    from calnet.cli import app

    _, _, _, root = calibrated
    run = root / "out"
    res = CliRunner().invoke(app, ["verify", str(root), "--run", str(run), "-k", "3"])
    assert res.exit_code == 0, res.output
    doc = json.loads((run / "verify.json").read_text())
    assert doc["k"] == 3 and set(doc["checks"]) == {"up.y", "up.z", "down.w"}
    assert len(doc["points"]) == 9
    assert "agrees" in res.output and "verify.json" in res.output
    # a line as each simulator run starts and ends (a run can take hours)
    for m in ("up", "down"):
        assert f"{m}: run 1 of 3 started" in res.stderr, res.stderr
        assert re.search(rf"{m}: run 3 of 3 ok \(\d+\.\d s\)", res.stderr), res.stderr
    res = CliRunner().invoke(app, ["verify", str(root), "--run", str(run), "-k", "2", "--json"])
    assert res.exit_code == 0, res.output
    assert json.loads(res.stdout)["k"] == 2  # progress lines go to stderr


def test_verify_command_without_a_run_folder_says_so_in_one_line(calibrated, tmp_path):
    from typer.testing import CliRunner

    from calnet.cli import app

    root = calibrated[3]
    res = CliRunner().invoke(app, ["verify", str(root), "--run", str(tmp_path / "none")])
    assert res.exit_code == 1, res.output
    lines = [line for line in res.output.splitlines() if line.strip()]
    assert len(lines) == 1 and "no fitted surrogates" in lines[0], res.output
    (tmp_path / "half" / "surrogates").mkdir(parents=True)
    calibrated[1].save(tmp_path / "half" / "surrogates")
    res = CliRunner().invoke(app, ["verify", str(root), "--run", str(tmp_path / "half")])
    assert res.exit_code == 1 and "no calibrated posterior" in res.output, res.output


@pytest.mark.slow
def test_verify_after_a_real_calibration(calibrated, tmp_path):
    network, sur, _, _ = calibrated
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CalibrationWarning)  # short chains: low ESS
        post = calibrate(network, sur, mode="joint", sampler=SAMPLER, seed=2)
    result = verify(network, sur, post, k=4, seed=0, workdir=tmp_path)
    assert result.agrees, {k: c.to_dict() for k, c in result.checks.items()}
    for p in result.points:
        model = p.surrogate.split(".")[0]
        assert p.inputs["a" if model == "up" else "b"] == post.theta[model][p.draw, 0]


NO_DATA_SPEC = '''
name: no_data
models:
  only:
    simulator: python:no_data_sims:f
    inputs: {x: {lower: 0, upper: 1}}
    outputs: {y: {}}
    campaign: {runs: 12}
settings:
  predict: [only.y]
'''


def test_a_network_without_data_or_parameters_is_verified_at_settings(tmp_path):
    """No data and no parameters: the posterior is empty, but the surrogates can still be
    checked; the settings come from the bounds, and the notes say how to use data."""
    from typer.testing import CliRunner

    from calnet.calibration.calibrate_network import uncalibrated
    from calnet.cli import app

    (tmp_path / "no_data_sims.py").write_text(
        "import math\n\n\ndef f(inputs):\n    return {'y': math.sin(3.0 * inputs['x'])}\n")
    (tmp_path / "network.yaml").write_text(textwrap.dedent(NO_DATA_SPEC))
    with on_path(tmp_path):
        network, sur = fitted_network(tmp_path)
    run = tmp_path / "out"
    sur.save(run / "surrogates")
    save_posterior(uncalibrated(network), run / "posterior")
    with on_path(tmp_path):
        res = CliRunner().invoke(app, ["verify", str(tmp_path), "--run", str(run), "-k", "4",
                                       "--json"], terminal_width=400)
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout)
    assert doc["draws"] == [None] * 4 and doc["checks"]["only.y"]["n"] == 4
    for p in doc["points"]:  # the simulator's values: the function at the drawn settings
        x = p["setting"]["only.x"]
        assert 0 <= x <= 1 and p["simulator"] == pytest.approx(math.sin(3 * x), abs=1e-12)
    assert any("no data sets" in n and "add data sets (data: in the spec" in n
               for n in doc["notes"]), doc["notes"]
    assert any("no calibration parameters" in n for n in doc["notes"]), doc["notes"]


def test_verify_command_counts_the_points_a_verdict_rests_on(calibrated, tmp_path):
    from typer.testing import CliRunner

    from calnet.cli import app

    _, _, _, root = calibrated
    flaky = _with_up(root, "up_flaky", "flaky_cli.yaml")
    res = CliRunner().invoke(app, ["verify", str(flaky), "--run", str(root / "out"),
                                   "-k", "8"])
    assert res.exit_code == 0, res.output
    doc = json.loads((root / "out" / "verify.json").read_text())
    up = doc["checks"]["up.y"]
    assert up["n_failed"] > 0 and up["n"] > 0
    line = next(s for s in res.output.splitlines() if s.startswith("up.y:"))
    assert line.endswith(f"at the {up['n']} of {up['n'] + up['n_failed']} points whose "
                         "simulator run finished")
    down = next(s for s in res.output.splitlines() if s.startswith("down.w:"))
    assert "points whose" not in down  # every run of down finished


def test_a_simulator_that_fails_every_point_fails_verify(calibrated):
    from typer.testing import CliRunner

    from calnet.cli import app

    _, _, _, root = calibrated
    broken = _with_up(root, "up_broken", "broken_cli.yaml")
    res = CliRunner().invoke(app, ["verify", str(broken), "--run", str(root / "out"),
                                   "-k", "2"])
    assert res.exit_code == 1, res.output
    assert "nan" not in res.output.lower()  # no number where nothing was measured
    assert "license server down" in res.output  # each point's message is shown
    last = [s for s in res.output.splitlines() if s.strip()][-1]
    assert last.startswith("error: verify: the simulator failed at every point of up.y (2), "
                           "up.z (2)"), last
    doc = json.loads((root / "out" / "verify.json").read_text())  # still written
    assert doc["checks"]["up.y"]["n"] == 0 and doc["checks"]["down.w"]["n"] == 2


def test_a_miss_behind_a_surrogate_warning_names_that_warning_first():
    """Where the calibration's surrogate check warned for the data set, a missed fit is
    put down to that first: the surrogates' variance let the posterior stray."""
    import numpy as np

    from calnet.verify import _fit

    found = np.array([[4.0, 1.0, 0.0], [-4.5, 1.0, 0.0], [3.9, 1.0, 0.0]])
    plain = _fit("d", "m.y", found, no_discrepancy=False).verdict
    assert plain.startswith("the simulator at the posterior misses these observations: RMS "
                            "4.1 sds of the calibration's noise and discrepancy over 3 "
                            "points (about 1 for a fit): the model may not describe")
    warned = _fit("d", "m.y", found, no_discrepancy=False, surrogate_warned=True).verdict
    assert ("(about 1 for a fit): the calibration's surrogate check warned that the "
            "surrogates' variance, not the data, sets this data set's posterior") in warned
    assert "Else the model may not describe these data" in warned
