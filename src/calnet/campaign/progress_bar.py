"""Progress of a campaign: a Rich bar on a terminal, plain lines elsewhere."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

from calnet.campaign.store import RunStore
from calnet.progress import Lines, to_stderr

EVERY_S = 10.0  # plain lines: one at least this often, also while no run finishes


class Tracker:
    """What a campaign tells its progress display: :meth:`started` when a run is handed
    to a worker, :meth:`finished` when its result is stored. This one shows nothing."""

    def started(self, index: int) -> None:
        """Run ``index`` is in flight from now."""

    def finished(self, index: int, status: str) -> None:
        """Run ``index`` ended with ``status``."""

    def note(self, text: str) -> None:
        """Something the user should know now (a worker process died)."""


@contextmanager
def campaign_progress(progress: bool | Callable[[str], None], name: str, total: int,
                      done: int, db: RunStore) -> Iterator[Tracker]:
    """Yields a :class:`Tracker`: a Rich bar (done / not ok / rate / ETA) on a terminal,
    plain lines elsewhere or through ``progress`` when it is a callable."""
    failed = {k: n for k, n in db.status_counts().items() if k not in ("ok", "unfinished")}
    if not progress:
        yield Tracker()
        return
    from rich.console import Console

    if callable(progress) or not Console().is_terminal:
        lines = Lines(name, progress if callable(progress) else to_stderr, every_s=EVERY_S)
        tracker = _LineTracker(lines, total, done, failed)
        with lines.heartbeat(tracker.text):
            yield tracker
        return
    with _bar(name, total, done, failed) as tracker:
        yield tracker


class _LineTracker(Tracker):
    """A line at every 10 % of the runs, and one whenever :data:`EVERY_S` seconds pass
    without one, naming the runs in flight and how long the oldest has been in flight
    (so that a log tells a hung simulator from a slow one)."""

    def __init__(self, lines: Lines, total: int, done: int, failed: dict[str, int]):
        self.lines, self.total, self.done, self.failed = lines, total, done, dict(failed)
        self.running: dict[int, float] = {}  # run index -> when it was handed out
        self.lock = threading.Lock()
        lines.note(f"{total - done} runs to go of {total}")

    def started(self, index: int) -> None:
        with self.lock:
            self.running[index] = time.monotonic()

    def finished(self, index: int, status: str) -> None:
        with self.lock:
            self.running.pop(index, None)
            self.done += 1
            if status != "ok":
                self.failed[status] = self.failed.get(status, 0) + 1
            fraction, text = self.done / self.total, self._counts()
        self.lines.update(fraction, text)

    def note(self, text: str) -> None:
        self.lines.note(text)

    def text(self) -> str:
        """The counts and the runs in flight, for a line written while none finishes."""
        with self.lock:
            text = self._counts()
            if self.running:
                oldest = time.monotonic() - min(self.running.values())
                text += f", {len(self.running)} in flight (the oldest for {oldest:.0f} s)"
            return text

    def _counts(self) -> str:
        return f"{self.done}/{self.total} runs, {not_ok(self.failed)}"


def not_ok(counts: dict[str, int]) -> str:
    """``"3 not ok (failed 1, timeout 2)"``, or ``"0 not ok"``, from runs per status
    other than ``ok``."""
    total = sum(counts.values())
    by = ", ".join(f"{k} {n}" for k, n in sorted(counts.items()) if n)
    return f"{total} not ok" + (f" ({by})" if by else "")


@contextmanager
def _bar(name: str, total: int, done: int, failed: dict[str, int]) -> Iterator[Tracker]:
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    columns = (TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
               TextColumn("[red]{task.fields[failed]}"),
               TextColumn("{task.fields[rate]}"), TimeElapsedColumn(), TextColumn("ETA"),
               TimeRemainingColumn())
    with Progress(*columns, transient=False) as bar:
        yield _BarTracker(bar, bar.add_task(name, total=total, completed=done,
                                            failed=not_ok(failed), rate=""), failed)


class _BarTracker(Tracker):
    """Advances a Rich bar (the bar's elapsed time shows that the campaign lives)."""

    def __init__(self, bar: Any, task: Any, failed: dict[str, int]):
        self.bar, self.task, self.failed, self.run = bar, task, dict(failed), 0
        self.start = time.perf_counter()

    def finished(self, index: int, status: str) -> None:
        self.run += 1
        if status != "ok":
            self.failed[status] = self.failed.get(status, 0) + 1
        rate = self.run / max(time.perf_counter() - self.start, 1e-9)
        self.bar.update(self.task, advance=1, failed=not_ok(self.failed),
                        rate=f"{rate * 60:.1f} runs/min" if rate < 1 else f"{rate:.1f} runs/s")

    def note(self, text: str) -> None:
        self.bar.console.print(text, soft_wrap=True)
