"""``metrics.json`` and ``run_info.json``: strict JSON from nested results (NumPy/JAX
arrays, dataclasses).

NaN and infinities become ``null`` (strict JSON has no NaN); keys are sorted and the file
is indented by two spaces, so that metrics files diff cleanly between runs. Two runs with
the same spec and seed write the same ``metrics.json``, byte for byte; what differs
between them (timings, paths, host, versions) goes to ``run_info.json`` beside it.

Examples
--------
>>> import numpy as np
>>> to_jsonable({"a": np.float32(1.5), "b": np.array([1.0, np.nan])})
{'a': 1.5, 'b': [1.0, None]}
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import platform
import socket
from collections.abc import Mapping
from importlib import metadata
from pathlib import Path, PurePath
from typing import Any

import numpy as np

import calnet
from calnet.files import make_folder, replacing


def to_jsonable(obj: Any) -> Any:
    """Convert a nested object to JSON-ready Python values.

    Handles dicts (keys become ``str``), lists/tuples/sets, NumPy and JAX arrays and
    scalars, objects with a ``to_dict()`` method, other dataclasses, and paths.
    Non-finite floats become ``None``.

    Parameters
    ----------
    obj : object
        The value to convert.

    Returns
    -------
    object
        Built from ``dict``, ``list``, ``str``, ``int``, ``float``, ``bool`` and ``None``.

    Raises
    ------
    TypeError
        For values with no JSON meaning (the type is named).
    """
    if obj is None or isinstance(obj, (bool, str)):
        return obj
    if isinstance(obj, int):
        return int(obj)
    if isinstance(obj, float):
        return float(obj) if math.isfinite(obj) else None
    if isinstance(obj, np.generic):
        return to_jsonable(obj.item())
    if isinstance(obj, Mapping):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple, set, frozenset)):
        items = sorted(obj, key=repr) if isinstance(obj, (set, frozenset)) else obj
        return [to_jsonable(v) for v in items]
    if isinstance(obj, PurePath):
        return str(obj)
    if callable(getattr(obj, "to_dict", None)):
        return to_jsonable(obj.to_dict())
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: to_jsonable(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, np.ndarray) or hasattr(obj, "__array__"):
        arr = np.asarray(obj)
        return to_jsonable(arr.item()) if arr.ndim == 0 else [to_jsonable(v) for v in arr]
    raise TypeError(f"cannot write {type(obj).__name__} to metrics.json; convert it to "
                    "numbers, strings, lists or dicts first")


def write_metrics(path: str | Path, metrics: Mapping[str, Any]) -> Path:
    """Write ``metrics`` as strict, key-sorted, indented JSON (atomically).

    Parameters
    ----------
    path : str or Path
        Destination, usually ``<out>/metrics.json``; parent folders are created.
    metrics : dict
        Nested results; see :func:`to_jsonable`.

    Returns
    -------
    Path
    """
    path = Path(path)
    make_folder(path.parent)
    text = json.dumps(to_jsonable(metrics), sort_keys=True, indent=2, allow_nan=False)
    with replacing(path) as tmp:
        tmp.write_text(text + "\n", encoding="utf-8")
    return path


def write_run_info(path: str | Path, info: Mapping[str, Any]) -> Path:
    """Write ``info`` (timings, paths, host, versions: what differs between two runs with
    the same seed) like :func:`write_metrics`, usually to ``<out>/run_info.json``."""
    return write_metrics(path, info)


def run_environment() -> dict[str, Any]:
    """Where and with what this process runs: versions of calnet, Python and the
    numerical libraries, the platform, the host, the XLA devices."""
    import jax  # jax only where a run's environment is written

    versions = {"calnet": calnet.__version__, "python": platform.python_version()}
    for name in ("jax", "jaxlib", "numpy", "scipy", "blackjax", "arviz", "SALib"):
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = None
    return {"versions": versions, "platform": platform.platform(),
            "host": socket.gethostname(), "cpu_count": os.cpu_count(),
            "xla_devices": jax.local_device_count(),
            "jax_compilation_cache": os.environ.get("JAX_COMPILATION_CACHE_DIR")}
