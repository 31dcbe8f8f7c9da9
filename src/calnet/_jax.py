"""JAX configuration for all of calnet, applied once when :mod:`calnet` is imported.

calnet computes in 64-bit floats (GP Cholesky factors and KOH log-densities lose too much
in 32 bits). Importing jax takes longer than the whole command line, so when jax is not
imported yet this sets ``JAX_ENABLE_X64``, which jax reads when it starts (subprocesses
inherit it, as they inherit ``XLA_FLAGS``); when jax is already imported it updates
jax's configuration. XLA host devices and the compilation cache are configured by the
entry points (:mod:`calnet.calibration.devices`), not here.

It also widens XLA's CPU thread pool (``NPROC``, read when jax starts its CPU backend)
to at least :data:`MIN_CPU_THREADS` threads. jaxlib 0.10 runs the batch of a batched
LAPACK call (Cholesky, triangular solve) as tasks on that pool and blocks a pool thread
until they finish; when every thread of the pool is blocked so, nothing runs them and the
process hangs for ever. The pool has one thread per core, so on a 2-core machine two
batched factorisations at once (two data sets predicted in two threads, or two in one
program) are enough. With more threads than calnet ever runs such calls at once, they
cannot all block. A pool that jax started before calnet was imported keeps its size:
import calnet first, or set ``NPROC`` yourself.
"""

from __future__ import annotations

import os
import sys

__all__ = ["enable_x64", "widen_cpu_pool", "device_array", "MIN_CPU_THREADS", "FEW_CALLS"]

MIN_CPU_THREADS = 16

FEW_CALLS = {"xla_backend_optimization_level": 0}
"""XLA compiler options of a program that runs a few times per calibration (predictives
over the posterior draws, leave-one-out conditionals, the surrogate checks): LLVM's
optimisation passes cost more there than they save. The sampler and the GP fits, which
run a program thousands of times, keep XLA's default."""


def enable_x64() -> None:
    """Make jax use 64-bit floats and integers by default, whether or not it is imported."""
    if "jax" in sys.modules:
        sys.modules["jax"].config.update("jax_enable_x64", True)
    else:
        os.environ["JAX_ENABLE_X64"] = "true"


def widen_cpu_pool() -> None:
    """Ask for an XLA CPU thread pool of at least :data:`MIN_CPU_THREADS` threads (one per
    core when there are more), unless ``NPROC`` is set already."""
    os.environ.setdefault("NPROC", str(max(MIN_CPU_THREADS, os.cpu_count() or 1)))


def device_array(x, dtype=None):
    """Host data ``x`` (a NumPy array, a list, a number) as a JAX array, compiling nothing.

    ``jnp.asarray`` of a NumPy array without a ``dtype``, and ``jnp.zeros`` or
    ``jnp.ones`` outside a trace, compile a small program per shape (jax 0.10); a
    calnet run made some 50 of them. ``jax.device_put`` copies the array as it is.
    """
    import jax
    import numpy as np

    return jax.device_put(np.asarray(x) if dtype is None else np.asarray(x, dtype=dtype))


enable_x64()
widen_cpu_pool()
