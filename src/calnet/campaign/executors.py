"""Where runs execute: in this process, in local worker processes, or on Dask.

Every executor has one method, :meth:`Executor.run`, which runs ``fn(*task)`` for a stream
of tasks and yields ``(task, result)`` as each finishes (in completion order), keeping at
most a small window of tasks in flight so that an interrupted campaign has few runs to
redo. ``result`` is the function's return value, or the exception a dead worker left
behind (Dask's ``KilledWorker``, or :class:`WorkerDied` from local processes, for a run
that killed its worker). The results do not depend on the executor: run ``i``'s inputs
are fixed by the design and each run is independent.

Dask is imported only when a Dask executor is made. Worker processes import simulator
modules by name: a Python callable's module must be importable there (``PYTHONPATH``,
or the spec's folder, which the callable adapter adds itself).
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import re
import signal
import time
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from multiprocessing.connection import wait as wait_ended
from typing import Any, Protocol

from threadpoolctl import threadpool_limits

from calnet.errors import CampaignError, UsageError
from calnet.parallel import usable_cores

Task = tuple[Any, ...]

CONNECT_TIMEOUT = "20s"  # how long to try reaching an existing Dask scheduler
EXECUTORS = ("auto", "in-process", "processes", "dask")  # the names make_executor knows
WORKER_GRACE = 5.0
"""Seconds a broken process pool's workers have to end on the pool's SIGTERM before they
are killed (:meth:`ProcessExecutor._restart`)."""
WATCH_INTERVAL = 1.0
"""Seconds between looks at a process pool's workers while no run finishes
(:meth:`ProcessExecutor._nudge`)."""
START_POLL = 0.1
"""Seconds between looks for the runs a process pool's workers have started, while one
handed to the pool has not started yet (:meth:`ProcessExecutor._note_starts`)."""
THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
"""The environment variables that set a worker process's BLAS and OpenMP threads: where
none is set, :func:`_init_worker` sets each to the worker's share of the cores."""
STOP_GRACE = 1.0
"""Seconds the workers of an interrupted process pool have to end on SIGTERM before they
are killed (:meth:`ProcessExecutor.close`)."""


class Executor(Protocol):
    """Runs tasks and yields ``(task, result)`` as each completes."""

    name: str
    workers: int

    def run(self, fn: Callable[..., Any], tasks: Iterable[Task],
            on_submit: Callable[[Task], None] | None = None,
            on_died: Callable[[list[Task], str], None] | None = None,
            ) -> Iterator[tuple[Task, Any]]: ...

    def close(self) -> None: ...


class InProcessExecutor:
    """Runs tasks one after another in this process (no parallelism; easiest to debug)."""

    name = "in-process"
    workers = 1

    def run(self, fn, tasks, on_submit=None, on_died=None):
        for task in tasks:
            if on_submit:
                on_submit(task)
            yield task, fn(*task)

    def close(self) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class WorkerDied(RuntimeError):
    """What a run that took its worker process down with it leaves as its result."""


class ProcessExecutor:
    """A pool of ``workers`` local processes (``spawn`` start method).

    Each worker announces the runs it starts, and ``run``'s ``on_submit`` is told of a
    run when its worker starts it (not when it is queued). A worker that dies (a
    simulator crashing the interpreter or calling ``os._exit``) breaks the pool: the runs
    it and the other workers were running are run again one at a time in a new pool, so
    that the run that kills its worker is found (executed at most twice) and its result
    is a :class:`WorkerDied`, while the others finish normally; runs that were only
    queued are queued again, not suspected. ``on_died`` is told of each such death (the
    runs that were running, and `` (exit code N)`` or `` (killed by signal SIGKILL (9))``). A run
    that asks for a fresh worker (:func:`replace_this_worker`, after a MemoryError) gets
    one: no run is handed out until those in flight finish, then the pool is replaced.
    """

    name = "processes"

    def __init__(self, workers: int):
        self.workers = workers
        self._serial = 0  # each submission's number, which its worker announces
        self._serials: dict[int, Future] = {}
        self._running: set[Future] = set()
        self._alone = False  # the run in flight is a suspect, run alone
        self._pool = self._new_pool()
        self._processes: list[Any] = []

    def _new_pool(self) -> ProcessPoolExecutor:
        # spawn: the workers are children of this process, so they die with it (see
        # _init_worker) and never inherit a half-copied threaded state
        context = multiprocessing.get_context("spawn")
        if getattr(self, "_starts", None) is not None:
            self._starts.close()  # the old pool's workers have ended
        self._starts = context.SimpleQueue()  # each worker announces the runs it starts
        self._serials = {}
        self._alone = False
        threads = max(1, usable_cores() // self.workers)
        return ProcessPoolExecutor(self.workers, mp_context=context, initializer=_init_worker,
                                   initargs=(self._starts, threads))

    def run(self, fn, tasks, on_submit=None, on_died=None):
        pending: dict[Future, Task] = {}
        self._running: set[Future] = set()  # pending runs a worker has started
        stream = iter(tasks)
        suspects: list[Task] = []  # running when a worker died: run again one at a time
        unsent: list[Task] = []  # queued, or refused by a pool that had just broken
        replace = False  # a run asked for a fresh worker (MemoryError): drain, then replace
        nudged = time.monotonic()
        try:
            while True:
                if replace and not pending:
                    self._replace()
                    replace = False
                if not replace and not self._fill(fn, stream, suspects, unsent, pending):
                    break
                alone = len(pending) == 1 and bool(self._alone)
                quiet = all(fut in self._running for fut in pending)
                done, _ = wait(pending, timeout=WATCH_INTERVAL if quiet else START_POLL,
                               return_when=FIRST_COMPLETED)
                self._note_starts(pending, on_submit)
                if not done:
                    if time.monotonic() - nudged >= WATCH_INTERVAL:
                        self._nudge()
                        nudged = time.monotonic()
                    continue
                if any(isinstance(fut.exception(), BrokenProcessPool) for fut in done):
                    done, _ = wait(pending)  # a broken pool fails every run in flight
                    self._note_starts(pending, on_submit)
                ran, queued = [], []
                for fut in done:
                    task = pending.pop(fut)
                    started = fut in self._running
                    self._running.discard(fut)
                    err = fut.exception()
                    if isinstance(err, BrokenProcessPool):
                        (ran if started else queued).append(task)
                    elif err is not None:
                        raise CampaignError(f"a run could not be executed in a worker "
                                            f"({type(err).__name__}: {err})") from err
                    else:
                        result, tired = fut.result()
                        replace = replace or tired
                        if result is _Spent:  # not run: its worker is to be replaced
                            (suspects if alone else unsent).insert(0, task)
                            continue
                        if not started and on_submit:
                            on_submit(task)
                        yield task, result
                if ran or queued:
                    code = self._restart()
                    unsent[:0] = queued  # only queued: not charged with the death
                    if alone and ran:
                        yield ran[0], WorkerDied(f"the process running it died{code}; "
                                                 "the simulator crashed the interpreter "
                                                 "or ended it (os._exit)")
                    elif ran:
                        suspects.extend(ran)
                        if on_died:
                            on_died(ran, code)
        finally:
            for fut in pending:
                fut.cancel()

    def _fill(self, fn, stream, suspects, unsent, pending) -> bool:
        """Submit tasks up to the window (a suspect alone, into an empty pool); False
        when nothing is left to run. A pool that broke since the last wait refuses a
        task: it goes back to its queue, and the runs in flight report the break."""
        while len(pending) < (1 if suspects or self._alone else 2 * self.workers):
            if self._alone and pending:
                break
            if suspects:
                if pending:
                    break
                queue, task = suspects, suspects.pop(0)
            elif unsent:
                queue, task = unsent, unsent.pop(0)
            else:
                queue, task = unsent, next(stream, None)
                if task is None:
                    break
            self._serial += 1
            try:
                future = self._pool.submit(_announced, self._serial, fn, *task)
            except BrokenProcessPool:
                queue.insert(0, task)
                if pending:
                    break
                self._restart()  # nothing in flight reports the break: start afresh
                continue
            pending[future] = task
            self._serials[self._serial] = future
            self._alone = queue is suspects
            self._processes = self._pool_processes()
            if self._alone:
                break
        return bool(pending)

    def _note_starts(self, pending, on_submit) -> None:
        """Mark the pending runs whose worker has said it started them, and tell
        ``on_submit`` of each (so a run merely queued is never taken as started)."""
        while not self._starts.empty():
            future = self._serials.pop(self._starts.get(), None)
            if future in pending and future not in self._running:
                self._running.add(future)
                if on_submit:
                    on_submit(pending[future])

    def _replace(self) -> None:
        """A fresh pool (fresh workers) for one whose runs have all finished."""
        self._pool.shutdown(wait=True)
        self._pool = self._new_pool()
        self._processes = []

    def _restart(self) -> str:
        """A new pool for a broken one; returns `` (exit code N)`` of the dead worker
        (`` (killed by signal SIGKILL (9))``), or "" when it is not known.

        The broken pool's management thread sends SIGTERM to the other workers and waits
        for them. A worker that does not end on SIGTERM (a simulator that ignores it, or
        a worker signalled while it was being started, between fork and exec, where this
        process's SIGTERM handler still catches the signal) would keep that thread, and
        this one, waiting for ever: what is left after :data:`WORKER_GRACE` seconds is
        killed (SIGKILL).
        """
        procs = list(dict.fromkeys([*self._processes, *self._pool_processes()]))
        # a process has ended when its sentinel is ready, whoever reaped it: its exit
        # code reaches this Process object only once the pool's thread has reaped it
        end = time.monotonic() + WORKER_GRACE
        for proc in procs:
            wait_ended([proc.sentinel], max(0.0, end - time.monotonic()))
        killed = {proc for proc in procs if not wait_ended([proc.sentinel], 0)}
        for proc in killed:
            proc.kill()
        # wait: the broken pool's management thread is ending; shutdown(wait=False) would
        # reset the pool's state under it, which can raise in that thread and hang
        # (CPython gh-132969)
        self._pool.shutdown(wait=True, cancel_futures=True)
        codes = []
        for proc in procs:
            # the pool's own management thread may reap the process first; its status
            # then reaches this Process object a moment later, so poll for it
            end = time.monotonic() + 5
            proc.join(5)
            while proc.exitcode is None and time.monotonic() < end:
                proc.join(0.05)
            if proc not in killed:
                codes.append(proc.exitcode)
        self._pool = self._new_pool()
        self._processes = []
        code = next((c for c in codes if c not in (None, 0, -15)), None)
        if code is None:
            return ""
        return f" ({_signalled(-code)})" if code < 0 else f" (exit code {code})"

    def _nudge(self) -> None:
        """Wake the pool's management thread, so that it looks at every worker again.

        It watches the workers it knew of when it last woke, and ``submit`` wakes it
        before starting a new worker (CPython 3.11-3.13): a worker started then that dies
        is not noticed until something else wakes the thread, and the runs in flight
        would wait for ever (or until another run finishes)."""
        wakeup = getattr(self._pool, "_executor_manager_thread_wakeup", None)
        lock = getattr(self._pool, "_shutdown_lock", None)
        if wakeup is not None and lock is not None:
            with lock:
                wakeup.wakeup()

    def _pool_processes(self) -> list[Any]:
        return list((getattr(self._pool, "_processes", None) or {}).values())

    def close(self, *, wait: bool = True) -> None:
        """Shut the pool down; ``wait=False`` also stops the runs in flight (the
        interpreter would otherwise wait for them at exit): SIGTERM, then SIGKILL for a
        worker still running :data:`STOP_GRACE` seconds later (a simulator that ignores
        SIGTERM)."""
        processes = list(dict.fromkeys([*self._processes, *self._pool_processes()]))
        self._pool.shutdown(wait=wait, cancel_futures=True)
        if not wait:
            _stop(processes, STOP_GRACE)
        self._starts.close()

    def __enter__(self):
        return self

    def __exit__(self, kind, *exc):
        # after an interrupt, do not wait for the runs in flight: they will be run again
        self.close(wait=kind is None)


def _signalled(number: int) -> str:
    """``killed by signal SIGKILL (9)``."""
    try:
        return f"killed by signal {signal.Signals(number).name} ({number})"
    except ValueError:
        return f"killed by signal {number}"


def _stop(processes: list[Any], grace: float) -> None:
    """SIGTERM to each process still alive, SIGKILL to those alive ``grace`` seconds
    later; returns once each has ended."""
    alive = [proc for proc in processes if proc.is_alive()]
    for proc in alive:
        proc.terminate()
    end = time.monotonic() + grace
    for proc in alive:
        wait_ended([proc.sentinel], max(0.0, end - time.monotonic()))
    for proc in alive:
        if not wait_ended([proc.sentinel], 0):
            proc.kill()
            wait_ended([proc.sentinel], 5)


_STARTS: list[Any] = []  # in a worker process: the queue it announces its runs on
_REPLACE = [False]  # in a worker process: its run asked for a fresh worker


def _init_worker(starts: Any, threads: int) -> None:
    """Set up a worker process: it dies with its parent (:func:`_die_with_parent`),
    announces its runs on ``starts``, ignores SIGINT, and runs BLAS and OpenMP on
    ``threads`` threads (its share of the cores) unless the environment sets any of
    :data:`THREAD_VARIABLES`. Ctrl-C reaches the whole process group; the campaign
    decides what it means and stops the workers itself, so a KeyboardInterrupt in a
    worker is always the simulator's own.

    Each BLAS library starts a thread per core by default; with two workers on two
    cores their threads spin against each other, and the ninb melt_pool runs took 4-5
    times their CPU time in wall time. The variables reach libraries loaded later
    (SciPy's own OpenBLAS) and the subprocesses of command simulators;
    ``threadpool_limits`` the ones already loaded."""
    _die_with_parent()
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _STARTS[:] = [starts]
    if not any(name in os.environ for name in THREAD_VARIABLES):
        os.environ.update(dict.fromkeys(THREAD_VARIABLES, str(threads)))
        threadpool_limits(limits=threads)


class _Spent:
    """What a worker to be replaced answers for a run it was queued, without running it."""


def _announced(serial: int, fn: Callable[..., Any], *task: Any) -> tuple[Any, bool]:
    """In a worker: say that submission ``serial`` starts, run it; its result, and
    whether this worker is to be replaced (:func:`replace_this_worker`). A worker to be
    replaced runs nothing more: the runs queued to it come back as :class:`_Spent`."""
    if _REPLACE[0]:
        return _Spent, True
    _STARTS[0].put(serial)
    result = fn(*task)
    return result, _REPLACE[0]


def replace_this_worker() -> None:
    """Ask, from a run in a local worker process, for a fresh process for the next runs
    (after a MemoryError, whatever leaked stays in this one); elsewhere a no-op."""
    _REPLACE[0] = True


def _die_with_parent() -> None:
    """Ask Linux to kill this worker when its parent dies (a campaign killed with -9), so
    that no orphan keeps simulating; a no-op elsewhere."""
    try:
        import ctypes

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


class DaskExecutor:
    """Dask distributed: a new ``LocalCluster`` of ``workers`` single-threaded worker
    processes, or an existing scheduler at ``scheduler`` (``tcp://host:8786``), which is
    how a campaign reaches a SLURM/PBS cluster (docs/campaigns.md)."""

    name = "dask"

    def __init__(self, *, workers: int | None = None, scheduler: str | None = None):
        try:
            from distributed import Client, LocalCluster
        except ImportError as err:  # pragma: no cover - a declared dependency
            raise CampaignError(f"the Dask executor needs 'distributed' ({err}); "
                                "pip install 'dask[distributed]'") from None
        self._cluster = None
        if scheduler:
            try:
                self._client = Client(scheduler, timeout=CONNECT_TIMEOUT)
            except (OSError, TimeoutError) as err:
                raise CampaignError(f"cannot reach the Dask scheduler at '{scheduler}' ({err});"
                                    " check the address, or start one with `dask scheduler`"
                                    ) from None
        else:
            self._cluster = LocalCluster(n_workers=workers or 1, threads_per_worker=1,
                                         processes=True, dashboard_address=None,
                                         silence_logs=logging.ERROR)
            self._client = Client(self._cluster)
        self.workers = max(1, sum(self._client.nthreads().values()))

    def run(self, fn, tasks, on_submit=None, on_died=None):
        from distributed import KilledWorker, as_completed

        stream = iter(tasks)
        pending: dict[str, Task] = {}
        completed = as_completed(with_results=False)

        def submit() -> bool:
            task = next(stream, None)
            if task is None:
                return False
            if on_submit:
                on_submit(task)
            fut = self._client.submit(fn, *task, pure=False)
            pending[fut.key] = task
            completed.add(fut)
            return True

        try:
            for _ in range(2 * self.workers):
                if not submit():
                    break
            for fut in completed:
                task = pending.pop(fut.key)
                try:
                    result = fut.result()
                except KilledWorker as err:  # this task killed its workers: record it failed
                    result = err
                except Exception as err:
                    raise CampaignError(f"a run could not be executed on Dask "
                                        f"({type(err).__name__}: {err})") from err
                fut.release()
                yield task, result
                submit()
        finally:
            completed.clear()
            for key in list(pending):
                pending.pop(key)

    def close(self) -> None:
        self._client.close()
        if self._cluster is not None:
            self._cluster.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def make_executor(kind: str = "auto", *, workers: int | None = None,
                  scheduler: str | None = None, isolate: bool = False) -> Executor:
    """Choose an executor.

    Parameters
    ----------
    kind : {"auto", "in-process", "processes", "dask"}
        ``auto``: Dask with ``scheduler`` given; in-process for ``workers`` None or 1
        (one local process with ``isolate``); local processes otherwise.
    workers : int, optional
        Number of parallel runs (processes, or LocalCluster workers).
    scheduler : str, optional
        Address of a running Dask scheduler.
    isolate : bool
        The runs must not share the calling process (a user's Python simulator that may
        end the interpreter): ``auto`` then never picks in-process.
    """
    kind = executor_kind(kind, workers=workers, scheduler=scheduler, isolate=isolate)
    if kind == "in-process":
        return InProcessExecutor()
    if kind == "processes":
        return ProcessExecutor(workers or 1)
    return DaskExecutor(workers=workers, scheduler=scheduler)


# [PROTOCOL://]HOST:PORT, HOST a name, an IPv4 address or a bracketed IPv6 address
_ADDRESS = re.compile(r"((tcp|tls|ucx|ws|wss)://)?([A-Za-z0-9_.-]+|\[[0-9A-Fa-f:.]+\]):(\d{1,5})")


def check_scheduler(address: str) -> None:
    """Refuse a Dask scheduler address that is not ``[PROTOCOL://]HOST:PORT`` (what
    ``dask scheduler`` prints: ``tcp://10.0.0.5:8786``), before anything is made.

    Raises
    ------
    UsageError
        One line naming ``--scheduler`` and the form expected.
    """
    match = _ADDRESS.fullmatch(address)
    if match is None or not 0 < int(match.group(4)) < 65536:
        raise UsageError(f"--scheduler '{address}' is not the address of a Dask scheduler; "
                         "give tcp://HOST:PORT, as `dask scheduler` prints it (such as "
                         "tcp://127.0.0.1:8786)")


def executor_kind(kind: str = "auto", *, workers: int | None = None,
                  scheduler: str | None = None, isolate: bool = False) -> str:
    """The executor :func:`make_executor` makes for these options ("in-process",
    "processes" or "dask"), without making it: a campaign checks its options with this
    before it runs anything.

    Raises
    ------
    CampaignError
        An unknown executor, or options that do not go together.
    UsageError
        A ``scheduler`` that is no address of a Dask scheduler (``tcp://HOST:PORT``).
    """
    if scheduler is not None:
        check_scheduler(scheduler)
    if kind not in EXECUTORS:
        raise CampaignError(f"unknown executor '{kind}'; choose auto, in-process, processes "
                            "or dask")
    if workers is not None and workers < 1:
        raise CampaignError(f"--workers must be >= 1, got {workers}")
    if scheduler and workers:
        raise CampaignError("give --workers or --scheduler, not both (an existing scheduler "
                            "brings its own workers)")
    if kind == "auto":
        parallel = (workers or 1) > 1 or isolate
        kind = "dask" if scheduler else ("processes" if parallel else "in-process")
    if scheduler and kind != "dask":
        raise CampaignError(f"--scheduler needs the Dask executor, not '{kind}'")
    if kind == "in-process" and workers and workers > 1:
        raise CampaignError(f"the in-process executor runs one run at a time, not --workers "
                            f"{workers}; use --executor processes for parallel runs, or drop "
                            "--workers")
    return kind
