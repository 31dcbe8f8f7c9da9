"""Fixtures of the campaign tests (helpers live in campaign_helpers.py)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent


@pytest.fixture(autouse=True)
def _toy_importable(monkeypatch):
    """Worker processes (process pools, Dask workers, timeout children) import the toy
    simulators through PYTHONPATH, as a user's would."""
    path = os.pathsep.join(p for p in (str(HERE), os.environ.get("PYTHONPATH")) if p)
    monkeypatch.setenv("PYTHONPATH", path)
    monkeypatch.syspath_prepend(str(HERE))
