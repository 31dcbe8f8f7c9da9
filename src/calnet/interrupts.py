"""Ctrl-C that is not lost: a SIGINT latch for the command line and the pipeline.

Python raises KeyboardInterrupt wherever the main thread is when SIGINT arrives, and drops
it when that is inside a garbage-collection callback (XLA's runs often), so a Ctrl-C can
vanish and a command go on to exit 0. Inside :func:`latch` SIGINT still raises
KeyboardInterrupt, and it also latches: the callable :func:`latch` yields raises
KeyboardInterrupt (in the main thread) once SIGINT has arrived. Long work calls it
between steps, and a command calls it when it ends.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager

__all__ = ["latch", "program_running", "program_in_flight", "ending_allowed", "end_now",
           "may_end_now"]

_hit = threading.Event()
_running = [0]  # compiled programs being waited for, in any thread
_running_lock = threading.Lock()


@contextmanager
def program_running() -> Iterator[None]:
    """Mark the block as waiting for a long compiled (XLA) program, which no signal can
    stop: a handler that must end the process soon (SIGTERM from a batch system) can ask
    :func:`program_in_flight` and end it at once rather than unwind and wait."""
    with _running_lock:
        _running[0] += 1
    try:
        yield
    finally:
        with _running_lock:
            _running[0] -= 1


def program_in_flight() -> bool:
    """Whether some thread waits for a program inside :func:`program_running`."""
    return _running[0] > 0


_NOTES: list[str] = []  # what a command says of its kept work when it ends at once


@contextmanager
def ending_allowed(note: str = "") -> Iterator[None]:
    """Within the block (a command of the command line), :func:`end_now` may end the
    process; ``note`` says what is kept (e.g. the finished campaign runs). Library
    code outside such a block (a notebook's kernel) is never ended."""
    _NOTES.append(note)
    try:
        yield
    finally:
        _NOTES.pop()


def may_end_now() -> bool:
    """Whether :func:`end_now` would end the process."""
    return bool(_NOTES)


def end_now(code: int, why: str) -> None:
    """Inside :func:`ending_allowed`, end the process at once with ``code`` after one
    line on stderr (``why``, then the command's note); else return. For a compiled
    program that nothing can stop: what is finished is on disk already, and ending
    without Python's clean-up avoids the crash of a normal exit with the program still
    running."""
    if not _NOTES:
        return
    sys.stdout.flush()
    print(f"interrupted ({why}): ended at once" + (f"; {_NOTES[-1]}" if _NOTES[-1] else ""),
          file=sys.stderr, flush=True)
    os._exit(code)


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
