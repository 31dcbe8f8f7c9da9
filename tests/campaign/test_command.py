"""``calnet campaign``: the Typer command, as the CLI registers it."""

from __future__ import annotations

import sys

import pytest
import typer
from campaign_helpers import toy_spec
from typer.testing import CliRunner

from calnet.campaign.command import campaign
from calnet.cli import user_errors

app = typer.Typer()
app.command("campaign")(user_errors(campaign))
app.command("other")(lambda: None)  # two commands, so the app dispatches by name


def test_command_runs_exports_and_resumes(tmp_path):
    spec = toy_spec(tmp_path, "python:toy_sims:crashy", runs=8)
    out = tmp_path / "runs.csv"
    result = CliRunner().invoke(app, ["campaign", str(spec), "--model", "toy", "--export",
                                      str(out), "--no-progress"])
    assert result.exit_code == 0, result.output
    assert "8 runs planned, 0 already finished, 8 run now" in result.output
    assert out.is_file() and (tmp_path / "runs.meta.json").is_file()
    store = tmp_path / "campaigns" / "toy.sqlite"
    before = store.read_bytes()
    again = CliRunner().invoke(app, ["campaign", str(spec), "--no-progress"])
    assert "complete, all 8 runs finished" in again.output
    assert store.read_bytes() == before  # a complete store is read, never written


def test_command_errors_are_one_line(tmp_path):
    spec = toy_spec(tmp_path)
    result = CliRunner().invoke(app, ["campaign", str(spec), "--model", "nope"])
    assert result.exit_code == 1
    assert "no model named 'nope'" in result.output


@pytest.mark.parametrize(("name", "message"), [
    ("runs.txt", "cannot export to 'runs.txt'; name the file *.csv or *.parquet"),
    ("runs.parquet", "Parquet export needs pyarrow"),
])
def test_a_bad_export_file_is_refused_before_any_run(tmp_path, monkeypatch, name, message):
    monkeypatch.setitem(sys.modules, "pyarrow", None)
    spec = toy_spec(tmp_path, runs=4)
    result = CliRunner().invoke(app, ["campaign", str(spec), "--export", str(tmp_path / name),
                                      "--no-progress"])
    assert result.exit_code == 1
    assert message in " ".join(result.output.split())
    assert "runs planned" not in result.output
    assert not (tmp_path / "campaigns").exists()  # nothing was simulated


def test_command_is_import_light():
    import subprocess
    import sys

    code = ("import sys, calnet.campaign.command; "
            "print(any(m.split('.')[0] in ('dask', 'distributed', 'umbridge', 'scipy') "
            "for m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.stdout.strip() == "False", out.stderr
