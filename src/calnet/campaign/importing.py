"""Tables read into a campaign: finished runs to import, and points of a design file.

Both are ``.csv`` or ``.parquet`` tables with one column per model input and parameter
(a run table adds one per output and, optionally, ``status`` and ``message``; other
columns, such as those ``calnet campaign --export`` writes, are ignored). Every problem
is one line naming the file, the column and the row (rows counted from 1, the header
aside) and the fix: a missing column, a value that is not a number, NaN or inf, a value
outside the declared bounds (a :class:`~calnet.errors.CampaignWarning`, or an error with
``settings.strict``), two rows with the same inputs, a table of another model.
"""

from __future__ import annotations

import json
import math
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from calnet.campaign.design import design_columns, log_columns, model_box, to_unit
from calnet.campaign.store import RunStore, input_hash
from calnet.errors import CampaignError, CampaignWarning
from calnet.spec.models import Model

STATUSES = ("ok", "failed", "timeout", "nonconverged")


@dataclass(frozen=True)
class ImportedRuns:
    """The finished runs of a run table, validated against one model.

    Attributes
    ----------
    path : Path
    runs : tuple of dict
        One per finished row, in file order: ``inputs`` (inputs then parameters, declared
        order, floats), ``status``, ``outputs`` (every declared output), ``message``,
        ``simulator``, ``simulator_version``, ``wall_time``.
    n_unfinished : int
        Rows with status ``unfinished`` (an export of an unfinished store), left out.
    """

    path: Path
    runs: tuple[dict[str, Any], ...]
    n_unfinished: int = 0


def read_frame(path: Path) -> Any:
    """The table at ``path`` (``.csv`` or ``.parquet``) as a pandas DataFrame."""
    import pandas as pd

    suffix = path.suffix.lower()
    if suffix not in (".csv", ".parquet"):
        raise CampaignError(f"cannot read '{path}'; give a .csv or .parquet file")
    if not path.is_file():
        raise CampaignError(f"no file '{path}'; check the path (a spec's path is relative "
                            "to the spec's folder)")
    try:
        if suffix == ".csv":  # a value written with 17 digits reads back exactly
            frame = pd.read_csv(path)
        else:
            frame = pd.read_parquet(path)
    except ImportError:
        raise CampaignError(f"reading '{path.name}' needs pyarrow; pip install "
                            "'calnet[parquet]' or give a .csv file") from None
    except Exception as err:  # pandas' parser errors have no common base class
        raise CampaignError(f"cannot read '{path}' as a table ({type(err).__name__}: "
                            f"{str(err).splitlines()[0] if str(err) else ''}); check its "
                            "format") from None
    if frame.empty:
        raise CampaignError(f"'{path}' has no rows; give a table with one row per run")
    return frame


def read_points(path: Path, model: Model, *, strict: bool) -> np.ndarray:
    """The points of a design file, shape ``(n_points, n_inputs + n_parameters)``,
    declared units, validated (see the module docstring)."""
    frame = read_frame(path)
    columns = design_columns(model)
    _check_columns(frame, columns, path, model, "a design file")
    X = np.column_stack([_numbers(frame, c, path) for c in columns])
    _check_inputs(X, columns, model, path, strict=strict)
    return X


def read_runs(path: Path, model: Model, *, strict: bool,
              shown: str | None = None) -> ImportedRuns:
    """The finished runs of a run table, validated (see the module docstring). ``shown``
    names the table in messages (default: ``path``)."""
    frame = read_frame(path)
    _check_meta(path, model)
    where = Path(shown) if shown is not None else path
    columns = design_columns(model)
    _check_columns(frame, (*columns, *model.output_names), where, model, "a run table")
    status = _statuses(frame, where)
    done = status != "unfinished"
    frame, status = frame[done].reset_index(drop=True), status[done]
    rows = np.flatnonzero(done) + 1  # file rows of the kept ones
    X = np.column_stack([_numbers(frame, c, where, rows) for c in columns])
    _check_inputs(X, columns, model, where, strict=strict, rows=rows)
    Y = {o: _numbers(frame, o, where, rows, finite=False) for o in model.output_names}
    for o, y in Y.items():
        bad = np.flatnonzero((status == "ok") & ~np.isfinite(y))
        if bad.size:
            raise CampaignError(f"{where}: column '{o}', row {rows[bad[0]]}: {y[bad[0]]} in a "
                                "run with status ok; give its value, or set that row's "
                                "status to failed")
    runs = tuple({"inputs": {c: float(v) for c, v in zip(columns, X[i], strict=True)},
                  "status": str(status[i]),
                  "outputs": {o: float(Y[o][i]) for o in model.output_names},
                  **_extras(frame, i)} for i in range(len(X)))
    return ImportedRuns(path, runs, int((~done).sum()))


def import_into(db: RunStore, runs: ImportedRuns, *, seed: int,
                model: Model) -> tuple[int, int]:
    """Add the runs the store does not hold yet; ``(added, already held)``.

    A run is identified by its inputs (the same values, or within round-off:
    :data:`SAME_POINT`): one the store holds with the same status and outputs (within
    round-off too) is skipped (importing a file twice, or its copy written with fewer
    digits, adds nothing), one it holds with other outputs is an error. A design point
    not simulated yet is no run: the imported run is added, and the campaign then takes
    it for that point.
    """
    find = point_finder(model, [r for r in db.rows() if r["status"] is not None])
    new, same = [], 0
    for row, run in enumerate(runs.runs, start=1):
        old, exact = find(run["inputs"])
        if old is None:
            new.append(run)
        elif _same_result(old, run, exact=exact):
            same += 1
        else:
            raise CampaignError(f"{runs.path}: row {row} has the inputs of run {old['idx']} "
                                f"of the store '{db.path}' but another result "
                                f"({old['status'] or 'unfinished'} {old['outputs']}); remove "
                                "the row, or import into a new --store")
    db.add_imported(new, seed=seed, source=runs.path.name)
    return len(new), same


# two points closer than this fraction of the box in every column are one point, and two
# results this close relative to their size are one: a value written with fewer digits
# than a float holds (15 significant digits) reads back this close
SAME_POINT = 1e-9


def point_finder(model: Model, rows: list[dict[str, Any]]
                 ) -> Callable[[Mapping[str, float]], tuple[dict[str, Any] | None, bool]]:
    """A function of a point (inputs then parameters) that gives the first of the store
    ``rows`` at that point, and whether its inputs are the same bit for bit (else within
    :data:`SAME_POINT` of the box in every column, in the unit cube, logs where
    declared); ``(None, False)`` when none is."""
    columns, log = design_columns(model), log_columns(model)
    lower, upper = model_box(model)

    def unit(points: list[Mapping[str, float]]) -> np.ndarray:
        x = np.array([[p[c] for c in columns] for p in points], dtype=float)
        return to_unit(x.reshape(len(points), len(columns)), lower, upper, log)

    by_hash: dict[str, dict[str, Any]] = {}
    for r in rows:
        by_hash.setdefault(r["input_hash"], r)
    held = unit([r["inputs"] for r in rows])

    def find(inputs: Mapping[str, float]) -> tuple[dict[str, Any] | None, bool]:
        row = by_hash.get(input_hash(inputs))
        if row is not None or not rows:
            return row, row is not None
        close = np.flatnonzero((np.abs(held - unit([inputs])) <= SAME_POINT).all(axis=1))
        return (rows[close[0]] if close.size else None), False

    return find


# ------------------------------------------------------------------ checks
def _check_meta(path: Path, model: Model) -> None:
    """An export's ``<stem>.meta.json`` names the model it belongs to."""
    meta = path.with_suffix(".meta.json")
    try:
        other = json.loads(meta.read_text()).get("model")
    except (OSError, ValueError, AttributeError):
        return
    if other and other != model.name:
        raise CampaignError(f"'{path}' holds runs of model '{other}' (so says {meta.name}), "
                            f"not of '{model.name}'; import it with --model {other}")


def _check_columns(frame: Any, needed: tuple[str, ...], path: Path, model: Model,
                   what: str) -> None:
    have = [str(c) for c in frame.columns]
    missing = [c for c in needed if c not in have]
    if not missing:
        return
    if len(missing) * 2 > len(needed):
        shown = ", ".join(have[:8]) + (", ..." if len(have) > 8 else "")
        raise CampaignError(f"'{path}' does not match model '{model.name}': it lacks "
                            f"{', '.join(missing)} (its columns: {shown}); is it {what} of "
                            f"another model? {what.capitalize()} of '{model.name}' needs "
                            f"columns {', '.join(needed)}")
    raise CampaignError(f"'{path}' has no column '{missing[0]}'"
                        + (f" (nor {', '.join(missing[1:])})" if missing[1:] else "")
                        + f"; {what} of '{model.name}' needs columns {', '.join(needed)}: "
                        "add it, or rename the column that holds it")


def _numbers(frame: Any, column: str, path: Path, rows: np.ndarray | None = None, *,
             finite: bool = True) -> np.ndarray:
    """Column ``column`` as floats; a one-line error at the first non-number (and, with
    ``finite``, at the first empty cell, NaN or inf)."""
    import pandas as pd

    raw = frame[column]
    rows = np.arange(1, len(raw) + 1) if rows is None else rows
    values = pd.to_numeric(raw, errors="coerce").to_numpy(dtype=float)
    text = raw.isna().to_numpy() == False  # noqa: E712  (elementwise)
    bad = np.flatnonzero(text & np.isnan(values))
    if bad.size:
        raise CampaignError(f"{path}: column '{column}', row {rows[bad[0]]}: "
                            f"'{raw.iloc[bad[0]]}' is not a number; write a number there")
    bad = np.flatnonzero(~np.isfinite(values))
    if finite and bad.size:
        value = "empty or NaN" if not text[bad[0]] else f"{values[bad[0]]}"
        raise CampaignError(f"{path}: column '{column}', row {rows[bad[0]]}: {value}; every "
                            "input and parameter needs a finite value")
    return values


def _check_inputs(X: np.ndarray, columns: tuple[str, ...], model: Model, path: Path, *,
                  strict: bool, rows: np.ndarray | None = None) -> None:
    """Bounds (a warning, an error with ``strict``; log-scale values must be > 0) and
    duplicate rows."""
    rows = np.arange(1, len(X) + 1) if rows is None else rows
    for j, var in enumerate((*model.inputs, *model.parameters)):
        x = X[:, j]
        if getattr(var, "scale", "linear") == "log" and (x <= 0).any():
            i = int(np.argmax(x <= 0))
            raise CampaignError(f"{path}: column '{var.name}', row {rows[i]}: {x[i]:g} <= 0, "
                                "but the variable is declared scale: log; fix the value")
        out = np.flatnonzero((x < var.lower) | (x > var.upper))
        if not out.size:
            continue
        msg = (f"{path}: column '{var.name}': {out.size} row(s) outside its bounds "
               f"[{var.lower:g}, {var.upper:g}] (first: row {rows[out[0]]}, {x[out[0]]:g})")
        if strict:
            raise CampaignError(msg + "; fix the values or widen the bounds "
                                "(settings.strict is on)")
        warnings.warn(msg + "; used as they are (widen the bounds to silence this)",
                      CampaignWarning, stacklevel=4)
    _, first, inverse = np.unique(X, axis=0, return_index=True, return_inverse=True)
    dup = np.flatnonzero(first[inverse.ravel()] != np.arange(len(X)))
    if dup.size:
        i = dup[0]
        raise CampaignError(f"{path}: rows {rows[first[inverse.ravel()[i]]]} and {rows[i]} "
                            f"have the same {', '.join(columns)}; remove one of them")


def _statuses(frame: Any, path: Path) -> np.ndarray:
    """The ``status`` column (``ok`` where absent or empty)."""
    if "status" not in frame.columns:
        return np.full(len(frame), "ok", dtype=object)
    status = frame["status"].fillna("ok").astype(str).str.strip().to_numpy(dtype=object)
    bad = np.flatnonzero(~np.isin(status, (*STATUSES, "unfinished")))
    if bad.size:
        raise CampaignError(f"{path}: column 'status', row {bad[0] + 1}: '{status[bad[0]]}'; "
                            f"write one of {', '.join(STATUSES)} (or leave it empty for ok)")
    return status


def _extras(frame: Any, i: int) -> dict[str, Any]:
    """Message, simulator, version and wall time of row ``i`` where the table has them."""
    out: dict[str, Any] = {}
    for key, column in (("message", "message"), ("simulator", "simulator"),
                        ("simulator_version", "simulator_version"),
                        ("wall_time", "wall_time_s")):
        if column in frame.columns:
            value = frame[column].iloc[i]
            if isinstance(value, float) and math.isnan(value):
                continue
            if key != "wall_time":
                out[key] = str(value)
            elif isinstance(value, (int, float)):
                out[key] = float(value)
    return out


def _same_result(old: dict[str, Any], run: dict[str, Any], *, exact: bool = True) -> bool:
    """Whether a stored run and an imported one hold one result (bit for bit, or with
    ``exact`` False within :data:`SAME_POINT` relative)."""
    if old["status"] != run["status"]:
        return False
    stored = old["outputs"] or {}
    return all(_same(stored.get(k, math.nan), v, exact) for k, v in run["outputs"].items())


def _same(a: float, b: float, exact: bool = True) -> bool:
    return (a == b or (math.isnan(a) and math.isnan(b))
            or (not exact and math.isclose(a, b, rel_tol=SAME_POINT)))
