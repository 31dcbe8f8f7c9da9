"""SIGTERM ends a command as Ctrl-C does.

A batch system (SLURM, PBS, ``timeout``) or ``kill`` stops a job with SIGTERM, whose
default ends Python at once: no ``finally`` runs, the local worker processes are left to
the kernel and Python's resource tracker reports their semaphores as leaked.
:func:`sigterm_exit` (and the decorator :func:`sigterm_exits`) turns SIGTERM into
:class:`Terminated`, a ``KeyboardInterrupt``, so that the work unwinds as after Ctrl-C
(finished runs committed, the store closed, the workers stopped), then prints one line
and exits with :data:`TERMINATED_EXIT`. Within :func:`sigterm_exit`, SIGTERM while a
compiled program runs (the sampler's chains, :func:`calnet.interrupts.program_running`)
ends the process at once with that code and one line, instead of waiting for it.
"""

from __future__ import annotations

import functools
import signal
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import typer

from calnet.interrupts import end_now, ending_allowed, program_in_flight

TERMINATED_EXIT = 143
"""Exit code after SIGTERM: 128 + 15, as a shell reports a process SIGTERM ended
(Ctrl-C exits with 130)."""


class Terminated(KeyboardInterrupt):
    """SIGTERM arrived (raised in the main thread, where Ctrl-C raises)."""


def resume_note(command: str, fresh: bool = False) -> str:
    """What an interrupted ``calnet run`` or ``calnet campaign`` says of its finished
    runs: the same command resumes them, without ``--fresh`` (which would delete them)."""
    again = "the same command without --fresh" if fresh else "the same command"
    later = " (later stages start again)" if command == "run" else ""
    return f"finished simulation runs are kept; {again} resumes them{later}"


@contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """Within the block, SIGTERM raises :class:`Terminated` in the main thread; a second
    SIGTERM while it unwinds is ignored, so that the clean-up ends. Outside the main
    thread (where no handler can be set) the block runs as it is."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, _raise)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _raise(signum: int, frame: Any) -> None:
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    if program_in_flight():
        # a compiled program (the sampler's chains) runs on and cannot be stopped:
        # unwinding would wait for it, longer than a batch system's grace period. What is
        # finished is on disk already (campaign runs, the run folder's incomplete mark),
        # so a command ends here (end_now; library code unwinds)
        end_now(TERMINATED_EXIT, "SIGTERM while a compiled program ran, which cannot be "
                "stopped")
    raise Terminated(f"signal {signum}")


@contextmanager
def sigterm_exit(command: str = "run", fresh: bool = False) -> Iterator[None]:
    """Within the block, SIGTERM stops the work as Ctrl-C does; then one line on stderr
    (:func:`resume_note` of ``command`` and ``fresh``) and exit code
    :data:`TERMINATED_EXIT` (``typer.Exit``)."""
    try:
        with ending_allowed(resume_note(command, fresh)), sigterm_as_interrupt():
            yield
    except Terminated:
        from rich.console import Console

        Console(stderr=True).print("[bold red]interrupted[/] (SIGTERM): "
                                   + resume_note(command, fresh), soft_wrap=True)
        raise typer.Exit(TERMINATED_EXIT) from None


def sigterm_exits(func: Callable[..., Any]) -> Callable[..., Any]:
    """A command run within :func:`sigterm_exit` (named by the function, with its
    ``fresh`` argument)."""

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        with sigterm_exit(func.__name__, bool(kwargs.get("fresh"))):
            return func(*args, **kwargs)

    return wrapper
