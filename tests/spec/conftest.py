"""A small valid spec written to a temporary folder, for the spec error tests to break."""

from __future__ import annotations

import copy
from pathlib import Path

import pytest
import yaml

BASE = {
    "name": "toy",
    "models": {
        "heat": {
            "simulator": "python:toy_sims:heat",
            "inputs": {"P": {"unit": "W", "lower": 50, "upper": 250},
                       "v": {"unit": "m/s", "lower": 0.1, "upper": 2.0}},
            "parameters": {"k": {"unit": "W/(m K)", "lower": 10, "upper": 30}},
            "outputs": {"W": {"unit": "um", "measurable": True},
                        "G": {"unit": "K/m", "transform": "log"}},
        },
        "micro": {
            "simulator": "python:toy_sims:micro",
            "inputs": {"G": {"unit": "K/m", "lower": 1e5, "upper": 1e8},
                       "S": {"unit": "m/s", "lower": 0.1, "upper": 2.0}},
            "parameters": {"s": {"lower": 1, "upper": 2}},
            "outputs": {"lam": {"unit": "um", "measurable": True}},
        },
    },
    "links": [{"from": "heat.G", "to": "micro.G"}, {"from": "heat.v", "to": "micro.S"}],
    "data": {
        "width": {"path": "width.csv", "observes": "heat.W",
                  "columns": {"P": "power", "v": "speed", "W": "width"}, "split": "split"},
        "spacing": {"path": "spacing.csv", "observes": "micro.lam",
                    "columns": {"P": "power", "v": "speed", "lam": "pdas"}},
    },
}

WIDTH_CSV = ("id,power,speed,width,split\n1,100,0.5,90,train\n2,150,1.0,80,train\n"
             "3,200,1.5,85,test\n")
SPACING_CSV = "id,power,speed,pdas\n1,100,0.5,0.3\n2,150,1.0,0.35\n"


@pytest.fixture
def base_spec() -> dict:
    return copy.deepcopy(BASE)


@pytest.fixture
def write_spec(tmp_path: Path):
    """Write a spec dict (and default CSVs) to tmp_path; return the YAML path."""

    def _write(spec: dict, *, width: str | None = WIDTH_CSV, spacing: str | None = SPACING_CSV,
               text: str | None = None) -> Path:
        if width is not None:
            (tmp_path / "width.csv").write_text(width)
        if spacing is not None:
            (tmp_path / "spacing.csv").write_text(spacing)
        path = tmp_path / "network.yaml"
        path.write_text(text if text is not None else yaml.safe_dump(spec, sort_keys=False))
        return path

    return _write
