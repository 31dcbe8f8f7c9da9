"""kill -9 of a campaign: every process it started for its runs dies with it."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from campaign_helpers import toy_spec

from calnet.campaign.lease import process_start

pytestmark = pytest.mark.skipif(not Path("/proc/self/stat").is_file(),
                                reason="reads the process tree from /proc (Linux)")


def _descendants(pid: int) -> dict[int, str]:
    """PID -> start time of every live process below ``pid``."""
    children: dict[int, list[int]] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rpartition(")")[2].split()
        except OSError:
            continue
        children.setdefault(int(fields[1]), []).append(int(stat.parent.name))
    found, todo = {}, [pid]
    while todo:
        for child in children.get(todo.pop(), []):
            start = process_start(child)
            if start:
                found[child] = start
                todo.append(child)
    return found


def _command_line(pid: int) -> list[str]:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().decode().split("\0")[:-1]
    except OSError:
        return []


def _alive(processes: dict[int, str]) -> list[str]:
    return [" ".join(_command_line(p)) or str(p) for p, start in processes.items()
            if process_start(p) == start]


@pytest.mark.parametrize(("simulator", "options"), [
    ("python:toy_sims:sleeper", ["--runs", "2"]),  # timeout: a child process per run
    ("python:toy_sims:sleeper", ["--runs", "4", "--workers", "2"]),  # ... in pool workers
    ({"kind": "command", "argv": ["sh", "-c", "sleep 61; true"], "output_mode": "stdout"},
     ["--runs", "2"]),
])
def test_kill_9_leaves_no_process_running(tmp_path, simulator, options):
    timeout = 120 if isinstance(simulator, str) else None
    spec = toy_spec(tmp_path, simulator, timeout=timeout)
    proc = subprocess.Popen([sys.executable, "-m", "calnet", "campaign", str(spec),
                             "--no-progress", *options], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    started: dict[int, str] = {}
    try:
        deadline = time.monotonic() + 60
        while not any(_command_line(p) == ["sleep", "61"] for p in started):
            assert proc.poll() is None and time.monotonic() < deadline, "no run started"
            time.sleep(0.1)
            started = _descendants(proc.pid)
        time.sleep(0.5)
        started = _descendants(proc.pid)  # the campaign's whole tree, reaper included
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        deadline = time.monotonic() + 15
        while _alive(started) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not _alive(started)
    finally:
        proc.kill()
        proc.wait()
        for pid, start in started.items():  # never leave a process behind, even failing
            if process_start(pid) == start:
                os.kill(pid, signal.SIGKILL)
