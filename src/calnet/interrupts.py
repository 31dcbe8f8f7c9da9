"""Ctrl-C that is not lost: a SIGINT latch for the command line and the pipeline.

Python raises KeyboardInterrupt wherever the main thread is when SIGINT arrives, and drops
it when that is inside a garbage-collection callback (XLA's runs often), so a Ctrl-C can
vanish and a command go on to exit 0. Inside :func:`latch` SIGINT still raises
KeyboardInterrupt, and it also latches: the callable :func:`latch` yields raises
KeyboardInterrupt (in the main thread) once SIGINT has arrived. Long work calls it
between steps, and a command calls it when it ends.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager

__all__ = ["latch"]

_hit = threading.Event()


def _handler(signum, frame) -> None:
    _hit.set()
    raise KeyboardInterrupt


def _check() -> None:
    if _hit.is_set() and threading.current_thread() is threading.main_thread():
        raise KeyboardInterrupt


def _nothing() -> None:
    return None


@contextmanager
def latch() -> Iterator[Callable[[], None]]:
    """Install the latch for the block (nested blocks share it). Where SIGINT is ignored
    (a shell's background job) or handled by someone else, or off the main thread,
    nothing is installed and the callable does nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield _check
        return
    current = signal.getsignal(signal.SIGINT)
    if current is _handler:  # inside another latch
        yield _check
        return
    if current is not signal.default_int_handler:
        yield _nothing
        return
    _hit.clear()
    signal.signal(signal.SIGINT, _handler)
    try:
        yield _check
    finally:
        signal.signal(signal.SIGINT, signal.default_int_handler)
        _hit.clear()
