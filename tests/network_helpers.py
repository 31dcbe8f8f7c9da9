"""Helpers for tests that build a small network in a folder: CSV data and fitted
surrogates (every campaign run in-process, GPs without cross-validation)."""

from __future__ import annotations

import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np


def write_csv(path: Path, **columns) -> None:
    """Write equal-length columns (name=values) as a CSV with a header."""
    names = list(columns)
    rows = zip(*(np.asarray(v).tolist() for v in columns.values()), strict=True)
    path.write_text(",".join(names) + "\n" + "".join(",".join(map(str, r)) + "\n"
                                                     for r in rows))


@contextmanager
def on_path(root: Path) -> Iterator[None]:
    """``root`` on ``sys.path`` (the spec's simulator modules beside it) for the block."""
    sys.path.insert(0, str(root))
    try:
        yield
    finally:
        sys.path.remove(str(root))


def fitted_network(root: Path, *, seed: int = 1):
    """``(network, surrogates)`` of the spec in ``root``: its campaigns run in-process
    (``root`` must be on ``sys.path``, see :func:`on_path`) and its GPs fitted."""
    from calnet.campaign import run_campaign
    from calnet.spec import load_spec
    from calnet.surrogates.fit_network import fit_surrogates

    network = load_spec(root)
    for m in network.order:
        run_campaign(network, m, executor="in-process", progress=False)
    return network, fit_surrogates(network, seed=seed, cv=False)
