"""The driver and the store: resume, augment, failures, the read API, export."""

from __future__ import annotations

import json
import sqlite3
import sys
from pathlib import Path

import numpy as np
import pytest
from campaign_helpers import store_rows, toy_network

from calnet.campaign import default_store, export_runs, load_runs, run_campaign, runs_frame
from calnet.campaign.store import RunStore
from calnet.errors import CampaignError, CampaignWarning


def test_campaign_stores_every_run_and_reads_back(tmp_path):
    net = toy_network(tmp_path, runs=10)
    summary = run_campaign(net, "toy", progress=False)
    assert summary.store_path == default_store(net, "toy") == tmp_path / "campaigns/toy.sqlite"
    assert (summary.planned, summary.ran, summary.skipped) == (10, 10, 0)
    assert summary.status_counts == {"ok": 10} and summary.complete
    table = load_runs(net, "toy")
    assert table.columns == ("x", "a", "b")
    assert table.X.shape == (10, 3) and set(table.Y) == {"y", "z"}
    x, a, b = table.X.T
    np.testing.assert_allclose(table.Y["y"], x * x + a * x + b)
    assert (table.n_total, table.n_excluded) == (10, 0)
    row = RunStore(summary.store_path, readonly=True).rows()[0]
    assert row["simulator"] == "toy_sims:quadratic" and row["simulator_version"] == "toy-1"
    assert row["seed"] == 0 and len(row["input_hash"]) == 64 and row["wall_time"] >= 0
    assert not (tmp_path / "campaigns/toy.sqlite-wal").exists()


def test_failures_are_recorded_and_excluded(tmp_path):
    crashy = toy_network(tmp_path / "c", "python:toy_sims:crashy", runs=20)
    summary = run_campaign(crashy, "toy", progress=False)
    counts = summary.status_counts
    assert counts["failed"] > 0 and counts["ok"] > 0 and sum(counts.values()) == 20
    assert all("diverged" in m for m in summary.failures.values())
    table = load_runs(crashy, "toy")
    assert table.n_excluded == counts["failed"] and len(table.X) == counts["ok"]
    assert (table.X[:, 0] <= 0.7).all()

    nan = toy_network(tmp_path / "n", "python:toy_sims:nan_out", runs=20)
    counts = run_campaign(nan, "toy", progress=False).status_counts
    assert counts["failed"] > 0
    assert np.isfinite(load_runs(nan, "toy").Y["y"]).all()


def test_a_hanging_simulator_times_out_and_the_campaign_completes(tmp_path):
    # a limit of 3 s: on a loaded machine an ok run of the toy (in a worker process) took
    # over 1 s
    net = toy_network(tmp_path, "python:toy_sims:hangs", runs=5, timeout=3.0, x_upper=0.3)
    summary = run_campaign(net, "toy", progress=False, workers=2)
    assert summary.complete and summary.status_counts.get("timeout", 0) >= 1
    assert summary.status_counts.get("ok", 0) >= 1
    messages = [r["message"] for r in RunStore(summary.store_path, readonly=True).rows()
                if r["status"] == "timeout"]
    assert all("timeout of 3 s" in m for m in messages)


def test_resume_skips_finished_and_reruns_in_flight(tmp_path):
    net = toy_network(tmp_path, runs=8)
    path = default_store(net, "toy")
    run_campaign(net, "toy", progress=False)
    with RunStore(path) as db:  # pretend runs 2 and 5 were in flight when a campaign died
        db._db.execute("UPDATE runs SET status = NULL, outputs = NULL WHERE idx IN (2, 5)")
        db._db.commit()
        kept = {r["idx"]: r["finished_at"] for r in db.rows() if r["status"]}
    summary = run_campaign(net, "toy", progress=False)
    assert (summary.skipped, summary.ran, summary.rerun_in_flight) == (6, 2, 2)
    after = {r["idx"]: r["finished_at"] for r in RunStore(path, readonly=True).rows()}
    assert all(after[i] == t for i, t in kept.items())
    again = run_campaign(net, "toy", progress=False)
    assert (again.ran, again.skipped) == (0, 8)


def test_more_runs_augment_the_design(tmp_path):
    net = toy_network(tmp_path, runs=6)
    run_campaign(net, "toy", progress=False)
    before = store_rows(default_store(net, "toy"))
    summary = run_campaign(net, "toy", runs=9, progress=False)
    assert (summary.planned, summary.ran) == (9, 3)
    after = store_rows(default_store(net, "toy"))
    assert after[:6] == before
    assert len({r[1] for r in after}) == 9  # no input hash repeated
    fewer = run_campaign(net, "toy", runs=4, progress=False)
    assert (fewer.planned, fewer.ran) == (9, 0)
    assert fewer.notes == ("--runs asks for 4 runs, the store plans 9: all 9 are kept (a "
                           "design shrinks only in a new store: --fresh, which deletes these "
                           "runs, or a new --store)",)
    again = run_campaign(net, "toy", progress=False)  # the spec's 6 < 9
    assert again.planned == 9 and again.notes[0].startswith(
        "models.toy.campaign.runs asks for 6 runs, the store plans 9: all 9 are kept")


def test_fewer_runs_in_the_spec_than_the_store_holds_are_said(tmp_path):
    """The spec's campaign.runs lowered from 8 to 5 after the runs finished: the store's
    8 runs are kept and used, and the summary says so (as for --runs 5)."""
    run_campaign(toy_network(tmp_path, runs=8), "toy", progress=False)
    summary = run_campaign(toy_network(tmp_path, runs=5), "toy", progress=False)
    assert summary.complete and (summary.planned, summary.ran) == (8, 0)
    assert summary.notes == ("models.toy.campaign.runs asks for 5 runs, the store plans 8: "
                             "all 8 are kept (a design shrinks only in a new store: --fresh, "
                             "which deletes these runs, or a new --store)",)


def test_retry_failed_and_fresh(tmp_path):
    net = toy_network(tmp_path, "python:toy_sims:crashy", runs=10)
    first = run_campaign(net, "toy", progress=False)
    retry = run_campaign(net, "toy", progress=False, retry_failed=True)
    assert retry.ran == first.status_counts["failed"]
    fresh = run_campaign(net, "toy", progress=False, fresh=True)
    assert fresh.ran == 10 and fresh.skipped == 0


def test_seed_zero_is_a_seed_and_a_store_keeps_its_seed(tmp_path):
    net = toy_network(tmp_path, runs=4, seed=7)
    a = run_campaign(net, "toy", progress=False, seed=0, store=tmp_path / "a.sqlite")
    b = run_campaign(net, "toy", progress=False, store=tmp_path / "b.sqlite")
    assert (a.seed, b.seed) == (0, 7)
    assert store_rows(a.store_path) != store_rows(b.store_path)
    with pytest.raises(CampaignError, match=r"made with seed 0, not 7; to keep it, set "
                       r"settings.seed back to 0 \(calnet campaign: --seed 0\); for the new "
                       r"seed, simulate again with --fresh: `calnet campaign SPEC --fresh`"):
        run_campaign(net, "toy", progress=False, store=a.store_path)


def test_load_runs_errors_name_the_fix(tmp_path):
    net = toy_network(tmp_path, runs=4)
    with pytest.raises(CampaignError, match="run `calnet campaign .* --model toy` first"):
        load_runs(net, "toy")
    run_campaign(net, "toy", progress=False)
    moved = toy_network(tmp_path, runs=4, x_upper=2.0)
    with pytest.raises(CampaignError, match=r"bounds of 'x' changed from \[0.0, 1.0\] to "
                                            r"\[0.0, 2.0\]\); re-simulate .*--fresh"):
        load_runs(moved, "toy")
    with pytest.raises(CampaignError, match="different 'toy' spec"):
        run_campaign(moved, "toy", progress=False)
    with pytest.raises(CampaignError, match="scale of 'x' changed to log"):
        load_runs(toy_network(tmp_path, runs=4, x_scale="log"), "toy")
    with pytest.raises(CampaignError, match="no model named 'nope'"):
        load_runs(net, "nope")


def test_not_a_store(tmp_path):
    bad = tmp_path / "bad.sqlite"
    bad.write_text("not a database" * 100)
    with pytest.raises(CampaignError, match="not a calnet campaign store"):
        RunStore(bad)


def test_a_damaged_store_is_called_damaged(tmp_path):
    """A store cut short (a copy interrupted, a disk fault): SQLite finds it malformed; the
    error says so and how to recover, not that it is no store."""
    net = toy_network(tmp_path, runs=6)
    run_campaign(net, "toy", progress=False)
    path = default_store(net, "toy")
    with open(path, "r+b") as fh:
        fh.truncate(path.stat().st_size // 2)
    with pytest.raises(CampaignError, match=r"is damaged \(database disk image is "
                                            r"malformed\).*--fresh"):
        load_runs(net, "toy")


def test_export_csv_and_parquet(tmp_path, monkeypatch):
    import pandas as pd

    net = toy_network(tmp_path, "python:toy_sims:crashy", runs=6)
    path = run_campaign(net, "toy", progress=False).store_path
    csv = export_runs(path, tmp_path / "out" / "toy.csv")
    frame = pd.read_csv(csv)
    assert list(frame.columns[:8]) == ["run", "status", "message", "x", "a", "b", "y", "z"]
    table = load_runs(net, "toy")
    ok = frame[frame.status == "ok"]
    np.testing.assert_array_equal(ok[["x", "a", "b"]].to_numpy(), table.X)  # exact floats
    meta = json.loads((tmp_path / "out" / "toy.meta.json").read_text())
    assert meta["model"] == "toy" and meta["calnet_version"] and len(meta["model_hash"]) == 64
    pq = pd.read_parquet(export_runs(path, tmp_path / "toy.parquet"))
    assert pq.shape == frame.shape
    monkeypatch.setitem(sys.modules, "pyarrow", None)
    with pytest.raises(CampaignError, match="Parquet export needs pyarrow"):
        export_runs(path, tmp_path / "again.parquet")
    with pytest.raises(CampaignError, match=r"\*.csv or \*.parquet"):
        export_runs(path, tmp_path / "toy.xlsx")


def test_store_is_plain_sqlite(tmp_path):
    net = toy_network(tmp_path, runs=3)
    path = run_campaign(net, "toy", progress=False).store_path
    with sqlite3.connect(path) as db:
        status = [s for (s,) in db.execute("SELECT status FROM runs ORDER BY idx")]
    db.close()
    assert status == ["ok", "ok", "ok"]


def test_a_store_made_by_another_simulator_version_is_not_mixed(tmp_path):
    net = toy_network(tmp_path, runs=6)
    path = run_campaign(net, "toy", progress=False).store_path
    with sqlite3.connect(path) as db:  # as if an older simulator had made these runs
        db.execute("UPDATE runs SET simulator_version = 'toy-0'")
    from calnet.errors import CampaignWarning

    with pytest.warns(CampaignWarning, match="6 runs with toy_sims:quadratic toy-0.*toy-1"):
        summary = run_campaign(net, "toy", progress=False)  # complete: used, with a warning
    assert summary.ran == 0
    with pytest.raises(CampaignError, match="mix two versions.*--fresh"):
        run_campaign(net, "toy", runs=9, progress=False)
    assert RunStore(path, readonly=True).status_counts() == {"ok": 6, "unfinished": 3}
    summary = run_campaign(net, "toy", runs=9, progress=False, fresh=True)
    assert summary.status_counts == {"ok": 9}


def test_the_old_version_warning_reads_the_same_wherever_the_spec_is(tmp_path):
    """``calnet run`` keeps the warning in metrics.json, whose bytes must not depend on
    the spec folder's place: the store is named relative to the spec's folder."""
    from calnet.errors import CampaignWarning

    messages = []
    for folder in (tmp_path / "a", tmp_path / "deep" / "er" / "b"):
        net = toy_network(folder, runs=4)
        path = run_campaign(net, "toy", progress=False).store_path
        with sqlite3.connect(path) as db:
            db.execute("UPDATE runs SET simulator_version = 'toy-0'")
        db.close()
        with pytest.warns(CampaignWarning) as caught:
            run_campaign(net, "toy", progress=False)
        messages += [str(w.message) for w in caught]
    assert len(messages) == 2 and messages[0] == messages[1]
    assert "the campaign store of 'toy' (campaigns/toy.sqlite) holds 4 runs" in messages[0]
    assert str(tmp_path) not in messages[0]


def test_resume_keeps_stored_inputs_bit_for_bit(tmp_path):
    """A stored design is never recomputed: points whose last bits would not survive a
    round trip through the unit cube (another machine, another SciPy) still resume, and
    augmenting only plans the new points."""
    from calnet.campaign.store import input_hash

    net = toy_network(tmp_path, runs=6)
    path = run_campaign(net, "toy", progress=False).store_path
    with sqlite3.connect(path) as db:
        for idx, text in db.execute("SELECT idx, inputs FROM runs").fetchall():
            inputs = {k: float(np.nextafter(v, np.inf)) for k, v in json.loads(text).items()}
            db.execute("UPDATE runs SET inputs = ?, input_hash = ? WHERE idx = ?",
                       (json.dumps(inputs), input_hash(inputs), idx))
        before = db.execute("SELECT inputs FROM runs ORDER BY idx").fetchall()
    assert run_campaign(net, "toy", progress=False).ran == 0
    summary = run_campaign(net, "toy", runs=8, progress=False)
    assert summary.ran == 2 and summary.status_counts == {"ok": 8}
    with sqlite3.connect(path) as db:
        assert db.execute("SELECT inputs FROM runs WHERE idx < 6 ORDER BY idx").fetchall() \
            == before


def test_a_module_beside_the_spec_has_its_version_stored(tmp_path, monkeypatch):
    """``python:beside_sim:f`` found only in the spec's folder: its ``VERSION`` is
    recorded in the store's metadata and on every run."""
    monkeypatch.setattr(sys, "path", list(sys.path))  # the spec's folder is appended
    monkeypatch.delitem(sys.modules, "beside_sim", raising=False)
    (tmp_path / "beside_sim.py").write_text(
        'VERSION = "2.5"\n\ndef f(inputs):\n    return {"y": inputs["x"], "z": inputs["a"]}\n')
    net = toy_network(tmp_path, "python:beside_sim:f", runs=3)
    path = run_campaign(net, "toy", progress=False, executor="in-process").store_path
    with RunStore(path, readonly=True) as db:
        assert db.meta()["simulator_version"] == "2.5"
        assert db.versions() == {"2.5": 3}


def test_progress_lines_through_a_callable(tmp_path):
    out = []
    run_campaign(toy_network(tmp_path, runs=20), "toy", progress=out.append,
                 executor="in-process")
    assert out[0].startswith("toy: 20 runs to go of 20")
    assert out[-1].startswith("toy: 20/20 runs, 0 not ok")
    assert 3 <= len(out) <= 12 and not any("\r" in line for line in out)


def test_progress_lines_go_on_while_runs_are_in_flight(tmp_path, monkeypatch):
    """A run that takes long (or hangs) still gets a line every EVERY_S seconds, naming
    the runs in flight, so that a batch log tells a hung simulator from a slow one."""
    from calnet.campaign import progress_bar

    monkeypatch.setattr(progress_bar, "EVERY_S", 0.1)
    out = []
    run_campaign(toy_network(tmp_path, "python:toy_sims:slower", runs=2), "toy",
                 progress=out.append, executor="in-process")
    waiting = [line for line in out if "in flight" in line]
    assert waiting, out
    assert all(line.startswith("toy: ") and ", 1 in flight (the oldest for " in line
               for line in waiting)
    assert waiting[0].startswith("toy: 0/2 runs, 0 not ok, 1 in flight")
    assert out[-1].startswith("toy: 2/2 runs, 0 not ok (")


def test_progress_without_a_terminal_is_lines_on_stderr(tmp_path, capfd):
    run_campaign(toy_network(tmp_path, runs=10), "toy", progress=True, executor="in-process")
    err = capfd.readouterr().err
    assert "toy: 10/10 runs, 0 not ok" in err and "\r" not in err


def test_an_undeclared_output_is_warned_about_once_per_campaign(tmp_path):
    spec = {"kind": "python", "target": "toy_sims:misnamed", "options": {"shape": "extra"}}
    net = toy_network(tmp_path, spec, runs=8)
    with pytest.warns(CampaignWarning) as caught:
        summary = run_campaign(net, "toy", executor="in-process", progress=False)
    assert summary.status_counts == {"ok": 8}
    messages = [str(w.message) for w in caught]
    assert len(messages) == 2  # one per name: 'residual' from run 0, 'iterations' later
    x = runs_frame(summary.store_path).x.to_numpy()
    first = int(np.flatnonzero(x > 0.6)[0])
    assert messages == [
        "toy: the simulator returned 'residual' (run 0 first), not declared in "
        "models.toy.outputs; the store keeps it, calnet uses only the declared outputs "
        "(y, z): declare it to use it, or stop returning it",
        f"toy: the simulator returned 'iterations' (run {first} first), not declared in "
        "models.toy.outputs; the store keeps it, calnet uses only the declared outputs "
        "(y, z): declare it to use it, or stop returning it"]
    assert all(w.filename == __file__ for w in caught)  # stacklevel: the caller


@pytest.mark.parametrize(("source", "message"), [
    ('raise RuntimeError("no licence server")\n', "RuntimeError: no licence server (at "),
    ("def f(inputs):\n    return {'y': 1\n", "SyntaxError: '{' was never closed"),
    ('import os\n__version__ = os.sep\nraise RuntimeError("no licence server")\n',
     "RuntimeError: no licence server (at "),  # a version only importing it tells
])
def test_a_module_that_raises_at_import_fails_its_runs_not_the_campaign(
        tmp_path, monkeypatch, source, message):
    monkeypatch.setattr(sys, "path", list(sys.path))  # the spec's folder is appended
    name = f"at_import_{abs(hash(source))}"
    (tmp_path / f"{name}.py").write_text(source)
    net = toy_network(tmp_path, f"python:{name}:f", runs=2)
    summary = run_campaign(net, "toy", progress=False, executor="in-process")
    assert summary.status_counts == {"failed": 2}
    assert all(m.startswith(f"failed: {message}") for m in summary.failures.values()), \
        summary.failures
    with RunStore(summary.store_path, readonly=True) as db:
        assert db.meta()["simulator_version"] == ""


@pytest.mark.timeout(60)
@pytest.mark.parametrize("version", ["", "__version__ = str(2)\n"])
def test_a_module_that_hangs_at_import_times_out_its_runs(tmp_path, monkeypatch, version):
    """The campaign never imports a user's module itself, where no timeout applies: its
    runs time out, the campaign ends."""
    monkeypatch.setattr(sys, "path", list(sys.path))
    name = f"hangs_at_import_{bool(version)}"
    (tmp_path / f"{name}.py").write_text(
        f"import time\n{version}time.sleep(600)\n\ndef f(inputs):\n    return {{}}\n")
    net = toy_network(tmp_path, f"python:{name}:f", runs=2, timeout=1.0)
    summary = run_campaign(net, "toy", progress=False)
    assert summary.status_counts == {"timeout": 2}
    assert name not in sys.modules


@pytest.mark.parametrize(("line", "version"), [
    ('__version__ = "3.1"\nVERSION = "no"\n', "3.1"),  # __version__ first, as on import
    ("VERSION = 7\n", "7"),
    ('__version__ = ".".join(["4", "2"])\n', "4.2"),  # computed: imported in a child
    ("", ""),
])
def test_a_modules_version_is_read_without_importing_it_here(tmp_path, monkeypatch, line,
                                                             version):
    monkeypatch.setattr(sys, "path", list(sys.path))
    name = f"versioned_{abs(hash(line))}"
    (tmp_path / f"{name}.py").write_text(
        f"{line}\ndef f(inputs):\n    return {{'y': inputs['x'], 'z': inputs['a']}}\n")
    net = toy_network(tmp_path, f"python:{name}:f", runs=2)
    path = run_campaign(net, "toy", progress=False, workers=1).store_path
    with RunStore(path, readonly=True) as db:
        assert db.meta()["simulator_version"] == version
        assert db.versions() == {version: 2}
    assert name not in sys.modules  # the runs ran in a worker process


def test_a_simulator_that_changes_directory_moves_no_store(tmp_path, monkeypatch):
    """In this process (--executor in-process), a simulator's os.chdir: the store stays
    where the campaign opened it, the working directory is set back."""
    from calnet.spec import load_spec

    (tmp_path / "elsewhere").mkdir()
    toy_network(tmp_path, {"kind": "python", "target": "toy_sims:moves",
                           "options": {"to": str(tmp_path / "elsewhere")}}, runs=3)
    monkeypatch.chdir(tmp_path)
    summary = run_campaign(load_spec("network.yaml"), "toy", progress=False,
                           executor="in-process")
    assert summary.status_counts == {"ok": 3}
    assert summary.store_path == tmp_path / "campaigns" / "toy.sqlite"
    assert Path.cwd() == tmp_path
    assert load_runs(load_spec("network.yaml"), "toy").n_ok == 3


def test_runs_made_without_a_version_are_said_to_be_unknown(tmp_path, monkeypatch):
    """A module that states a version after its runs were made without one (or the
    other way round): nothing tells whether the runs differ, and the warning says so
    instead of staying silent; the runs are kept either way."""
    from calnet.errors import CampaignWarning

    monkeypatch.setattr(sys, "path", list(sys.path))
    module = tmp_path / "later_versioned.py"
    module.write_text("def f(inputs):\n    return {'y': inputs['x'], 'z': inputs['a']}\n")
    net = toy_network(tmp_path, "python:later_versioned:f", runs=3)
    run_campaign(net, "toy", progress=False, workers=1)
    module.write_text('__version__ = "2"\n' + module.read_text())
    with pytest.warns(CampaignWarning, match=r"holds 3 runs with later_versioned:f stating "
                      r"no version; the installed later_versioned:f is 2, so whether its "
                      r"results changed is not known: if they did, re-simulate with "
                      r"--fresh"):
        summary = run_campaign(net, "toy", runs=4, progress=False, workers=1)
    assert summary.status_counts == {"ok": 4}
