"""``calnet predict`` on a calibrated two-model chain: a point's prediction depends on the
seed and the point only, extra columns and names are ignored alike (one warning), and a
target asked for twice is predicted once."""

from __future__ import annotations

import json
import textwrap
import warnings

import numpy as np
import pytest
from network_helpers import fitted_network, on_path, write_csv
from typer.testing import CliRunner

from calnet.calibration.calibrate_network import calibrate
from calnet.calibration.persist import save_posterior
from calnet.cli import app
from calnet.errors import CalibrationWarning
from calnet.spec import read_all
from calnet.spec.models import SamplerSettings

SIMS = '''
import math


def up(inputs):
    return {"w": 0.5 * inputs["x"] ** 2}


def down(inputs):
    w, a = inputs["w"], inputs["a"]
    return {"y": a * w + 0.2 * math.sin(3.0 * w)}
'''

SPEC = '''
name: predict_chain
models:
  up:
    simulator: python:predict_sims:up
    inputs: {x: {lower: 0, upper: 2}}
    outputs: {w: {}}
    campaign: {runs: 10}
  down:
    simulator: python:predict_sims:down
    inputs: {w: {lower: 0, upper: 2}}
    parameters: {a: {lower: 0.5, upper: 2.0}}
    outputs: {y: {measurable: true}}
    campaign: {runs: 16}
links:
  - {from: up.w, to: down.w}
data:
  yd: {path: y.csv, observes: down.y, columns: {x: x, y: y}}
settings:
  seed: 4
'''


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """``(spec folder, run folder)``: surrogates and a short posterior written as
    ``calnet run`` writes them."""
    root = tmp_path_factory.mktemp("predict_chain")
    (root / "predict_sims.py").write_text(SIMS)
    (root / "network.yaml").write_text(textwrap.dedent(SPEC))
    x = np.linspace(0.1, 1.9, 8)
    w = 0.5 * x**2
    noise = np.random.default_rng(0).normal(0, 0.02, len(x))
    write_csv(root / "y.csv", x=x, y=1.2 * w + 0.2 * np.sin(3 * w) + noise)
    with on_path(root):
        network, sur = fitted_network(root)
    data = {k: d.train for k, d in read_all(network).items()}
    with warnings.catch_warnings():  # a short chain may not converge: not tested here
        warnings.simplefilter("ignore", CalibrationWarning)
        post = calibrate(network, sur, data=data, seed=1,
                         sampler=SamplerSettings(chains=2, warmup=100, draws=100))
    out = root / "out"
    sur.save(out / "surrogates")
    save_posterior(post, out / "posterior")
    return root, out


def _invoke(run, *args: str):
    """``calnet predict`` on the fixture's spec and run folder, with ``args``."""
    root, out = run
    return CliRunner().invoke(app, ["predict", str(root), "--run", str(out), *args],
                              terminal_width=400)


def _predict(run, *args: str):
    result = _invoke(run, "--json", *args)
    assert result.exit_code == 0, result.output
    return json.loads(result.stdout)["predictions"], result.stderr


# the round-off of a batched evaluation depends on a point's place in its block (seen up
# to 1.2e-11 relative on the band's ends); dependence on the other points' draws moved
# the band by about 3 %
RTOL = 1e-9


def _at(pred: dict, x: float) -> tuple[float, float, float]:
    i = [row[0] for row in pred["x"]].index(x)
    return pred["mean"][i], pred["lower95"][i], pred["upper95"][i]


def test_a_points_prediction_depends_on_the_seed_and_the_point_only(run):
    """The same draws at the same point: equal up to the round-off of the batched
    evaluation (a point's place in a block of rows), far below the Monte Carlo error of
    the 95 % band (about 1 % of its width for 200 draws x 20 samples)."""
    alone, _ = _predict(run, "--at", "x=0.3")
    among, _ = _predict(run, "--at", "x=1.7", "--at", "x=0.3", "--at", "x=1.1")
    np.testing.assert_allclose(_at(alone[0], 0.3), _at(among[0], 0.3), rtol=RTOL)
    reordered, _ = _predict(run, "--at", "x=1.1", "--at", "x=1.7")
    np.testing.assert_allclose(_at(reordered[0], 1.7), _at(among[0], 1.7), rtol=RTOL)
    other_seed, _ = _predict(run, "--at", "x=0.3", "--seed", "5")
    band = np.subtract(*_at(alone[0], 0.3)[:0:-1])
    assert abs(_at(other_seed[0], 0.3)[1] - _at(alone[0], 0.3)[1]) > 1e-6 * band  # seeded


def test_a_simulator_outputs_prediction_depends_on_the_point_only(run):
    """``-d model.output``: Monte Carlo through the linked surrogates, per point."""
    alone, _ = _predict(run, "-d", "down.y", "--at", "x=0.3")
    among, _ = _predict(run, "-d", "down.y", "--at", "x=1.7", "--at", "x=0.3")
    np.testing.assert_allclose(_at(alone[0], 0.3), _at(among[0], 0.3), rtol=RTOL)


def test_extra_columns_and_names_are_ignored_alike(run, tmp_path):
    plain, _ = _predict(run, "--at", "x=0.3")
    points = tmp_path / "points.csv"
    points.write_text("x,id,y_measured,label\n0.3,7,0.1,first point\n")
    from_csv, warned_csv = _predict(run, "--csv", str(points))
    from_at, warned_at = _predict(run, "--at", "x=0.3,id=7,y_measured=0.1")
    assert from_csv == from_at == plain
    for warned, extra in ((warned_csv, "id, y_measured, label"), (warned_at, "id, y_measured")):
        lines = [line for line in warned.splitlines() if "ignored" in line]
        assert lines == [f"warning: ignored {extra}: not process inputs of yd (it takes x)"], \
            warned


def test_the_output_table_keeps_a_points_other_columns(run, tmp_path):
    """With --output, the columns that are not inputs (an ID, a label) stay beside each
    point's predictions, so they join back to the sample list."""
    import csv

    points = tmp_path / "points.csv"
    points.write_text("x,id,label\n0.3,A7,first point\n0.9,B2,second\n")
    table = tmp_path / "out.csv"
    _, warned = _predict(run, "--csv", str(points), "--output", str(table))
    assert "not used id, label: not process inputs of yd (it takes x); copied to --output " \
           "beside each point" in " ".join(warned.split()), warned
    rows = list(csv.DictReader(table.open()))
    assert [(r["point"], r["id"], r["label"], r["up.x"]) for r in rows] == [
        ("1", "A7", "first point", "0.3"), ("2", "B2", "second", "0.9")]


@pytest.mark.parametrize(("text", "said"), [
    (None, "--csv: no file"),
    ("x\n", "no rows"),
    ("x,x\n0.3,0.4\n", "column 'x' appears twice"),
    ("x,label\n0.3,a\nfast,b\n", "point 2: up.x = 'fast' is not a number"),
    ("xx\n0.3\n", "point 1: missing x"),
])
def test_a_bad_points_file_is_a_usage_error(run, tmp_path, text, said):
    """As for a bad --at value: one line, exit code 2."""
    points = tmp_path / "points.csv"
    if text is not None:
        points.write_text(text)
    result = _invoke(run, "--csv", str(points))
    assert result.exit_code == 2, result.output
    assert said in result.output, result.output


def test_a_target_asked_twice_is_predicted_once(run):
    preds, warned = _predict(run, "--at", "x=0.3", "-d", "yd", "-d", "yd")
    assert [p["dataset"] for p in preds] == ["yd"]
    assert "warning: -d yd is given twice; it is predicted once" in warned


def test_a_linked_input_outside_its_bounds_is_said(run):
    """x = 2.3 lies outside x's bounds and sends w = 0.5 x^2 (about 2.6) past down.w's
    upper bound 2: both are said, once each; x = 1 sends w = 0.5, inside, and x = 2 sends
    w = 2, on the bound, where the surrogate's mean may overshoot it a little: nothing."""
    result = _invoke(run, "--at", "x=1", "--at", "x=2.3", "--at", "x=2")
    assert result.exit_code == 0, result.output
    said = [line for line in result.stderr.splitlines() if "outside its bounds" in line]
    assert len(said) == 2, result.stderr
    assert "point 2: up.x = 2.3 lies outside its bounds [0, 2]" in said[0]
    assert "point 2: down.w = " in said[1] and "(from up.w)" in said[1]
    assert "bounds [0, 2]; the down surrogates extrapolate there" in said[1]


def test_an_unknown_target_is_a_usage_error(run):
    result = _invoke(run, "--at", "x=1", "-d", "nosuch")
    assert result.exit_code == 2, result.output  # a bad option value, as the README says
    assert "nothing to predict for ['nosuch']; choose a calibrated data set ['yd']" in \
        result.stderr


def test_the_table_names_the_data_set_or_the_simulator_output(run):
    result = _invoke(run, "--at", "x=1", "-d", "yd", "-d", "up.w")
    assert result.exit_code == 0, result.output
    rows = [line for line in result.stdout.splitlines() if "x=1" in line]
    assert len(rows) == 2, result.stdout
    assert rows[0].split("│")[1].strip() == "yd: down.y (measured)"
    assert rows[1].split("│")[1].strip() == "up.w (simulator)"


def test_a_run_that_did_not_finish_is_refused(run):
    """A rerun stopped part-way leaves the files of two runs in its folder: predict says
    so instead of mixing a new posterior with an old report."""
    from calnet.files import mark_complete, mark_incomplete

    _, out = run
    mark_incomplete(out, "validation")
    try:
        result = _invoke(run, "--at", "x=0.5")
        assert result.exit_code == 1, result.output
        assert "did not finish (it stopped in its validation stage)" in " ".join(
            result.output.split())
    finally:
        mark_complete(out)
    assert _invoke(run, "--at", "x=0.5").exit_code == 0


def test_a_data_file_changed_after_the_calibration_is_said(run, tmp_path):
    """The posterior conditions on the points it was calibrated with; a data file edited
    since is said to be so (its points are not used), and an unchanged one is not."""
    import shutil

    root, out = run
    copy = tmp_path / "spec"
    shutil.copytree(root, copy, ignore=shutil.ignore_patterns("out", "__pycache__"))
    args = ["predict", str(copy), "--run", str(out), "--at", "x=1.0"]
    same = CliRunner().invoke(app, args, terminal_width=400)
    assert same.exit_code == 0 and "changed after the calibration" not in same.output
    lines = (copy / "y.csv").read_text().splitlines()
    lines[3] = lines[3].split(",")[0] + ",0.9"  # one measurement edited
    (copy / "y.csv").write_text("\n".join(lines) + "\n")
    edited = CliRunner().invoke(app, args, terminal_width=400)
    assert edited.exit_code == 0, edited.output
    assert (f"data set yd: its file changed after the calibration in '{out}' (1 of its 8 "
            "training points differ from the calibration's); the predictions use the "
            "calibration's points; calibrate again (calnet run) to use the file as it is"
            ) in " ".join(edited.stderr.split()), edited.stderr
    (copy / "y.csv").write_text("\n".join(lines[:-1]) + "\n")  # one fewer
    fewer = CliRunner().invoke(app, args, terminal_width=400)
    assert "it now has 7 training points, the calibration had 8" in fewer.stderr, fewer.stderr
