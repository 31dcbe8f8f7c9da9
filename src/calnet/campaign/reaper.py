"""Processes started for runs die with the process that started them.

A run's child (the Python process of a run with a timeout, a command) runs in its own
process group, so that a timeout kills it with everything it started. Killing the
campaign with ``kill -9`` would leave those groups running, their timeouts gone with
the campaign. So every process that starts such children also starts, once, a small
reaper process in its own session, tells it each group it starts and each it has
finished with through a pipe, and holds the pipe's only write end. When that process
ends, however it ends, the pipe reaches end-of-file and the reaper kills every group
still registered, then exits.
"""

from __future__ import annotations

import atexit
import os
import subprocess
import sys
import threading

_CODE = """\
import os, signal, sys
signal.signal(signal.SIGINT, signal.SIG_IGN)
groups = set()
for line in sys.stdin:
    op, pgid = line.split()
    (groups.add if op == "+" else groups.discard)(int(pgid))
for pgid in groups:
    try:
        os.killpg(pgid, signal.SIGKILL)
    except OSError:
        pass
"""

_lock = threading.Lock()
_reaper: dict[int, subprocess.Popen] = {}  # this process's reaper, by PID (not a fork's)
_closing: set[int] = set()  # the processes that close their reaper at exit


def watch(pgid: int) -> None:
    """Have process group ``pgid`` killed if this process ends before :func:`unwatch`."""
    _send(f"+ {pgid}\n")


def unwatch(pgid: int) -> None:
    """Forget process group ``pgid`` (its leader has been waited for)."""
    _send(f"- {pgid}\n")


def _send(line: str) -> None:
    with _lock:
        for _ in range(2):  # a reaper that has died is started again, once
            proc = _reaper.get(os.getpid())
            if proc is None or proc.poll() is not None:
                proc = _reaper[os.getpid()] = _start()
            try:
                proc.stdin.write(line.encode())
                proc.stdin.flush()
                return
            except OSError:
                _reaper.pop(os.getpid(), None)


def _start() -> subprocess.Popen:
    if os.getpid() not in _closing:
        _closing.add(os.getpid())
        atexit.register(_close)
    return subprocess.Popen([sys.executable, "-I", "-S", "-c", _CODE], stdin=subprocess.PIPE,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)


def _close() -> None:
    """At a normal exit: end this process's reaper (what it watches has been waited for)."""
    proc = _reaper.pop(os.getpid(), None)
    if proc is not None:
        proc.stdin.close()
        proc.wait()
