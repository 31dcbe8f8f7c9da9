"""One writer per store: a lease row that a campaign holds while it runs.

A campaign that writes a store first takes its lease, a single row of the ``lease``
table (host, PID and start time of the holder, since when, last heartbeat), in one
``BEGIN IMMEDIATE`` transaction, so two campaigns starting together cannot both take it.
While it runs, a background thread renews the heartbeat every :data:`HEARTBEAT` seconds;
closing the store gives the lease back. A second campaign on a held store is refused
with the holder's name. A lease is stale, and is taken over, when its holder is gone:
on the same host, its process no longer exists (or the PID now names another process);
on another host, its heartbeat is older than :data:`TIMEOUT` seconds.
"""

from __future__ import annotations

import os
import socket
import sqlite3
import threading
import time
from pathlib import Path

from calnet.errors import CampaignError

HEARTBEAT = 15.0  # seconds between two renewals of a held lease
TIMEOUT = 120.0  # seconds without a heartbeat after which another host's lease is stale

SCHEMA = """
CREATE TABLE IF NOT EXISTS lease (
    id INTEGER PRIMARY KEY CHECK (id = 1),
    host TEXT NOT NULL,
    pid INTEGER NOT NULL,
    pid_start TEXT NOT NULL,
    since REAL NOT NULL,
    heartbeat REAL NOT NULL
);
"""


class Lease:
    """The lease of the store at ``path`` for this process, taken on creation.

    Parameters
    ----------
    db : sqlite3.Connection
        The store's open (writable) connection.
    path : Path
        The store, for the heartbeat's own connection and for messages.

    Raises
    ------
    CampaignError
        When another live campaign holds the store.
    """

    def __init__(self, db: sqlite3.Connection, path: Path):
        self.path = path
        self.me = (socket.gethostname(), os.getpid(), process_start(os.getpid()))
        now = time.time()
        db.commit()
        db.execute("BEGIN IMMEDIATE")
        try:
            row = db.execute("SELECT host, pid, pid_start, since, heartbeat FROM lease "
                             "WHERE id = 1").fetchone()
            if row is not None and tuple(row[:3]) != self.me and not is_stale(row, now):
                raise CampaignError(describe_holder(path, row, now))
            db.execute("INSERT OR REPLACE INTO lease VALUES (1, ?, ?, ?, ?, ?)",
                       (*self.me, now, now))
        except BaseException:
            db.rollback()
            raise
        db.commit()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._beat, name="calnet-lease", daemon=True)
        self._thread.start()

    def _beat(self) -> None:
        while not self._stop.wait(HEARTBEAT):
            try:
                db = sqlite3.connect(self.path, timeout=30)
                with db:
                    db.execute("UPDATE lease SET heartbeat = ? WHERE id = 1 AND host = ? "
                               "AND pid = ? AND pid_start = ?", (time.time(), *self.me))
                db.close()
            except sqlite3.Error:  # the campaign itself reports a store it cannot write
                pass

    def release(self, db: sqlite3.Connection) -> None:
        """Stop the heartbeat and delete the lease row (if it is still this process's)."""
        self._stop.set()
        self._thread.join()
        with db:
            db.execute("DELETE FROM lease WHERE id = 1 AND host = ? AND pid = ? "
                       "AND pid_start = ?", self.me)


def holder(path: Path) -> str | None:
    """Who holds the store at ``path`` (a message), or None when nobody live does."""
    if not path.is_file():
        return None
    try:
        db = sqlite3.connect(f"file:{path.resolve()}?mode=ro", uri=True, timeout=30)
        try:
            row = db.execute("SELECT host, pid, pid_start, since, heartbeat FROM lease "
                             "WHERE id = 1").fetchone()
        finally:
            db.close()
    except sqlite3.Error:  # no lease table, or not a store: the campaign says what is wrong
        return None
    now = time.time()
    return describe_holder(path, row, now) if row and not is_stale(row, now) else None


def is_stale(row: tuple, now: float) -> bool:
    """Whether the holder of lease ``row`` (host, pid, pid_start, since, heartbeat) is gone."""
    host, pid, pid_start, _, heartbeat = row
    if host == socket.gethostname():
        return process_start(int(pid)) != pid_start  # None: no such process
    return now - float(heartbeat) > TIMEOUT


def describe_holder(path: Path, row: tuple, now: float) -> str:
    host, pid, _, since, heartbeat = row
    started = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(float(since)))
    return (f"the store '{path}' is in use by another calnet campaign (pid {pid} on host "
            f"{host}, since {started}, last heartbeat {now - float(heartbeat):.0f} s ago); "
            "wait for it to finish, or stop it, then run the command again")


def process_start(pid: int) -> str | None:
    """An identity of process ``pid`` that a reused PID does not share (its start time in
    clock ticks since boot, on Linux; "" where unknown); None when no such process runs."""
    if Path("/proc/self/stat").is_file():
        try:
            fields = Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()
        except OSError:
            return None
        return None if fields[0] in ("Z", "X") else fields[19]  # state, starttime
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return None
    except PermissionError:
        pass
    return ""
