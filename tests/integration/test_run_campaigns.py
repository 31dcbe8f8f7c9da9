"""``calnet run`` and its campaign stores: which stores a run uses with and without
``--fresh`` and ``--out``, and the warning about a model with many failed runs."""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from calnet.cli import app

SIMS = '''import os


def f(inputs):
    """y = x^2, one line per call in $ONE_SIMS_COUNT."""
    with open(os.environ["ONE_SIMS_COUNT"], "a") as fh:
        fh.write("f\\n")
    return {"y": inputs["x"] ** 2}


def g(inputs):
    """y = 2 x, failing for x > 0.5."""
    if inputs["x"] > 0.5:
        raise ValueError("solver diverged")
    return {"y": 2 * inputs["x"]}
'''


def _spec(folder: Path, function: str, runs: int = 8) -> Path:
    """An emulation-only network of one model (quick to run end to end)."""
    spec = {"name": "one", "models": {"M": {
        "simulator": f"python:one_sims:{function}", "inputs": {"x": {"lower": 0, "upper": 1}},
        "outputs": {"y": {}}, "campaign": {"runs": runs}}},
        "settings": {"seed": 0, "predict": ["M.y"]}}
    (folder / "network.yaml").write_text(yaml.safe_dump(spec, sort_keys=False))
    return folder


@pytest.fixture
def work(tmp_path, monkeypatch):
    folder = tmp_path / "one"
    folder.mkdir()
    (folder / "one_sims.py").write_text(SIMS)
    monkeypatch.syspath_prepend(str(folder))
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(
        p for p in (str(folder), os.environ.get("PYTHONPATH")) if p))
    monkeypatch.setenv("ONE_SIMS_COUNT", str(tmp_path / "calls.txt"))
    return folder


def _calls(work: Path) -> int:
    path = work.parent / "calls.txt"
    return len(path.read_text().splitlines()) if path.exists() else 0


def _run(*args: str):
    return CliRunner().invoke(app, ["run", *args, "--quick"])


def _stores(out: Path) -> set[str]:
    return set(json.loads((out / "run_info.json").read_text())["campaign_stores"].values())


@pytest.mark.integration
@pytest.mark.slow
def test_run_fresh_with_out_simulates_there_and_later_runs_use_it(work, tmp_path):
    _spec(work, "g")
    assert CliRunner().invoke(app, ["campaign", str(work), "--no-progress"]).exit_code == 0
    _spec(work, "f")  # the stores beside the spec are now of another spec
    out = tmp_path / "out"

    refused = _run(str(work), "--out", str(out))
    assert refused.exit_code == 1
    text = " ".join(refused.output.split())
    assert "(simulator target: one_sims:g -> one_sims:f)" in text
    assert ("`calnet campaign SPEC --fresh` simulates the stores beside the spec again, "
            "`calnet run SPEC --fresh --out OUT` those in OUT/campaigns (which later runs "
            "with that --out use)") in text

    fresh = _run(str(work), "--fresh", "--out", str(out))
    assert fresh.exit_code == 0, fresh.output
    assert _calls(work) == 8
    assert _stores(out) == {str((out / "campaigns" / "M.sqlite").resolve())}

    again = _run(str(work), "--out", str(out))  # uses out/campaigns: nothing to simulate
    assert again.exit_code == 0, again.output
    assert _calls(work) == 8
    assert _stores(out) == {str((out / "campaigns" / "M.sqlite").resolve())}

    refresh = _run(str(work), "--fresh", "--out", str(out))  # simulates everything again
    assert refresh.exit_code == 0, refresh.output
    assert _calls(work) == 16

    other = tmp_path / "other"  # another --out holds no store: the spec's are used
    beside = _run(str(work), "--out", str(other))
    assert beside.exit_code == 1 and "one_sims:g -> one_sims:f" in beside.output


@pytest.mark.integration
@pytest.mark.slow
def test_run_warns_about_a_model_with_many_failed_runs(work, tmp_path):
    _spec(work, "g", runs=12)
    out = tmp_path / "out"
    result = _run(str(work), "--out", str(out))
    assert result.exit_code == 0, result.output
    text = " ".join(result.output.split())
    found = re.search(r"warning: M: (\d+) of 12 runs \(\d+ %\) did not finish ok \(failed "
                      r"\1\); they lie at x in \[0\.5\d*, [0-9.]+\], the ok runs at x in "
                      r"\[[0-9.]+, 0\.[0-4]\d*\]", text)
    assert found, text
    # and why they failed: the simulator's commonest message
    assert re.search(r"the commonest outcome: failed \(\d+ runs\), e\.g\. ValueError: "
                     r"solver diverged", text), text
    assert text.index("warning: M:") > text.index("total wall time")  # at the end
    warnings = json.loads((out / "metrics.json").read_text())["warnings"]
    assert any(w.startswith("M: ") and "did not finish ok" in w for w in warnings)
