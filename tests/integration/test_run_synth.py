"""End to end: ``calnet run --quick`` on a synthetic three-model network with an
unmeasurable intermediate; the true parameters are known (synth/synth_sims.py)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from calnet.cli import app

SYNTH = Path(__file__).parent / "synth"


@pytest.mark.integration
def test_quick_run_on_three_model_network(tmp_path, monkeypatch):
    work = tmp_path / "synth"
    shutil.copytree(SYNTH, work, ignore=shutil.ignore_patterns("campaigns", "__pycache__"))
    monkeypatch.syspath_prepend(str(work))
    monkeypatch.setenv("PYTHONPATH", str(work))
    out = tmp_path / "out"
    result = CliRunner().invoke(app, ["run", str(work), "--out", str(out), "--quick"])
    assert result.exit_code == 0, result.output
    for rel in ("report.html", "metrics.json", "figures/network.png", "figures/data.png",
                "posterior/thermal.nc", "posterior/micro.nc", "posterior/hardness.nc"):
        assert (out / rel).is_file(), rel
    html = (out / "report.html").read_text()
    assert "data:image/png;base64," in html and "https://" not in html
    m = json.loads((out / "metrics.json").read_text())
    for key in ("campaigns", "surrogates", "calibration", "validation", "sensitivity",
                "predictions", "timings_s"):
        assert key in m, key
    assert set(m["surrogates"]) == {"thermal.W", "thermal.G", "micro.lam", "hardness.H"}
    for ds in ("width", "pdas"):
        assert {"mape", "se_pred", "coverage95"} <= set(m["validation"][ds]["test"])
        assert "training_mean" in m["validation"][ds]["baselines_test"]
    assert "calnet" in m["validation"]["hard"]["loo"]
    # the true parameters (a 1.2, b 0.8, c 2.0) lie in the 95 % intervals
    for model, name, true in (("thermal", "a", 1.2), ("micro", "b", 0.8), ("hardness", "c", 2.0)):
        row = m["calibration"]["models"][model]["parameters"][name]
        assert row["q2.5"] <= true <= row["q97.5"], (model, row)
