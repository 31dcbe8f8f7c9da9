"""Reading a finished campaign: the run table for surrogates, and CSV/Parquet export."""

from __future__ import annotations

import json
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from calnet.campaign.design import design_columns
from calnet.campaign.store import (
    RunStore,
    default_store,
    describe_change,
    fingerprint_hash,
    model_fingerprint,
)
from calnet.errors import CampaignError, UnknownModel
from calnet.files import make_folder, replacing
from calnet.spec.network import Network


@dataclass(frozen=True)
class RunTable:
    """The ``ok`` runs of one model's campaign, ready for surrogate fitting.

    Attributes
    ----------
    columns : tuple of str
        Model input names then parameter names, in declaration order.
    X : ndarray, shape (n_ok, n_columns)
        Inputs of the ``ok`` runs, in run-index order, declared units (a design point
        that an imported run holds is that run, read once).
    Y : dict of str to ndarray, each shape (n_ok,)
        Every declared output of those runs.
    n_total : int
        Finished runs in the store, whatever their status.
    n_excluded : int
        Finished runs left out: status not ``ok``.
    status_counts : dict of str to int
        Runs per status (``unfinished`` for planned runs not yet finished, if any).
    store_path : Path
    """

    columns: tuple[str, ...]
    X: np.ndarray
    Y: dict[str, np.ndarray]
    n_total: int
    n_excluded: int
    status_counts: dict[str, int]
    store_path: Path

    @property
    def n_ok(self) -> int:
        return len(self.X)


def load_runs(network: Network, model_name: str, store: str | Path | None = None) -> RunTable:
    """Read the ``ok`` runs of ``model_name``'s campaign.

    Parameters
    ----------
    network : Network
    model_name : str
    store : path, optional
        Default :func:`~calnet.campaign.default_store` (``<spec>/campaigns/<model>.sqlite``).

    Returns
    -------
    RunTable

    Raises
    ------
    CampaignError
        When the store is missing, or was made from a different spec of the model
        (bounds, order, outputs or simulator changed).
    """
    try:
        model = network.model(model_name)
    except KeyError:
        raise UnknownModel(f"no model named '{model_name}'; choose one of "
                            f"{[m.name for m in network.models]}") from None
    path = Path(store) if store is not None else default_store(network, model_name)
    spec = network.source or network.root
    if not path.is_file():
        raise CampaignError(f"no campaign store for '{model_name}' at '{path}'; run "
                            f"`calnet campaign {spec} --model {model_name}` first")
    with RunStore(path, readonly=True) as db:
        meta, rows, counts = db.meta(), db.rows(), db.status_counts()
    fp = model_fingerprint(model)
    if meta.get("model_hash") != fingerprint_hash(fp):
        change = describe_change(json.loads(meta.get("model_spec", "{}")), fp)
        raise CampaignError(f"the store '{path}' was made from a different '{model_name}' "
                            f"spec ({change}); re-simulate with `calnet campaign {spec} "
                            f"--model {model_name} --fresh` or pass a new store")
    columns = design_columns(model)
    ok = [r for r in rows if r["status"] == "ok"]
    X = np.array([[r["inputs"][c] for c in columns] for r in ok], dtype=float)
    Y = {o: np.array([r["outputs"][o] for r in ok], dtype=float) for o in model.output_names}
    n_total = sum(r["status"] is not None for r in rows)
    return RunTable(columns, X.reshape(len(ok), len(columns)), Y, n_total, n_total - len(ok),
                    counts, path)


def runs_frame(store: str | Path) -> Any:
    """Every run of a store as a pandas DataFrame: ``run``, ``status``, ``message``, one
    column per input/parameter, one per output, then wall time, simulator, hashes and
    provenance (``origin``: simulated or imported; ``source``: the design or the file)."""
    with RunStore(store, readonly=True) as db:
        return _frame(db.rows())


def _frame(rows: list[dict[str, Any]]) -> Any:
    """:func:`runs_frame` of the store's ``rows``."""
    import pandas as pd

    inputs = list(dict.fromkeys(k for r in rows for k in r["inputs"]))
    outputs = list(dict.fromkeys(k for r in rows for k in (r["outputs"] or {})))
    records = [{"run": r["idx"], "status": r["status"] or "unfinished",
                "message": r["message"] or "",
                **{k: r["inputs"][k] for k in inputs},
                **{k: (r["outputs"] or {}).get(k, np.nan) for k in outputs},
                "wall_time_s": r["wall_time"], "simulator": r["simulator"],
                "simulator_version": r["simulator_version"], "seed": r["seed"],
                "input_hash": r["input_hash"], "origin": r.get("origin") or "simulated",
                "source": r.get("source") or ""} for r in rows]
    return pd.DataFrame.from_records(records)


def check_export(out: Path) -> str:
    """The suffix of an export file :func:`export_runs` can write (``.csv`` or
    ``.parquet``, the latter with pyarrow); a CampaignError otherwise."""
    suffix = out.suffix.lower()
    if suffix not in (".csv", ".parquet"):
        raise CampaignError(f"cannot export to '{out.name}'; name the file *.csv or *.parquet")
    if suffix == ".parquet":
        try:
            import pyarrow  # noqa: F401
        except ImportError:
            raise CampaignError("Parquet export needs pyarrow; pip install 'calnet[parquet]' "
                                "or export to .csv") from None
    return suffix


def export_runs(store: str | Path, out: str | Path) -> Path:
    """Write a store's runs to CSV or Parquet (by ``out``'s suffix), and its metadata
    (spec hash, seed, calnet and simulator versions, status counts) beside it as
    ``<out stem>.meta.json``; returns ``out``.

    Raises
    ------
    CampaignError
        For another suffix, or for Parquet without pyarrow.
    CalnetError
        When a file cannot be written (no space left, read-only); each is replaced whole
        or left as it was.
    """
    return write_export(store, out)[0]


def write_export(store: str | Path, out: str | Path) -> tuple[Path, dict[str, int]]:
    """:func:`export_runs`, also returning the status counts of the runs written
    (``unfinished`` for those not finished). The runs and the metadata are read at one
    moment, so that they agree while a campaign is still writing the store."""
    out = Path(out)
    suffix = check_export(out)
    with RunStore(store, readonly=True) as db, db.snapshot():
        meta, rows = db.meta(), db.rows()
    counts = dict(sorted(Counter(r["status"] or "unfinished" for r in rows).items()))
    frame = _frame(rows)
    make_folder(out.parent)
    with replacing(out) as tmp:
        if suffix == ".csv":
            frame.to_csv(tmp, index=False, float_format="%.17g")
        else:
            frame.to_parquet(tmp, index=False)
    meta = {**meta, "status_counts": counts, "store": Path(store).name}
    meta["model_spec"] = json.loads(meta.get("model_spec", "{}"))
    with replacing(out.with_suffix(".meta.json")) as tmp:
        tmp.write_text(json.dumps(meta, indent=2) + "\n")
    return out, counts
