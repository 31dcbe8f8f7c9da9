# ruff: noqa: F401  (the TYPE_CHECKING imports name the lazily loaded API)
"""Simulation campaigns (method.md section 2): design, run, store, read back.

The verbs are :func:`run_campaign` (design and simulate, resumable), :func:`import_runs`
(finished runs from a table) and :func:`load_runs` (the ``ok`` runs as arrays, for
surrogates). Attributes are imported on first use, so
that ``import calnet.campaign`` (and the CLI) stays fast.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # for type checkers only; at run time the names load lazily
    from calnet.campaign.campaign import (
        CampaignSummary,
        import_runs,
        run_campaign,
    )
    from calnet.campaign.design import Design, augment, latin_hypercube
    from calnet.campaign.executors import make_executor
    from calnet.campaign.runners import RunRecord, execute_run, make_simulator
    from calnet.campaign.store import RunStore, default_store
    from calnet.campaign.table import RunTable, export_runs, load_runs, runs_frame

_EXPORTS = {
    "CampaignSummary": "calnet.campaign.campaign",
    "run_campaign": "calnet.campaign.campaign",
    "import_runs": "calnet.campaign.campaign",
    "default_store": "calnet.campaign.store",
    "RunTable": "calnet.campaign.table",
    "load_runs": "calnet.campaign.table",
    "export_runs": "calnet.campaign.table",
    "runs_frame": "calnet.campaign.table",
    "Design": "calnet.campaign.design",
    "latin_hypercube": "calnet.campaign.design",
    "augment": "calnet.campaign.design",
    "make_simulator": "calnet.campaign.runners",
    "execute_run": "calnet.campaign.runners",
    "RunRecord": "calnet.campaign.runners",
    "make_executor": "calnet.campaign.executors",
    "RunStore": "calnet.campaign.store",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'calnet.campaign' has no attribute '{name}'")


def __dir__() -> list[str]:
    return __all__
