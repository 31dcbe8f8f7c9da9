"""``calnet campaign``: the Typer command, as the CLI registers it."""

from __future__ import annotations

import re
import sys

import pytest
import yaml
from campaign_helpers import HERE, campaign_app, toy_spec
from typer.testing import CliRunner

app = campaign_app()


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
    assert result.exit_code == 2  # a bad option value: a usage error
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
    assert result.exit_code == 2  # a bad option value: a usage error
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


def test_a_campaign_without_one_ok_run_exits_1(tmp_path):
    spec = toy_spec(tmp_path, "python:toy_sims:broken", runs=4)
    result = CliRunner().invoke(app, ["campaign", str(spec), "--no-progress"])
    assert result.exit_code == 1, result.output
    assert "license server unreachable" in result.output  # the failures are listed
    assert "no run of toy finished ok" in " ".join(result.output.split())
    again = CliRunner().invoke(app, ["campaign", str(spec), "--no-progress"])
    assert again.exit_code == 1 and "complete" in again.output  # a finished, useless store


def test_runs_of_a_command_that_fail_alike_are_counted_as_one_cause(tmp_path):
    # each message names its run's logs; the closing line counts the runs by cause
    spec = toy_spec(tmp_path, {"kind": "command", "argv": [sys.executable, str(
        HERE / "cmd_sim.py"), "fail"]}, runs=3)
    result = CliRunner().invoke(app, ["campaign", str(spec), "--no-progress"])
    assert result.exit_code == 1, result.output
    assert ("no run of toy finished ok (toy: 3 runs: failed: command exited with code 3: mesh "
            "generation failed);") in " ".join(result.output.split())


def test_an_unknown_executor_is_a_usage_error(tmp_path):
    spec = toy_spec(tmp_path, runs=4)
    result = CliRunner().invoke(app, ["campaign", str(spec), "--executor", "foo"])
    assert result.exit_code == 2
    assert "'foo' is not one of" in result.output
    assert not (tmp_path / "campaigns").exists()


def test_an_unknown_calibration_mode_is_a_usage_error(tmp_path):
    from calnet.cli import app as calnet_app

    for option in ("--mode", "--plug"):
        result = CliRunner().invoke(calnet_app, ["calibrate", str(tmp_path), option, "foo"])
        assert result.exit_code == 2, result.output
        assert "'foo' is not one of" in result.output


@pytest.mark.parametrize("workers", [1, 2])
def test_a_simulator_ending_its_process_is_a_failed_run(tmp_path, workers):
    """``os._exit`` in a Python simulator without a timeout: the run is recorded failed
    with the reason, every other run finishes, the campaign exits 0."""
    import json
    import subprocess

    from calnet.campaign.store import RunStore

    spec = toy_spec(tmp_path, "python:toy_sims:dies", runs=12)
    out = subprocess.run([sys.executable, "-m", "calnet", "campaign", str(spec), "--workers",
                          str(workers), "--no-progress"], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stdout + out.stderr
    with RunStore(tmp_path / "campaigns" / "toy.sqlite", readonly=True) as db:
        rows = db.rows()
    died = [r for r in rows if r["inputs"]["x"] > 0.9]
    assert died and all(r["status"] == "failed" and "died (exit code 7)" in r["message"]
                        for r in died), json.dumps(died)
    assert all(r["status"] == "ok" for r in rows if r["inputs"]["x"] <= 0.9)


@pytest.mark.parametrize(("runs", "more"), [(15, 10), (30, 25)])
def test_the_summary_counts_every_failure_beyond_the_five_shown(tmp_path, runs, more):
    spec = toy_spec(tmp_path, "python:toy_sims:broken", runs=runs)
    result = CliRunner().invoke(app, ["campaign", str(spec), "--executor", "in-process",
                                      "--no-progress"])
    assert result.exit_code == 1, result.output
    summary, error = result.output.split("error:")
    assert summary.count("license server unreachable") == 5  # the first five, and
    assert f"(toy: {runs} runs: failed: RuntimeError: license server" in " ".join(error.split())
    assert f"... {more} more not ok (see the store)" in result.output


def test_a_store_without_an_ok_run_starts_afresh_once_the_spec_is_fixed(tmp_path):
    """A simulator that fails everywhere, fixed in the spec: the store holds no result,
    so the next call (--retry-failed, as the error advises) simulates it afresh."""
    spec = toy_spec(tmp_path, "python:toy_sims:broken", runs=6)
    failed = CliRunner().invoke(app, ["campaign", str(spec), "--executor", "in-process",
                                      "--no-progress"])
    assert failed.exit_code == 1 and "--retry-failed" in failed.output
    toy_spec(tmp_path, "python:toy_sims:quadratic", runs=6)
    fixed = CliRunner().invoke(app, ["campaign", str(spec), "--executor", "in-process",
                                     "--retry-failed", "--no-progress"])
    assert fixed.exit_code == 0, fixed.output
    text = " ".join(fixed.output.split())
    assert "held no ok run and was made from another spec (simulator target: " \
           "toy_sims:broken -> toy_sims:quadratic); it is started afresh" in text
    assert "6 runs planned, 0 already finished, 6 run now" in text
    assert ": ok 6" in text


def test_a_store_with_results_names_only_the_changed_fields(tmp_path):
    spec = toy_spec(tmp_path, "python:toy_sims:quadratic", runs=4)
    args = ["campaign", str(spec), "--executor", "in-process", "--no-progress"]
    assert CliRunner().invoke(app, args).exit_code == 0
    toy_spec(tmp_path, {"kind": "python", "target": "toy_sims:quadratic",
                        "options": {"scale": 2.0}}, runs=4)
    refused = CliRunner().invoke(app, args)
    assert refused.exit_code == 1
    text = " ".join(refused.output.split())
    assert "(simulator options.scale: (unset) -> 2.0); simulate again with --fresh" in text
    assert "'kind'" not in text and "input_mode" not in text
    # the other way out keeps the runs: export the old store, import it into a new one
    assert ("or keep its runs: export them (`calnet campaign SPEC --model toy --export-only "
            "--export runs.csv`), then import them into a new --store (`calnet campaign "
            "SPEC --model toy --store NEW.sqlite --import runs.csv`)") in text
    table, new = tmp_path / "runs.csv", tmp_path / "NEW.sqlite"
    base = ["campaign", str(spec), "--model", "toy"]
    assert CliRunner().invoke(app, [*base, "--export-only", "--export", str(table)]
                              ).exit_code == 0
    moved = CliRunner().invoke(app, [*base, "--store", str(new), "--import", str(table)])
    assert moved.exit_code == 0 and "imported 4 runs" in moved.output, moved.output


def test_a_campaign_with_many_failed_runs_ends_with_a_warning_saying_where(tmp_path):
    spec = toy_spec(tmp_path, "python:toy_sims:crashy", runs=20)  # raises for x > 0.7
    result = CliRunner().invoke(app, ["campaign", str(spec), "--executor", "in-process",
                                      "--no-progress"])
    assert result.exit_code == 0, result.output
    text = " ".join(result.output.split())
    warning = re.search(r"warning: toy: (\d+) of 20 runs \((\d+) %\) did not finish ok "
                        r"\(failed \1\); they lie at x in \[0\.7\d*, [0-9.]+\], the ok runs "
                        r"at x in \[[0-9.]+, 0\.[0-6]\d*\]", text)
    assert warning, text
    assert round(100 * int(warning.group(1)) / 20) == int(warning.group(2))
    assert text.index("warning: toy:") > text.index("more not ok")  # at the end



def _chain_spec(folder, upstream: str):
    """``up`` (inputs x; parameters a, b; outputs y, z) feeds ``down.x`` from ``up.y``."""
    import yaml

    def model(sim):
        return {"simulator": sim, "inputs": {"x": {"lower": -2.0, "upper": 3.0}},
                "parameters": {"a": {"lower": 0.0, "upper": 1.0, "shared": True},
                               "b": {"lower": -1.0, "upper": 1.0, "shared": True}},
                "outputs": {"y": {}, "z": {}}, "campaign": {"runs": 6}}
    spec = {"name": "chain", "models": {"up": model(upstream),
                                        "down": model("python:toy_sims:quadratic")},
            "links": [{"from": "up.y", "to": "down.x"}], "settings": {"seed": 0}}
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "network.yaml").write_text(yaml.safe_dump(spec, sort_keys=False))
    return folder / "network.yaml"


def test_models_downstream_of_one_without_an_ok_run_are_not_simulated(tmp_path):
    spec = _chain_spec(tmp_path, "python:toy_sims:broken")
    result = CliRunner().invoke(app, ["campaign", str(spec), "--no-progress"])
    assert result.exit_code == 1, result.output
    said = " ".join(result.output.split())
    assert "no run of up finished ok" in said and "down, downstream of it, not simulated" in said
    assert not (tmp_path / "campaigns" / "down.sqlite").exists()


def test_a_chain_design_made_without_parent_runs_is_recorded_as_what_it_is(tmp_path):
    import sqlite3

    import yaml

    spec = _chain_spec(tmp_path, "python:toy_sims:quadratic")
    result = CliRunner().invoke(app, ["campaign", str(spec), "--model", "down",
                                      "--no-progress"])
    assert result.exit_code == 0, result.output
    assert "its design is a Latin hypercube instead" in " ".join(result.output.split())
    with sqlite3.connect(tmp_path / "campaigns" / "down.sqlite") as db:
        meta = dict(db.execute("SELECT key, value FROM meta"))
    db.close()
    assert meta["design_kind"] == "lhs" and "not a chain design" in meta["design"]
    # the parents' runs exist now; continuing the stand-in design says so, every time
    for argv in (["--model", "up"], ["--model", "down"], ["--model", "down", "--runs", "12"]):
        result = CliRunner().invoke(app, ["campaign", str(spec), *argv, "--no-progress"])
        assert result.exit_code == 0, result.output
        said = " ".join(result.output.split())
        assert ("holds a Latin hypercube, not a chain design" in said) == (argv[1] == "down"), said
    assert "--fresh for a chain design" in said and "campaign.design: lhs" in said
    # a spec that names the design keeps it without the note
    doc = yaml.safe_load(spec.read_text())
    doc["models"]["down"]["campaign"] = {**doc["models"]["down"].get("campaign", {}),
                                         "design": "lhs"}
    spec.write_text(yaml.safe_dump(doc, sort_keys=False))
    result = CliRunner().invoke(app, ["campaign", str(spec), "--model", "down", "--no-progress"])
    assert result.exit_code == 0 and "not a chain design" not in result.output, result.output


def test_calnet_run_stops_at_a_model_without_an_ok_run(tmp_path):
    from calnet.cli import app as calnet

    spec = _chain_spec(tmp_path, "python:toy_sims:broken")
    result = CliRunner().invoke(calnet, ["run", str(spec), "--out", str(tmp_path / "out"),
                                         "--quick"])
    assert result.exit_code == 1, result.output
    said = " ".join(result.output.split())
    assert "no run of 'up' finished ok (6 runs: failed: " in said and "license server" in said
    assert "--retry-failed" in said
    assert "the models after it were not simulated" in said and "Traceback" not in said
    assert not (tmp_path / "campaigns" / "down.sqlite").exists()


def test_a_worker_killed_from_outside_is_said_and_its_runs_run_again(tmp_path):
    marker = tmp_path / "killed"
    spec = toy_spec(tmp_path, {"kind": "python", "target": "toy_sims:killed_once",
                               "options": {"marker": str(marker)}}, runs=4)
    result = CliRunner().invoke(app, ["campaign", str(spec), "--workers", "1"])
    assert result.exit_code == 0, result.output
    text = " ".join(result.output.split())
    assert marker.is_file() and "toy.sqlite:ok4" in "".join(result.output.split())
    # run 1 was only queued behind run 0: it is not suspected, nor named
    said = ("a worker process died (killed by signal SIGKILL (9)) with run 0 running; it is run "
            "again alone (a run that ends its process again is recorded failed)")
    assert f"toy: {said}" in text  # the progress line, as it happens
    assert f"note: {said}" in text  # and the summary


def test_progress_lines_count_the_runs_not_ok_by_status(tmp_path):
    spec = toy_spec(tmp_path, "python:toy_sims:crashy", runs=10)
    result = CliRunner().invoke(app, ["campaign", str(spec), "--executor", "in-process"])
    text = "".join(result.output.split())  # the store's path may wrap, even mid-word
    n = int(re.search(r"toy\.sqlite:failed(\d+),ok", text).group(1))
    assert n > 0 and f"toy: 10/10 runs, {n} not ok (failed {n}) (" in result.output


def test_export_only_writes_the_store_as_it_is(tmp_path):
    """--export-only writes a partly finished store's runs and simulates nothing: the
    spec asks for 8 runs, the store holds 4."""
    import csv

    spec = toy_spec(tmp_path, runs=8)
    first = CliRunner().invoke(app, ["campaign", str(spec), "--runs", "4", "--no-progress"])
    assert first.exit_code == 0, first.output
    store = tmp_path / "campaigns" / "toy.sqlite"
    before = store.read_bytes()
    out = tmp_path / "runs.csv"
    result = CliRunner().invoke(app, ["campaign", str(spec), "--model", "toy", "--export",
                                      str(out), "--export-only"])
    assert result.exit_code == 0, result.output
    assert "toy: 4 runs in" in " ".join(result.output.split())
    assert "planned" not in result.output
    with out.open() as fh:
        assert len(list(csv.DictReader(fh))) == 4
    assert (tmp_path / "runs.meta.json").is_file()
    assert store.read_bytes() == before


@pytest.mark.parametrize(("args", "code", "message"), [
    (["--export-only"], 2, "--export-only writes a store to a file: give --export FILE"),
    (["--export-only", "--export", "x.csv", "--runs", "3", "--fresh"], 2,
     "--export-only simulates and imports nothing: drop --runs and --fresh"),
    (["--export-only", "--export", "x.csv"], 1, "no campaign store for 'toy' at"),
    (["--export-only", "--export", "x.csv", "--store", "nope.sqlite"], 1,
     "no campaign store for 'toy' at 'nope.sqlite'"),
])
def test_export_only_errors_are_one_line(tmp_path, monkeypatch, args, code, message):
    monkeypatch.chdir(tmp_path)
    spec = toy_spec(tmp_path, runs=4)
    result = CliRunner().invoke(app, ["campaign", str(spec), "--model", "toy", *args])
    assert result.exit_code == code, result.output
    said = " ".join(result.output.split())
    assert message in said and "Traceback" not in result.output
    assert ("first" in said) == ("--store" not in args and code == 1)  # no misleading fix
    assert not (tmp_path / "campaigns").exists()


def test_export_only_refuses_another_models_store_and_names_a_changed_seed(tmp_path):
    spec = toy_spec(tmp_path, runs=4, seed=2)
    assert CliRunner().invoke(app, ["campaign", str(spec), "--no-progress"]).exit_code == 0
    store = str(tmp_path / "campaigns" / "toy.sqlite")
    doc = spec.read_text().replace("toy:", "other:", 1)
    other = tmp_path / "other" / "network.yaml"
    other.parent.mkdir()
    other.write_text(doc)
    refused = CliRunner().invoke(app, ["campaign", str(other), "--model", "other", "--store",
                                       store, "--export", str(tmp_path / "o.csv"),
                                       "--export-only"])
    assert refused.exit_code == 1 and "holds runs of model 'toy', not of 'other'" in \
        " ".join(refused.output.split()), refused.output
    seeded = CliRunner().invoke(app, ["campaign", str(spec), "--model", "toy", "--seed", "5",
                                      "--export", str(tmp_path / "s.csv"), "--export-only"])
    assert seeded.exit_code == 0 and (tmp_path / "s.csv").is_file(), seeded.output
    assert "was made from seed 2, not 5; it is exported as it is" in " ".join(
        seeded.output.split()), seeded.output


def test_summaries_are_not_wrapped_off_a_terminal(tmp_path):
    """stdout to a log file: each summary line is one line, so that grep finds it."""
    deep = tmp_path / ("a-rather-long-folder-name-" * 3)
    spec = toy_spec(deep, runs=4)
    result = CliRunner().invoke(app, ["campaign", str(spec), "--no-progress"])
    assert result.exit_code == 0, result.output
    lines = result.output.splitlines()
    assert any("4 runs planned" in line and "re-run after an interruption) in" in line
               and line.endswith("lhs design)") for line in lines), result.output
    assert any(line.startswith(f"  store {deep}") and line.endswith("ok 4")
               for line in lines), result.output


@pytest.mark.parametrize("address", ["localhost", "notanaddr", "tcp://:8786x",
                                     "tcp://host:99999"])
def test_a_bad_scheduler_address_is_a_usage_error_before_anything_is_made(tmp_path,
                                                                          address):
    spec = toy_spec(tmp_path, runs=2)
    store = tmp_path / "x.sqlite"
    result = CliRunner().invoke(app, ["campaign", str(spec), "--store", str(store),
                                      "--scheduler", address, "--no-progress"])
    assert result.exit_code == 2, result.output
    assert (f"--scheduler '{address}' is not the address of a Dask scheduler; give "
            "tcp://HOST:PORT") in " ".join(result.output.split())
    assert not store.exists() and not (tmp_path / "campaigns").exists()


def test_a_model_whose_module_fails_at_import_does_not_stop_the_others(tmp_path):
    (tmp_path / "no_licence.py").write_text('raise RuntimeError("no licence server")\n')
    spec = toy_spec(tmp_path, runs=2)
    doc = yaml.safe_load(spec.read_text())
    toy = doc["models"]["toy"]
    doc["models"] = {"Lic": {"simulator": "python:no_licence:f", "inputs": toy["inputs"],
                             "outputs": {"w": {}}, "campaign": toy["campaign"]},
                     "Fine": toy}
    spec.write_text(yaml.safe_dump(doc, sort_keys=False))
    result = CliRunner().invoke(app, ["campaign", str(spec), "--no-progress"])
    said = " ".join(result.output.split())
    assert result.exit_code == 1, result.output
    assert "internal error" not in said
    assert "run 0: failed: RuntimeError: no licence server (at no_licence.py:1)" in said
    assert "Fine: 2 runs planned" in said and "Fine.sqlite: ok 2" in said


def test_a_simulator_that_changes_directory_in_process_leaves_the_campaign_alone(
        tmp_path, monkeypatch):
    (tmp_path / "elsewhere").mkdir()
    toy_spec(tmp_path, {"kind": "python", "target": "toy_sims:moves",
                        "options": {"to": str(tmp_path / "elsewhere")}}, runs=3)
    monkeypatch.chdir(tmp_path)
    result = CliRunner().invoke(app, ["campaign", "network.yaml", "--executor", "in-process",
                                      "--no-progress"])
    assert result.exit_code == 0, result.output
    assert "store campaigns/toy.sqlite: ok 3" in result.output


def test_export_only_says_the_counts_of_what_it_wrote(tmp_path, monkeypatch):
    """A run that a campaign still running finishes while --export-only reads the store
    is in the file and in the counts said, or in neither."""
    import csv
    import json

    from calnet.campaign.runners import RunRecord
    from calnet.campaign.store import RunStore

    spec = toy_spec(tmp_path, runs=4)
    assert CliRunner().invoke(app, ["campaign", str(spec), "--no-progress"]).exit_code == 0
    store = tmp_path / "campaigns" / "toy.sqlite"
    with RunStore(store) as db:
        db._db.execute("UPDATE runs SET status = NULL, outputs = NULL WHERE idx > 0")
    rows = RunStore.rows
    campaign = RunStore(store)  # the campaign still running, which finishes run 1

    def run_1_finishes(self, **kw):
        if self.readonly and campaign.status_counts().get("ok") == 1:
            campaign.record(RunRecord(1, "ok", {"y": 1.0, "z": 1.0}, "", {}, 0.1),
                            simulator="toy_sims:quadratic", version="toy-1")
        return rows(self, **kw)

    monkeypatch.setattr(RunStore, "rows", run_1_finishes)
    out = tmp_path / "runs.csv"
    try:
        result = CliRunner().invoke(app, ["campaign", str(spec), "--model", "toy",
                                          "--export", str(out), "--export-only"])
    finally:
        campaign.close()
    assert result.exit_code == 0, result.output
    with out.open() as fh:
        written = sorted(r["status"] for r in csv.DictReader(fh))
    said = " ".join(result.output.split())
    counts = {s: written.count(s) for s in set(written)}
    assert f"({', '.join(f'{k} {n}' for k, n in sorted(counts.items()))})" in said, said
    meta = json.loads((tmp_path / "runs.meta.json").read_text())
    assert meta["status_counts"] == counts


def test_the_failures_said_are_in_run_order():
    from rich.console import Console

    from calnet.campaign.campaign import CampaignSummary
    from calnet.campaign.command import print_summary

    console = Console(width=200, record=True)
    summary = CampaignSummary("toy", HERE / "toy.sqlite", 4, 0, 4, 0, {"failed": 3, "ok": 1},
                              {3: "failed: c", 0: "failed: a", 2: "failed: b"}, n_failed=3)
    print_summary(summary, console)
    said = [line.split(":")[0].strip() for line in console.export_text().splitlines()
            if line.strip().startswith("run ")]
    assert said == ["run 0", "run 2", "run 3"]
