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


def one_model_campaign(folder, monkeypatch, module: str, returns: str, model: str):
    """A model ``m`` (input x, output y) whose Python simulator ``module:f`` (a name of
    its own: modules stay imported) returns ``{'y': returns}``, one data point, ``model``
    extra YAML of the model; its campaign run, the network back."""
    from calnet.campaign import run_campaign
    from calnet.spec import load_spec

    (folder / f"{module}.py").write_text(f"def f(inputs):\n    return {{'y': {returns}}}\n")
    (folder / "d.csv").write_text("x,y\n0.5,1.5\n")
    (folder / "network.yaml").write_text(
        f"models:\n  m: {{simulator: 'python:{module}:f', inputs: {{x: {{lower: 0, upper: 1}}}},\n"
        f"      outputs: {{y: {{measurable: true}}}}, {model}}}\n"
        "data:\n  d: {path: d.csv, observes: m.y, columns: {x: x, y: y}}\n")
    monkeypatch.syspath_prepend(str(folder))
    net = load_spec(folder)
    run_campaign(net, "m", executor="in-process", progress=False)
    return net
