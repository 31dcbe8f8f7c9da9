"""Progress of a campaign: a Rich bar on a terminal, plain lines elsewhere."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

from calnet.campaign.store import RunStore
from calnet.progress import Lines, to_stderr


@contextmanager
def campaign_progress(progress: bool | Callable[[str], None], name: str, total: int,
                      done: int, db: RunStore) -> Iterator[Any]:
    """Yields ``advance(status)``: a Rich bar (done / failed / rate / ETA) on a terminal,
    plain lines elsewhere or through ``progress`` when it is a callable."""
    failed = sum(n for k, n in db.status_counts().items() if k not in ("ok", "unfinished"))
    if not progress:
        yield lambda status: None
        return
    from rich.console import Console

    if callable(progress) or not Console().is_terminal:
        yield _lines(Lines(name, progress if callable(progress) else to_stderr), total, done,
                     failed)
        return
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    columns = (TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
               TextColumn("[red]{task.fields[failed]} failed"),
               TextColumn("{task.fields[rate]}"), TimeElapsedColumn(), TextColumn("ETA"),
               TimeRemainingColumn())
    with Progress(*columns, transient=False) as bar:
        task = bar.add_task(name, total=total, completed=done, failed=failed, rate="")
        counts = {"failed": failed, "run": 0}
        start = time.perf_counter()

        def advance(status: str) -> None:
            counts["run"] += 1
            counts["failed"] += status != "ok"
            rate = counts["run"] / max(time.perf_counter() - start, 1e-9)
            bar.update(task, advance=1, failed=counts["failed"],
                       rate=f"{rate * 60:.1f} runs/min" if rate < 1 else f"{rate:.1f} runs/s")

        yield advance


def _lines(lines: Lines, total: int, done: int, failed: int) -> Callable[[str], None]:
    """``advance(status)`` writing a line at every 10 % of the runs (and every 10 s)."""
    counts = {"done": done, "failed": failed}
    lines.note(f"{total - done} runs to go of {total}")

    def advance(status: str) -> None:
        counts["done"] += 1
        counts["failed"] += status != "ok"
        lines.update(counts["done"] / total, f"{counts['done']}/{total} runs, "
                                             f"{counts['failed']} failed")

    return advance
