"""XLA host devices, so that NUTS chains run in parallel on CPU cores.

JAX on CPU shows one device unless told otherwise, and the device count is fixed when the
backend starts: ``XLA_FLAGS=--xla_force_host_platform_device_count=N`` must be set before
the backend starts. Call :func:`configure_host_devices` first thing in a program, before
anything runs on jax (the ``calnet`` command does it before it runs a command).
"""

from __future__ import annotations

import os
import re
import sys
import warnings
from dataclasses import dataclass

__all__ = ["HostDevices", "configure_host_devices", "enable_compilation_cache"]

_FLAG = "--xla_force_host_platform_device_count"


@dataclass(frozen=True)
class HostDevices:
    """What :func:`configure_host_devices` did.

    Attributes
    ----------
    requested : int
        Devices asked for.
    applied : bool
        Whether the request will take effect (jax not yet started).
    how : str
        ``"XLA_FLAGS"`` (set before jax was imported), ``"jax_num_cpu_devices"`` (jax
        imported, backend not yet started) or ``"too late"`` (backend already running).
    message : str
        One line for logs.
    """

    requested: int
    applied: bool
    how: str
    message: str


def _set_flag(n: int) -> None:
    flags = re.sub(rf"{_FLAG}=\d+", "", os.environ.get("XLA_FLAGS", "")).split()
    os.environ["XLA_FLAGS"] = " ".join(flags + [f"{_FLAG}={n}"])


def configure_host_devices(n: int | None = None) -> HostDevices:
    """Ask XLA for ``n`` CPU devices (default: ``max(4, os.cpu_count())``).

    Sets ``XLA_FLAGS`` if jax is not imported yet (also inherited by subprocesses); if jax
    is imported but its backend has not started, sets ``jax_num_cpu_devices``; otherwise
    nothing can be done: the report says so and a warning too (chains then run one after
    another).
    4 devices for 4 chains is fastest even on 2 cores (benchmarks/README.md,
    "Chains on CPU").

    Examples
    --------
    >>> report = configure_host_devices(4)
    >>> report.requested
    4
    """
    n = max(4, os.cpu_count() or 1) if n is None else int(n)
    if n < 1:
        raise ValueError(f"configure_host_devices: expected n >= 1, got {n}")
    if "jax" not in sys.modules:
        _set_flag(n)
        return HostDevices(n, True, "XLA_FLAGS", f"XLA_FLAGS set for {n} host devices")
    import jax
    from jax._src import xla_bridge

    if not xla_bridge.backends_are_initialized():
        _set_flag(n)
        jax.config.update("jax_num_cpu_devices", n)
        return HostDevices(n, True, "jax_num_cpu_devices",
                           f"jax imported but not started: jax_num_cpu_devices={n}")
    have = jax.local_device_count()
    if have >= n:
        return HostDevices(n, True, "too late", f"jax already started with {have} devices")
    report = HostDevices(n, False, "too late",
                         f"jax already started with {have} device(s); set XLA_FLAGS="
                         f"{_FLAG}={n} before importing jax to run {n} chains in parallel")
    warnings.warn(f"configure_host_devices({n}) came after jax started with {have} "
                  "device(s): chains run one after another, not in parallel, and their "
                  "draws differ from parallel chains' (valid, but not the same numbers as "
                  "'calnet calibrate' gives for the same seed); call it before anything "
                  "that imports jax", UserWarning, stacklevel=2)
    return report


def enable_compilation_cache() -> str | None:
    """Keep XLA's compiled programs on disk, so a second run skips most compilation.

    Uses ``$CALNET_JAX_CACHE`` if set (``off`` disables it), else
    ``$XDG_CACHE_HOME/calnet/jax`` (``~/.cache/calnet/jax``). Works through jax's own
    environment variables, so it must run before jax is imported to take effect; a
    value the user already set in ``JAX_COMPILATION_CACHE_DIR`` wins. Returns the folder,
    or None when disabled.
    """
    setting = os.environ.get("CALNET_JAX_CACHE", "").strip()
    if setting.lower() in ("off", "0", "no", "false"):
        return None
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    path = setting or os.path.join(base, "calnet", "jax")
    os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", path)
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0.5")
    return os.environ["JAX_COMPILATION_CACHE_DIR"]
