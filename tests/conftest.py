"""Shared test configuration: single-threaded BLAS, 4 host devices (calnet turns on 64-bit JAX)."""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")
os.environ.setdefault("MPLBACKEND", "Agg")
# the tests set the terminal width they check (CliRunner env); pytest-xdist's workers get
# COLUMNS=80 and LINES=24, which Rich would read once, when calnet.cli makes its console
if os.environ.get("PYTEST_XDIST_WORKER"):
    os.environ.pop("COLUMNS", None)
    os.environ.pop("LINES", None)
if "jax" not in __import__("sys").modules:
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_force_host_platform_device_count" not in flags:
        os.environ["XLA_FLAGS"] = (flags + " --xla_force_host_platform_device_count=4").strip()


import gc  # noqa: E402

import pytest  # noqa: E402


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_programs():
    """Drop JAX's and calnet's compiled programs after each test module.

    Every XLA CPU executable holds memory mappings; a whole suite in one process compiles
    thousands of programs, and past the kernel's vm.max_map_count (65530) the compiler's
    next mmap fails and the process dies with a segmentation fault.
    """
    yield
    import sys

    if "jax" in sys.modules:
        import jax

        from calnet.calibration.sampling import clear_cache

        clear_cache()
        jax.clear_caches()
        gc.collect()


@pytest.fixture
def python_sigint():
    """Python's own SIGINT handler for the test, as in a terminal: a suite started as a
    shell's background job inherits SIGINT ignored, and then a signal the test sends
    itself would do nothing."""
    import signal

    old = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, old)
