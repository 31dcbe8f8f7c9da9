"""Independent pieces of a stage side by side, one thread per usable core.

XLA compiles a program on one core, and SciPy's optimisers drive XLA calls from one
Python thread; both release the GIL while they work, so a stage with independent pieces
(one GP fit per output, one predictive per data set) runs them in threads, with BLAS on
one thread (:func:`one_blas_thread`).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

from threadpoolctl import threadpool_limits

T = TypeVar("T")
R = TypeVar("R")


def usable_cores() -> int:
    """The cores this process may run on (its CPU affinity; ``os.cpu_count`` elsewhere)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def map_threads(fn: Callable[[T], R], items: Iterable[T]) -> list[R]:
    """``[fn(item) for item in items]``, computed in up to :func:`usable_cores` threads,
    with BLAS on one thread.

    Results keep the order of ``items``. The exception of the first failing item (in
    that order) propagates once the calls already running have finished; calls not
    started by then are dropped.

    Examples
    --------
    >>> map_threads(lambda x: x * x, [1, 2, 3])
    [1, 4, 9]
    """
    items = list(items)
    workers = min(len(items), usable_cores())
    with one_blas_thread():  # also one by one: the same numbers whatever the core count
        if workers <= 1:
            return [fn(item) for item in items]
        with ThreadPoolExecutor(workers) as pool:
            return list(pool.map(fn, items))


def one_blas_thread():
    """A context in which BLAS (OpenBLAS, MKL) runs on one thread.

    JAX's CPU Cholesky and triangular solves call LAPACK through SciPy's OpenBLAS; with
    several threads of XLA work at once (chains on several XLA host devices, or the
    threads of :func:`map_threads`) each call would start its own BLAS threads and they
    spin against each other. On 2 cores, 4 parallel chains of the ninb thermal stage took
    150 s with default BLAS threads and 15 s with one (benchmarks/README.md, "Chains on
    CPU").
    """
    return threadpool_limits(limits=1, user_api="blas")
