"""Progress for logs and pipes: plain lines, throttled, never carriage returns.

On a terminal the CLI shows Rich bars; anywhere else (``calnet run ... | tee log``, a
batch job) a bar prints nothing until it ends, so the long loops report through
:class:`Lines` instead: one line at every tenth of the work, and one after
``every_s`` seconds without a line, each with the seconds elapsed.

Examples
--------
>>> out = []
>>> lines = Lines("thermal", out.append, clock=iter([0.0, 1.0, 2.0, 3.0]).__next__)
>>> for done in (1, 2, 10):
...     lines.update(done / 10, f"{done}/10 runs")
>>> out
['thermal: 1/10 runs (1 s)', 'thermal: 2/10 runs (2 s)', 'thermal: 10/10 runs (3 s)']
"""

from __future__ import annotations

import math
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

__all__ = ["Lines", "to_stderr"]


def to_stderr(text: str) -> None:
    """Write one line to stderr now (a pipe is block-buffered otherwise)."""
    print(text, file=sys.stderr, flush=True)


class Lines:
    """Throttled progress lines ``"label: text (N s)"`` for one long piece of work.

    Parameters
    ----------
    label : str
        What is in progress (a model, a stage); starts every line.
    write : callable
        Takes one line (no newline): a console's ``print``, a logger, :func:`to_stderr`.
    step : float
        A line each time the fraction done passes another multiple of ``step``.
    every_s : float
        And a line after this many seconds without one.
    clock : callable
        Seconds, for the elapsed times (``time.perf_counter``).
    """

    def __init__(self, label: str, write: Callable[[str], None] = to_stderr, *,
                 step: float = 0.1, every_s: float = 10.0,
                 clock: Callable[[], float] = time.perf_counter):
        self.label, self.write, self.step, self.every_s = label, write, step, every_s
        self.clock = clock
        self.t0 = self.last = clock()
        self.mark = -1  # the last multiple of step that a line reported
        self.lock = threading.Lock()

    def elapsed(self) -> float:
        """Seconds since the work started."""
        return self.clock() - self.t0

    def restart(self) -> None:
        """Count the seconds from now (the work proper starts after a preparation)."""
        with self.lock:
            self.t0 = self.last = self.clock()

    def note(self, text: str) -> None:
        """Write ``text`` now."""
        with self.lock:
            self._write(text, self.clock())

    def update(self, fraction: float, text: str) -> None:
        """Report ``fraction`` (0 to 1) of the work done; ``text`` says what it is. Writes
        a line when another ``step`` is done, at the end, or after ``every_s`` quiet
        seconds."""
        with self.lock:
            now = self.clock()
            mark = math.floor(fraction / self.step + 1e-9)
            if mark > self.mark or now - self.last >= self.every_s:
                self.mark = max(mark, self.mark)
                self._write(text, now)

    @contextmanager
    def heartbeat(self, text: Callable[[], str]) -> Iterator[None]:
        """While the block runs, a line ``text()`` whenever ``every_s`` seconds pass
        without one: for work that reports no steps for a while (XLA's warm-up loop)."""
        stop = threading.Event()

        def beat() -> None:
            while not stop.wait(min(1.0, self.every_s)):
                with self.lock:
                    now = self.clock()
                    if now - self.last >= self.every_s:
                        self._write(text(), now)

        thread = threading.Thread(target=beat, name=f"progress {self.label}", daemon=True)
        thread.start()
        try:
            yield
        finally:
            stop.set()
            thread.join()

    def _write(self, text: str, now: float) -> None:
        self.last = now
        self.write(f"{self.label}: {text} ({now - self.t0:.0f} s)")
