"""End to end through the CLI: examples/chain3, a three-model chain without data or
parameters (emulation only), against its analytic answer y = f3(f1(x), f2(f1(x)))."""

from __future__ import annotations

import json
import shutil
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from calnet.cli import app

CHAIN3 = Path(__file__).parents[2] / "examples" / "chain3"
runner = CliRunner()


def _composite(x: np.ndarray) -> np.ndarray:
    sys.path.insert(0, str(CHAIN3))
    try:
        from chain3_sims import composite
    finally:
        sys.path.remove(str(CHAIN3))
    return composite(x)


@pytest.mark.integration
@pytest.mark.slow
def test_emulation_only_chain_end_to_end(tmp_path, monkeypatch):
    work = tmp_path / "chain3"
    shutil.copytree(CHAIN3, work, ignore=shutil.ignore_patterns("__pycache__"))
    monkeypatch.syspath_prepend(str(work))
    monkeypatch.setenv("PYTHONPATH", str(work))
    out = tmp_path / "out"

    res = runner.invoke(app, ["check", str(work)], terminal_width=400)
    assert res.exit_code == 0 and "warning" not in res.output, res.output
    assert "no data sets: emulation only" in res.output

    res = runner.invoke(app, ["run", str(work), "--out", str(out), "--quick"])
    assert res.exit_code == 0, res.output
    m = json.loads((out / "metrics.json").read_text())
    assert set(m["surrogates"]) == {"M1.w1", "M2.w2", "M3.y"}  # y: requested, not observed
    assert "calibration" not in m and m["validation"] == {}
    s = m["predicted_outputs"]["M3.y"]
    assert s["inputs"] == ["M1.x"]
    sl = s["slices"]["M1.x"]
    x, mean = np.array(sl["x"]), np.array(sl["mean"])
    lo, hi = np.array(sl["lower95"]), np.array(sl["upper95"])
    truth = _composite(x)
    # 40 runs through a sharp step: a few % of y's range, and bands that hold the truth
    nrmse = np.sqrt(np.mean((mean - truth) ** 2)) / np.ptp(truth)
    assert nrmse < 0.06, nrmse
    assert np.mean((lo <= truth) & (truth <= hi)) >= 0.9
    assert set(s["variance_shares"]) == {"emulator M1.w1", "emulator M2.w2", "emulator M3.y"}
    html = (out / "report.html").read_text()
    assert "Predicted outputs (through the chain)" in html and "emulation only" in html
    for absent in ("Calibration</a>", "Prediction and validation", "Sensitivity"):
        assert absent not in html, absent
    assert (out / "figures" / "predicted_M3.y.png").is_file()

    # the unobserved output at new settings, from the run's empty posterior
    res = runner.invoke(app, ["predict", str(work), "--run", str(out), "--at", "x=0.3",
                              "--at", "x=0.8", "-d", "M3.y", "--json"])
    assert res.exit_code == 0, res.output
    pred = json.loads(res.output)["predictions"][0]
    assert pred["dataset"] is None and pred["observes"] == "M3.y"
    truth = _composite(np.array([0.3, 0.8]))
    assert np.all(np.abs(np.array(pred["mean"]) - truth) < 0.1 * np.ptp(_composite(x)))
    assert np.all((np.array(pred["lower95"]) <= truth) & (truth <= np.array(pred["upper95"])))

    res = runner.invoke(app, ["calibrate", str(work), "--surrogates", str(out / "surrogates"),
                              "--out", str(tmp_path / "post")], terminal_width=400)
    assert res.exit_code == 0, res.output
    assert "no data sets: nothing to calibrate; the posterior is empty (0 parameters)" \
        in res.output


@pytest.mark.integration
@pytest.mark.slow
def test_cli_calibrate_and_predict_with_data_but_no_parameters(tmp_path, monkeypatch):
    """The chain with y observed (known noise, no discrepancy) and no parameters: nothing
    to sample, a posterior of 0 draws, and predict uses it (it raised IndexError, exit 3)."""
    import yaml

    work = tmp_path / "chain3"
    shutil.copytree(CHAIN3, work, ignore=shutil.ignore_patterns("__pycache__", "campaigns"))
    monkeypatch.syspath_prepend(str(work))
    monkeypatch.setenv("PYTHONPATH", str(work))
    spec = yaml.safe_load((work / "network.yaml").read_text())
    spec["models"]["M3"]["outputs"]["y"]["measurable"] = True
    spec["data"] = {"yd": {"path": "yd.csv", "observes": "M3.y", "columns": {"x": "x", "y": "y"},
                           "noise": {"sd": 0.02}, "discrepancy": "none"}}
    (work / "network.yaml").write_text(yaml.safe_dump(spec))
    x = np.array([0.1, 0.3, 0.5, 0.7, 0.9])
    (work / "yd.csv").write_text("x,y\n" + "".join(f"{a},{b}\n" for a, b in
                                                   zip(x, _composite(x), strict=True)))
    out = tmp_path / "out"
    for args in (["campaign", str(work), "--no-progress"],
                 ["surrogates", str(work), "--out", str(out / "surrogates"), "--no-cv"]):
        res = runner.invoke(app, args)
        assert res.exit_code == 0, res.output
    res = runner.invoke(app, ["calibrate", str(work), "--surrogates", str(out / "surrogates"),
                              "--out", str(out / "posterior")], terminal_width=400)
    assert res.exit_code == 0, res.output
    assert "no calibration parameters: nothing to sample" in res.output
    # with the noise unknown, it is sampled: the model is listed with its diagnostics
    spec["data"]["yd"].pop("noise")
    (work / "network.yaml").write_text(yaml.safe_dump(spec))
    from calnet.calibration import calibrate
    from calnet.calibration.summary import calibration_result
    from calnet.errors import CalibrationWarning
    from calnet.predict import load_surrogates
    from calnet.spec import SamplerSettings, load_spec, read_all

    network = load_spec(work)
    with warnings.catch_warnings():  # a short run: its diagnostics may warn
        warnings.simplefilter("ignore", CalibrationWarning)
        post = calibrate(network, load_surrogates(network, out), seed=1,
                         data={k: d.train for k, d in read_all(network).items()},
                         sampler=SamplerSettings(chains=2, warmup=100, draws=100))
    m3 = calibration_result(network, post).models["M3"]
    assert m3["parameters"] == {} and m3["datasets"] == ["yd"]
    assert m3["max_rhat"] > 0 and m3["min_ess_bulk"] > 0 and "prior_only" not in m3
    # the run in `out` was calibrated with the known noise: this spec no longer has it
    predict = ["predict", str(work), "--run", str(out), "--at", "x=0.8", "--json"]
    res = runner.invoke(app, predict)
    assert res.exit_code == 1 and "calibrated with other noise settings" in res.output
    spec["data"]["yd"]["noise"] = {"sd": 0.02}  # the spec the run was calibrated with
    (work / "network.yaml").write_text(yaml.safe_dump(spec))
    res = runner.invoke(app, predict)
    assert res.exit_code == 0, res.output
    preds = {p["dataset"] or p["observes"]: p for p in json.loads(res.output)["predictions"]}
    assert set(preds) == {"yd", "M3.y"}  # the data set, and settings.predict's output
    truth = float(_composite(np.array(0.8)))
    for p in preds.values():
        assert p["lower95"][0] <= truth <= p["upper95"][0], p
    assert "noise" in preds["yd"]["variance_shares"]
    assert "parameters" not in preds["yd"]["variance_shares"]  # the network has none
    assert "noise" not in preds["M3.y"]["variance_shares"]  # the simulator's output


@pytest.mark.integration
def test_cli_surrogates_table_when_a_mape_is_meaningless(tmp_path, monkeypatch):
    """M2.w2 crosses zero, so its CV MAPE is None: the table shows '-', as the report does."""
    work = tmp_path / "chain3"
    shutil.copytree(CHAIN3, work)
    monkeypatch.setenv("COLUMNS", "200")
    res = CliRunner().invoke(app, ["surrogates", str(work), "--out", str(tmp_path / "s")])
    assert res.exit_code == 0, res.output
    row = next(line for line in res.output.splitlines() if "M2.w2" in line and "│" in line)
    assert [c.strip() for c in row.split("│")][5] == "-"  # output, runs, excluded, k, MAPE
