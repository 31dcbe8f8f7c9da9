"""Batched LAPACK calls run at once in two threads finish (jaxlib's CPU thread pool).

jaxlib 0.10 blocks a thread of XLA's CPU pool while the batch of a batched Cholesky or
triangular solve runs on the same pool; with as many such calls at once as the pool has
threads, the process hangs. The pool has one thread per core unless ``NPROC`` says
otherwise, so the check runs in a subprocess restricted to two cores, as on the 2-core
machines calnet runs on.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

SCRIPT = textwrap.dedent("""
    import os, threading, time
    os.sched_setaffinity(0, sorted(os.sched_getaffinity(0))[:2])
    import calnet  # noqa: F401  (before jax starts its CPU backend)
    import jax, jax.numpy as jnp, numpy as np

    @jax.jit
    def factor(a):  # two independent batched Cholesky factorisations in one program
        k = a @ jnp.swapaxes(a, 1, 2) + 50.0 * jnp.eye(a.shape[1])
        return jnp.linalg.cholesky(k[:16]).sum() + jnp.linalg.cholesky(k[16:]).sum()

    x = jnp.asarray(np.random.default_rng(0).normal(size=(32, 30, 30)))
    def work():
        for i in range(300):
            np.asarray(factor(x + i * 1e-6))
    threads = [threading.Thread(target=work, daemon=True) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=60)
    def name(task):  # a thread may end between the listing and the read
        try:
            return open(f"/proc/self/task/{task}/comm").read().strip()
        except FileNotFoundError:
            return ""
    pool = sum(name(t) == "tf_XLAEigen" for t in os.listdir("/proc/self/task"))
    print("hung" if any(t.is_alive() for t in threads) else "finished", pool, flush=True)
    os._exit(0)
""")


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity") or not os.path.isdir("/proc/self/task"),
                    reason="needs Linux (CPU affinity, /proc)")
def test_batched_factorisations_in_two_threads_finish():
    env = {k: v for k, v in os.environ.items() if k != "NPROC"}
    out = subprocess.run([sys.executable, "-c", SCRIPT], env=env, capture_output=True,
                         text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    status, pool = out.stdout.split()
    assert status == "finished"
    from calnet._jax import MIN_CPU_THREADS

    assert int(pool) >= MIN_CPU_THREADS
