"""kill -9 of a running campaign, then resume: nothing finished is lost or repeated."""

from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import sys
import time

import pytest
from campaign_helpers import store_rows, toy_spec

from calnet.campaign import run_campaign
from calnet.spec import load_spec

RUNS = 40


def _finished(path) -> dict[int, float]:
    if not path.exists():
        return {}
    db = sqlite3.connect(path, timeout=5)
    try:
        return dict(db.execute("SELECT idx, finished_at FROM runs WHERE status IS NOT NULL"))
    except sqlite3.OperationalError:  # the schema is not there yet
        return {}
    finally:
        db.close()


_WITH_SIGINT = ("import runpy, signal, sys; "
                "signal.signal(signal.SIGINT, signal.default_int_handler); "
                "sys.argv = ['calnet', *sys.argv[1:]]; "
                "runpy.run_module('calnet', run_name='__main__', alter_sys=True)")


def _campaign(spec, store) -> list[str]:
    return [sys.executable, "-m", "calnet", "campaign", str(spec), "--model", "toy",
            "--store", str(store), "--no-progress"]


def _signalled(argv: list[str], ready, sig: int, *, settle: float = 0.0,
               timeout: float = 60) -> tuple[int, str, float]:
    """Run ``argv``, wait until ``ready()`` (at most 90 s), then ``settle`` seconds, send
    ``sig``: its exit code, its output and the seconds it took to end after the signal."""
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, env=os.environ.copy())
    try:
        deadline = time.monotonic() + 90
        while not ready():
            assert proc.poll() is None and time.monotonic() < deadline
            time.sleep(0.05)
        time.sleep(settle)
        proc.send_signal(sig)
        start = time.monotonic()
        output, _ = proc.communicate(timeout=timeout)
        waited = time.monotonic() - start
    finally:
        proc.kill()
        proc.wait()
    return proc.returncode, output, waited


@pytest.mark.integration
def test_kill_9_then_resume_equals_an_uninterrupted_run(tmp_path):
    spec = toy_spec(tmp_path, "python:toy_sims:slow", runs=RUNS, seed=0)
    store = tmp_path / "killed.sqlite"
    proc = subprocess.Popen(_campaign(spec, store), stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, env=os.environ.copy())
    try:
        deadline = time.monotonic() + 90
        while len(_finished(store)) < 8:
            assert proc.poll() is None, proc.stdout.read().decode()
            assert time.monotonic() < deadline, "campaign made no progress"
            time.sleep(0.05)
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.kill()
        proc.wait()
        proc.stdout.close()
    assert proc.returncode == -signal.SIGKILL
    before = _finished(store)
    assert 8 <= len(before) < RUNS

    resumed = subprocess.run(_campaign(spec, store), capture_output=True, text=True,
                             timeout=120, env=os.environ.copy())
    assert resumed.returncode == 0, resumed.stdout + resumed.stderr
    assert f"{len(before)} already finished" in resumed.stdout
    after = _finished(store)
    assert len(after) == RUNS
    assert all(after[i] == t for i, t in before.items())  # finished runs were not re-run

    reference = run_campaign(load_spec(spec), "toy", progress=False,
                             store=tmp_path / "uninterrupted.sqlite")
    assert reference.ran == RUNS
    assert store_rows(store) == store_rows(reference.store_path)


@pytest.mark.integration
def test_ctrl_c_keeps_finished_runs(tmp_path):
    spec = toy_spec(tmp_path, "python:toy_sims:slower", runs=RUNS, seed=0)
    store = tmp_path / "interrupted.sqlite"
    # a shell's background jobs inherit SIGINT ignored, and Python then installs no
    # KeyboardInterrupt handler: install it, as for a campaign run in a terminal
    argv = [sys.executable, "-c", _WITH_SIGINT, *_campaign(spec, store)[3:]]
    code, output, _ = _signalled(argv, lambda: len(_finished(store)) >= 3, signal.SIGINT)
    assert code == 130, output
    assert "finished simulation runs are kept" in output
    kept = _finished(store)
    assert 3 <= len(kept) < RUNS
    summary = run_campaign(load_spec(spec), "toy", store=store, progress=False)
    assert summary.skipped == len(kept) and summary.complete


@pytest.mark.integration
def test_sigint_to_a_parallel_campaign_does_not_wait_for_the_runs_in_flight(tmp_path):
    """SIGINT to the campaign process alone (``kill -INT``, a batch system), with local
    worker processes busy in 60 s runs: it stops at once, keeping what finished, instead
    of letting the interpreter wait for the runs in flight (they are run again later)."""
    # seed 2: the first three runs are quick (x >= 0.5), the next ones busy
    spec = toy_spec(tmp_path, "python:toy_sims:busy", runs=12, seed=2)
    store = tmp_path / "busy.sqlite"
    argv = [sys.executable, "-c", _WITH_SIGINT, *_campaign(spec, store)[3:], "--workers", "2"]
    # the quick runs finish, then both workers compute
    code, output, waited = _signalled(argv, lambda: len(_finished(store)) >= 1,
                                      signal.SIGINT, settle=3, timeout=120)
    assert code == 130, output
    assert waited < 30, f"waited {waited:.0f} s for the runs in flight"  # they take 60 s
    kept = _finished(store)
    assert 1 <= len(kept) < 12


def _started(path) -> int:
    if not path.exists():
        return 0
    db = sqlite3.connect(path, timeout=5)
    try:
        return db.execute("SELECT COUNT(*) FROM runs WHERE started_at IS NOT NULL").fetchone()[0]
    except sqlite3.OperationalError:  # the schema is not there yet
        return 0
    finally:
        db.close()


@pytest.mark.integration
def test_sigterm_to_a_campaign_with_a_hung_simulator_stops_as_ctrl_c_does(tmp_path):
    """SIGTERM (a batch system, ``timeout``, ``kill``) with a run hanging in a worker
    process: one line, exit code 143, the finished runs kept, and no noise from Python's
    resource tracker about leaked semaphores."""
    spec = toy_spec(tmp_path, "python:toy_sims:hangs", runs=12, seed=0, x_upper=0.3)
    store = tmp_path / "hung.sqlite"
    # the runs x < 0.2 hang for ever
    code, output, _ = _signalled(_campaign(spec, store), lambda: _started(store) >= 1,
                                 signal.SIGTERM, settle=2)
    assert code == 143, output
    assert ("interrupted (SIGTERM): finished simulation runs are kept; the same command "
            "resumes them") in output and "later stages" not in output  # none in a campaign
    assert "resource_tracker" not in output and "Traceback" not in output, output
    kept = _finished(store)
    assert len(kept) < 12
    with sqlite3.connect(f"file:{store}?mode=ro", uri=True) as db:  # closed cleanly
        assert db.execute("SELECT COUNT(*) FROM lease").fetchone()[0] == 0
        # the hung run was started, the one queued behind it was not: a resume says
        # "1 re-run after an interruption"
        assert db.execute("SELECT COUNT(*) FROM runs WHERE status IS NULL AND started_at "
                          "IS NOT NULL").fetchone()[0] == 1
    db.close()


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False


@pytest.mark.integration
@pytest.mark.parametrize(("sig", "code"), [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_an_interrupt_ends_a_campaign_whose_simulator_ignores_signals(tmp_path, sig, code):
    """A Python simulator that ignores SIGTERM and SIGINT hangs in the worker process
    (no timeout): Ctrl-C or SIGTERM still ends the campaign within seconds, with 130 or
    143 and one line, the worker killed (SIGKILL after a short grace) and the store
    closed cleanly."""
    pid_file = tmp_path / "worker.pid"
    spec = toy_spec(tmp_path, {"kind": "python", "target": "toy_sims:deaf_hang",
                               "options": {"pid_file": str(pid_file)}}, runs=4)
    store = tmp_path / "deaf.sqlite"
    argv = [sys.executable, "-c", _WITH_SIGINT, *_campaign(spec, store)[3:]]
    got, output, waited = _signalled(argv, pid_file.exists, sig, settle=0.5, timeout=30)
    assert got == code, output
    assert waited < 10, f"took {waited:.0f} s to end"
    assert "interrupted" in output and "Traceback" not in output, output
    assert "resource_tracker" not in output, output
    assert not _alive(int(pid_file.read_text()))
    with sqlite3.connect(f"file:{store}?mode=ro", uri=True) as db:
        assert db.execute("SELECT COUNT(*) FROM lease").fetchone()[0] == 0
    db.close()
