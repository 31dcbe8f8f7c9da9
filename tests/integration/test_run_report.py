"""``calnet run --quick`` on one model observed by two data sets, with a discrepancy
variant compared: the report says each variant note once, says that a quick run's Sobol
spread is indicative only, and its wall time is the stage timings of run_info.json."""

from __future__ import annotations

import html
import json
import math
import re
import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from calnet.cli import app

TWODATA = Path(__file__).parent / "twodata"


def report_text(out: Path) -> str:
    """report.html's text as a reader sees it (tags, styles and images left out)."""
    page = (out / "report.html").read_text()
    page = re.sub(r"<(style|script)[^>]*>.*?</\1>|<img[^>]*>", " ", page, flags=re.S)
    return re.sub(r"\s+", " ", html.unescape(re.sub(r"<[^>]+>", " ", page)))


def check_report(out: Path) -> None:
    text = report_text(out)
    metrics = json.loads((out / "metrics.json").read_text())
    info = json.loads((out / "run_info.json").read_text())
    # each note of the variant once, though both data sets' comparisons carry it
    notes = {n for ds in metrics["comparison"].values() for n in
             ds["no_discrepancy"]["notes"]}
    assert notes, "the variant has no notes: the check below would test nothing"
    for note in notes:
        assert text.count(note) == 1, note
    # the quick run's spread over 3 draws is labelled indicative
    draws = {s["over_draws"]["n_draws"] for s in metrics["sensitivity"].values()}
    assert draws == {3}
    assert ("Quick run: the spread of ST over posterior draws comes from 3 posterior draws "
            "only, so it is indicative, not a 95 % interval") in text
    # the report's wall time is run_info.json's stage timings, not a second clock
    shown = re.search(r"Wall time ([0-9.]+) s for the stages before this report", text)
    stages = {k: v for k, v in info["timings_s"].items() if k not in ("total", "report")}
    # an exact sum: run_info.json lists the stages in another order than they ran
    assert shown and float(shown.group(1)) == round(math.fsum(stages.values()), 1), shown


@pytest.mark.integration
@pytest.mark.slow
def test_quick_run_report_of_two_data_sets_and_a_variant(tmp_path, monkeypatch):
    work = tmp_path / "twodata"
    shutil.copytree(TWODATA, work, ignore=shutil.ignore_patterns("campaigns", "__pycache__"))
    with (work / "d1.csv").open("a") as f:  # a measurement beyond x's upper bound, 2
        f.write(f"2.05,{1.2 * 2.05 + 0.2 * math.sin(3 * 2.05):.4f}\n")
    monkeypatch.syspath_prepend(str(work))
    monkeypatch.setenv("PYTHONPATH", str(work))
    out = tmp_path / "out"
    result = CliRunner().invoke(app, ["run", str(work), "--out", str(out), "--quick"])
    assert result.exit_code == 0, result.output
    check_report(out)
    # the data's warning, given while the data are read, is in the report and metrics,
    # without the spec's folder (metrics.json is the same wherever the spec is)
    outside = "d1.csv: data.d1: 1 of 11 point(s) lie outside the model's input bounds"
    assert outside in result.output
    metrics = (out / "metrics.json").read_text()
    assert json.loads(metrics)["warnings"][0].startswith(outside)  # the spec's come first
    assert str(tmp_path) not in metrics
    assert outside in report_text(out) and "No warnings" not in report_text(out)
    # each data set's noise sd and discrepancy, as calibrated (the data's noise sd: 0.03)
    terms = json.loads(metrics)["calibration"]["datasets"]
    assert set(terms) == {"d1", "d2"}
    for d in terms.values():
        for q in (d["noise_sd"], d["discrepancy_sd"], d["length_scales"]["x"]):
            assert 0 < q["q2.5"] < q["mean"] < q["q97.5"], d
    assert "Noise and discrepancy per data set" in report_text(out)
    # the sampler's diagnostics per stage, which is what they are computed for
    assert "Sampler diagnostics per calibration stage" in report_text(out)


WRONG = Path(__file__).parent / "wrongmodel"


@pytest.mark.integration
@pytest.mark.slow
def test_a_known_wrong_model_without_discrepancy_is_flagged(tmp_path, monkeypatch):
    """A linear model of quadratic data (y = 1 + 2x + 3x^2, noise sd 0.05 declared),
    `discrepancy: none`: the surrogate's variance in the likelihood lets leave-one-out
    predict a point from its neighbours' misfit, but the posterior predictive misses
    most of its own calibration points and of its held-out test points, and the warning
    says so and points to the discrepancy the spec switched off."""
    work = tmp_path / "wrong"
    shutil.copytree(WRONG, work, ignore=shutil.ignore_patterns("campaigns", "__pycache__"))
    monkeypatch.syspath_prepend(str(work))
    monkeypatch.setenv("PYTHONPATH", str(work))
    out = tmp_path / "out"
    result = CliRunner().invoke(app, ["run", str(work), "--out", str(out), "--quick"])
    assert result.exit_code == 0, result.output
    metrics = json.loads((out / "metrics.json").read_text())
    fit = metrics["validation"]["quad"]["loo"]["fit_check"]
    assert fit["flagged"] and fit["outside95"] >= 6 and fit["n"] == 16, fit
    said = [w for w in metrics["warnings"] if w.startswith("quad: the ")
            and "does not describe these data" in w]
    assert len(said) == 1 and "its spec sets discrepancy: none" in said[0], said
    assert "flagged" in report_text(out)
    # the held-out points, which the calibration has not seen, say the same
    held_out = metrics["validation"]["quad"]["test"]["check"]
    assert held_out["flagged"] and held_out["n"] == 3, held_out
    assert "the posterior predictive misses its test points" in said[0], said
