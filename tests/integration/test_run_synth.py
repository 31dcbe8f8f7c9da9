"""End to end: ``calnet run --quick`` on a synthetic three-model network with an
unmeasurable intermediate; the true parameters are known (synth/synth_sims.py)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from calnet.cli import app
from calnet.pipeline import STAGES

SYNTH = Path(__file__).parent / "synth"


BANNER = "undergoing a major refactor"  # ArviZ's once-a-day notice (tests/test_cli.py)


@pytest.fixture(scope="module")
def two_runs(tmp_path_factory):
    """``calnet run --quick`` twice, in two processes, from two copies of the spec into two
    folders, each running its campaigns (no stores copied). Piped output; a fresh cache
    folder each (so ArviZ's notice would be due)."""
    tmp = tmp_path_factory.mktemp("synth")
    src = Path(__file__).resolve().parents[2] / "src"
    jax_cache = os.environ.get("CALNET_JAX_CACHE") or str(Path.home() / ".cache/calnet/jax")
    runs = []
    for k in (1, 2):
        work = tmp / f"spec{k}" / "synth"
        shutil.copytree(SYNTH, work, ignore=shutil.ignore_patterns("campaigns", "__pycache__"))
        env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(work), str(src)]),
               "XDG_CACHE_HOME": str(tmp / f"cache{k}"), "CALNET_JAX_CACHE": jax_cache}
        env.pop("COLUMNS", None)
        out = tmp / f"out{k}"
        run = subprocess.run([sys.executable, "-m", "calnet", "run", str(work), "--out",
                              str(out), "--quick"], env=env, capture_output=True, text=True,
                             timeout=900)
        runs.append((work, out, run))
    return tmp, runs


@pytest.mark.integration
def test_quick_run_on_three_model_network(two_runs, monkeypatch):
    tmp_path, runs = two_runs
    work, out, run = runs[0]
    assert run.returncode == 0, run.stdout + run.stderr
    monkeypatch.syspath_prepend(str(work))
    monkeypatch.setenv("PYTHONPATH", str(work))
    # the campaigns ran here: the copy had no stores
    assert {p.name.split(".")[0] for p in (work / "campaigns").iterdir()} >= {
        "thermal", "micro", "hardness"}
    for rel in ("report.html", "metrics.json", "figures/network.png", "figures/data.png",
                "posterior/thermal.nc", "posterior/micro.nc", "posterior/hardness.nc",
                "posterior/posterior_draws.csv", "posterior/posterior_summary.csv"):
        assert (out / rel).is_file(), rel
    html = (out / "report.html").read_text()
    assert "data:image/png;base64," in html and "https://" not in html
    assert "reference study" not in html  # not the case study: no comparison with it
    _check_report(out)
    m = json.loads((out / "metrics.json").read_text())
    for key in ("campaigns", "surrogates", "calibration", "validation", "sensitivity",
                "predictions"):
        assert key in m, key
    info = json.loads((out / "run_info.json").read_text())
    assert set(info["timings_s"]) == {*STAGES, "total"}
    assert set(info["calibration_stages"]) == {"thermal", "micro", "hardness"}
    assert set(m["surrogates"]) == {"thermal.W", "thermal.G", "micro.lam", "hardness.H"}
    for ds in ("width", "pdas"):
        assert {"mape", "rmse", "nrmse", "crps", "coverage95"} <= set(m["validation"][ds]["test"])
        assert "training_mean" in m["validation"][ds]["baselines_test"]
    assert "calnet" in m["validation"]["hard"]["loo"]
    # the true parameters (a 1.2, b 0.8, c 2.0) lie in the 95 % intervals
    for model, name, true in (("thermal", "a", 1.2), ("micro", "b", 0.8), ("hardness", "c", 2.0)):
        row = m["calibration"]["models"][model]["parameters"][name]
        assert row["q2.5"] <= true <= row["q97.5"], (model, row)
    _check_predict(work, out, tmp_path)


def _check_report(out: Path) -> None:
    """The headline box, captions in words, one meaning of "runs" per column, the posterior
    CSVs, and (with Chromium) a clean render."""
    import csv
    import re
    import shutil

    from calnet.report.screenshot import CHROMIUM, check_page

    html = (out / "report.html").read_text()
    assert html.index('id="headline"') < html.index("<nav>")
    for text in ("Calibrated parameters", "Prediction error: RMSE (MAPE)", "thermal.a",
                 "finished runs", "runs not ok (left out)", "training runs"):
        assert text in html, text
    captions = re.findall(r"<figcaption>(.*?)</figcaption>", html)
    assert captions and all(len(c.split()) > 5 for c in captions), captions
    with open(out / "posterior" / "posterior_draws.csv", newline="") as fh:
        header = next(csv.reader(fh))
    assert header == ["draw", "thermal.a", "micro.b", "hardness.c"]
    exe = CHROMIUM if Path(CHROMIUM).exists() else shutil.which("chromium")
    if exe:
        page = check_page(out / "report.html", chromium=exe, ids=["headline"])
        assert page is not None and page.ok, page
        assert page.images >= 10 and page.tops["headline"] < 300


def _check_predict(work: Path, out: Path, tmp_path: Path) -> None:
    """``calnet predict`` on the folder ``calnet run`` wrote: --at, --csv, JSON, errors."""
    runner = CliRunner()
    res = runner.invoke(app, ["predict", str(work), "--run", str(out), "--at", "P=200,v=0.5",
                              "--at", "thermal.P=120,v=1.2", "-d", "pdas", "--json"])
    assert res.exit_code == 0, res.output
    doc = json.loads(res.output)["predictions"]
    assert len(doc) == 1 and doc[0]["observes"] == "micro.lam"
    assert doc[0]["x"] == [[200.0, 0.5], [120.0, 1.2]]
    for lo, m, hi in zip(doc[0]["lower95"], doc[0]["mean"], doc[0]["upper95"], strict=True):
        assert 0 < lo < m < hi
    shares = doc[0]["variance_shares"]
    assert abs(sum(shares.values()) - 1) < 1e-9 and "emulator thermal.G" in shares
    # the widths have no surrogate upstream: the budget names their own (thermal.W) and
    # none of those feeding the models downstream of them (thermal.G, micro.lam)
    res = runner.invoke(app, ["predict", str(work), "--run", str(out), "--at", "P=200,v=0.5",
                              "-d", "width", "--json"])
    assert res.exit_code == 0, res.output
    shares = json.loads(res.output)["predictions"][0]["variance_shares"]
    assert [k for k in shares if k.startswith("emulator")] == ["emulator thermal.W"], shares
    points = tmp_path / "points.csv"
    points.write_text("P,v\n150,0.8\n300,0.5\n")
    table = tmp_path / "pred.csv"
    res = runner.invoke(app, ["predict", str(work), "--run", str(out), "--csv", str(points),
                              "--output", str(table)])
    assert res.exit_code == 0, res.output
    assert "outside its bounds" in res.output  # P = 300 W extrapolates: said, not hidden
    lines = table.read_text().splitlines()
    assert lines[0] == "point,dataset,output,thermal.P,thermal.v,mean,lower95,upper95"
    assert len(lines) == 1 + 2 * 3  # two points for each of the three data sets
    res = runner.invoke(app, ["predict", str(work), "--run", str(out), "--at", "P=200"])
    assert res.exit_code == 2 and "missing v" in res.output  # a bad --at value
    res = runner.invoke(app, ["predict", str(work), "--run", str(tmp_path / "none"),
                              "--at", "P=200,v=1"])
    assert res.exit_code == 1 and "no fitted surrogates" in res.output
    res = runner.invoke(app, ["predict", str(work), "--run", str(out), "--at", "P=200,v=1",
                              "--seed", "-5"])
    assert res.exit_code == 2  # a usage error, not a crash
    # the run folder of another spec: one line that says so, from predict, verify, calibrate
    ninb = Path(__file__).parents[2] / "examples" / "ninb"
    for argv in (["predict", str(ninb), "--run", str(out), "--at", "P=200,v=0.5"],
                 ["verify", str(ninb), "--run", str(out), "-k", "1"],
                 ["calibrate", str(ninb), "--surrogates", str(out / "surrogates"),
                  "--out", str(tmp_path / "cal")]):
        res = runner.invoke(app, argv)
        assert res.exit_code == 1, (argv, res.output)
        assert "were not fitted for network 'ninb'" in res.output
        assert "Traceback" not in res.output


@pytest.mark.integration
def test_same_seed_writes_the_same_metrics_bytes(two_runs):
    """The two runs write the same metrics.json, byte for byte (campaigns included);
    timings, paths and the host go to run_info.json.
    Piped output: plain progress lines, no ArviZ notice."""
    tmp_path, runs = two_runs
    for _, _, run in runs:
        assert run.returncode == 0, run.stdout + run.stderr
        text = run.stdout + run.stderr
        assert BANNER not in text and "\r" not in text
        for stage in STAGES:
            assert f"{stage}: done in " in run.stderr, stage
        assert "calibration: thermal: sampled (" in run.stderr
    outs = [out for _, out, _ in runs]
    first, second = ((o / "metrics.json").read_bytes() for o in outs)
    assert first == second
    assert BANNER.encode() not in first and str(tmp_path).encode() not in first
    info = json.loads((outs[1] / "run_info.json").read_text())
    assert set(info["timings_s"]) == {*STAGES, "total"} and info["timings_s"]["total"] > 0
    assert all(v["compile_s"] >= 0 and v["sampling_s"] > 0
               for v in info["calibration_stages"].values())
    assert info["out"] == str(outs[1].resolve()) and info["versions"]["calnet"]
    assert BANNER not in (outs[1] / "report.html").read_text()


def test_shipped_synth_campaigns_match_the_spec():
    """The stores in synth/campaigns are the current spec's, complete (so that
    ``calnet run tests/integration/synth`` reads them instead of refusing them)."""
    from calnet.campaign import load_runs
    from calnet.spec import load_spec

    network = load_spec(SYNTH)
    for name, runs in (("thermal", 40), ("micro", 30), ("hardness", 60)):
        table = load_runs(network, name)
        assert table.n_ok == runs and table.status_counts == {"ok": runs}, name
