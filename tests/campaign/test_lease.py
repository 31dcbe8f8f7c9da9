"""One writer per store: a second campaign on a held store is refused, a stale lease is
taken over."""

from __future__ import annotations

import socket
import sqlite3
import subprocess
import sys
import time

import pytest
from campaign_helpers import toy_network, toy_spec

from calnet.campaign import run_campaign
from calnet.campaign.lease import TIMEOUT, process_start
from calnet.campaign.store import RunStore
from calnet.errors import CampaignError

RUNS = 10


def _lease(path) -> tuple | None:
    if not path.exists():
        return None
    db = sqlite3.connect(path, timeout=5)
    try:
        return db.execute("SELECT host, pid FROM lease").fetchone()
    except sqlite3.OperationalError:  # the table is not there yet
        return None
    finally:
        db.close()


def test_two_campaigns_at_once_run_every_run_once(tmp_path, monkeypatch):
    count = tmp_path / "executions.txt"
    release = tmp_path / "release"  # the first campaign's runs wait for it
    monkeypatch.setenv("TOY_COUNT_FILE", str(count))
    monkeypatch.setenv("TOY_RELEASE_FILE", str(release))
    spec = toy_spec(tmp_path, "python:toy_sims:counted", runs=RUNS)
    store = tmp_path / "campaigns" / "toy.sqlite"
    argv = [sys.executable, "-m", "calnet", "campaign", str(spec), "--no-progress"]
    first = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        deadline = time.monotonic() + 60
        while not count.exists():  # the first run has started
            assert first.poll() is None and time.monotonic() < deadline
            time.sleep(0.05)
        second = subprocess.run(argv, capture_output=True, text=True, timeout=60)
        release.touch()
        output, _ = first.communicate(timeout=120)
    finally:
        first.kill()
        first.wait()
    assert len(count.read_text().splitlines()) == RUNS  # every run executed once
    assert first.returncode == 0, output
    assert second.returncode == 1, second.stdout + second.stderr
    message = " ".join(second.stderr.split())
    assert f"is in use by another calnet campaign (pid {first.pid} on host " \
           f"{socket.gethostname()}, since" in message
    assert _lease(store) is None  # given back when the campaign finished


def _hold(path, host: str, pid: int, pid_start: str, heartbeat: float) -> None:
    with sqlite3.connect(path) as db:
        db.execute("INSERT OR REPLACE INTO lease VALUES (1, ?, ?, ?, ?, ?)",
                   (host, pid, pid_start, heartbeat - 5, heartbeat))
    db.close()


def test_a_stale_lease_is_taken_over_and_a_live_one_refused(tmp_path):
    net = toy_network(tmp_path, runs=3)
    path = tmp_path / "store.sqlite"
    RunStore(path).close()
    here, now = socket.gethostname(), time.time()
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()  # a process of this host that has ended
    alive = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        live = (here, alive.pid, process_start(alive.pid), now)
        stale = [(here, gone.pid, "1", now),  # same host, process gone
                 (here, alive.pid, "1", now),  # same host, PID reused by another process
                 ("elsewhere", 12345, "1", now - TIMEOUT - 10)]  # heartbeat too old
        for k, holder in enumerate(stale):  # one more run each time: the store is written
            _hold(path, *holder)
            summary = run_campaign(net, "toy", store=path, runs=3 + k, progress=False)
            assert summary.ran == (3 if k == 0 else 1) and summary.complete
        for holder, who in ((live, f"pid {alive.pid} on host {here}"),
                            (("elsewhere", 12345, "1", now), "pid 12345 on host elsewhere")):
            _hold(path, *holder)
            for fresh in (False, True):
                with pytest.raises(CampaignError, match=f"in use by another calnet campaign "
                                                        f"\\({who}, since"):
                    run_campaign(net, "toy", store=path, runs=9, progress=False, fresh=fresh)
            assert path.exists()  # --fresh did not delete a store in use
    finally:
        alive.kill()
        alive.wait()
    with RunStore(path, readonly=True) as db:
        assert db.planned() == 5
