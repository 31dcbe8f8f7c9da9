"""What simulators print: one pair of log files per run, never the campaign's console.

A run's standard output and standard error go to ``stdout.log`` and ``stderr.log`` in its
folder of the campaign's work folder (``<store>.work/run-00012/``) whenever the run does
not share the campaign's process: a command, a Python call in a worker process or in a
timeout's child process. Empty logs are removed (and the run's folder, when nothing else
is left in it), so a quiet simulator leaves no files behind. A simulator called in the
campaign's own process (``--executor in-process`` without a timeout) prints where the
campaign prints.
"""

from __future__ import annotations

import os
import re
import sys
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from pathlib import Path

LOGS = ("stdout.log", "stderr.log")
TAIL_LINES = 3  # lines of standard error a failed run's message quotes


def open_logs(folder: Path) -> tuple[int, int] | None:
    """File descriptors of ``folder``'s two logs, truncated; None when they cannot be
    made (a folder of another machine's disk, a full disk): the output is then lost."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        return tuple(os.open(folder / name, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
                     for name in LOGS)  # type: ignore[return-value]
    except OSError:
        return None


@contextmanager
def captured(folder: Path) -> Iterator[None]:
    """Send this process's standard output and error (file descriptors 1 and 2, so the
    output of compiled code too) to ``folder``'s logs while the block runs."""
    fds = open_logs(folder)
    if fds is None:
        yield
        return
    for stream in (sys.stdout, sys.stderr):
        with suppress(Exception):
            stream.flush()
    saved = [os.dup(1), os.dup(2)]
    os.dup2(fds[0], 1)
    os.dup2(fds[1], 2)
    try:
        yield
    finally:
        for stream in (sys.stdout, sys.stderr):
            with suppress(Exception):
                stream.flush()
        for fd, old in zip((1, 2), saved, strict=True):
            os.dup2(old, fd)
            os.close(old)
        for fd in fds:
            os.close(fd)
        tidy(folder)


def tidy(folder: Path) -> None:
    """Remove ``folder``'s empty logs, and ``folder`` itself when that empties it."""
    for name in LOGS:
        path = folder / name
        with suppress(OSError):
            if path.stat().st_size == 0:
                path.unlink()
    with suppress(OSError):
        folder.rmdir()  # only when empty


def tail(folder: Path, name: str = "stderr.log", lines: int = TAIL_LINES) -> list[str]:
    """The last ``lines`` non-empty lines of one of ``folder``'s logs ([] without it)."""
    try:
        with open(folder / name, "rb") as fh:
            fh.seek(0, os.SEEK_END)
            fh.seek(max(0, fh.tell() - 4096))
            text = fh.read().decode(errors="replace")
    except OSError:
        return []
    return [line for line in text.splitlines() if line.strip()][-lines:]


def where(folder: Path) -> str:
    """`` (logs in <folder>: stderr.log, stdout.log)`` naming the logs a run left; ""
    when it left none."""
    names = [name for name in reversed(LOGS) if (folder / name).is_file()]
    return f" (logs in {folder}: {', '.join(names)})" if names else ""


_WHERE = re.compile(r" \(logs in .*?: (?:stdout|stderr)\.log(?:, (?:stdout|stderr)\.log)?\)$")


def without_where(message: str) -> str:
    """``message`` less the :func:`where` at its end (to count runs that failed alike)."""
    return _WHERE.sub("", message)


def logs_note(work: Path, indices: list[int]) -> str | None:
    """The line saying where the output of the runs ``indices`` is, when any left a log
    in the work folder ``work``; None otherwise."""
    wrote = [i for i in indices if any((work / f"run-{i:05d}" / n).is_file() for n in LOGS)]
    if not wrote:
        return None
    runs = "1 run" if len(wrote) == 1 else f"{len(wrote)} runs"
    return (f"what the simulator printed is in {work}/run-NNNNN/stdout.log and stderr.log "
            f"({runs} of this call, the first run {wrote[0]})")
