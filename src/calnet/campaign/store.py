"""The campaign store: one embedded SQLite database per campaign, durable and resumable.

One row per planned run (the design), filled in as the run finishes:

=================  =======================================================================
column             meaning
=================  =======================================================================
idx                run index (row of the design)
input_hash         sha256 of the inputs (canonical JSON), to detect a moved design
inputs             JSON object: inputs then parameters, declared units
seed               the campaign's design seed
started_at         UNIX time the run was last handed to a worker (NULL: never)
status             ``ok`` / ``failed`` / ``timeout`` / ``nonconverged``; NULL: not finished
outputs            JSON object of output values (may hold NaN when not ok)
message            why a run is not ok
diagnostics        JSON object, the simulator's diagnostics
wall_time          seconds
simulator          simulator name; simulator_version its version
finished_at        UNIX time the row was committed
origin             ``simulated`` (a design point run by the campaign; NULL in stores made
                   before runs could be imported) or ``imported`` (a finished run read
                   from a table)
source             the design that placed a simulated run (``lhs``, ``sobol``, ``halton``,
                   ``chain``, ``file:<name>``), or the file an imported run came from
same_as            on a design run whose point an imported run holds (the same inputs, or
                   within round-off): that run's index. Such a row holds no result of its
                   own: it keeps the design's place, the imported run is the run (counted,
                   read and exported once)
=================  =======================================================================

The database runs in WAL mode while a campaign writes; every finished run is committed on
its own, so a killed campaign loses at most the runs in flight. When a campaign closes the
store it is checkpointed back to a single file (unless another connection is reading it),
so a finished store can be shipped and read from a read-only folder.
"""

from __future__ import annotations

import hashlib
import json
import math
import sqlite3
import time
from collections.abc import Iterable, Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from calnet.campaign.lease import SCHEMA as LEASE_SCHEMA
from calnet.campaign.lease import Lease
from calnet.campaign.runners import RunRecord
from calnet.errors import CampaignError
from calnet.files import make_folder
from calnet.spec.models import Model
from calnet.spec.network import Network

SCHEMA_VERSION = "1"

_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS runs (
    idx INTEGER PRIMARY KEY,
    input_hash TEXT NOT NULL,
    inputs TEXT NOT NULL,
    seed INTEGER NOT NULL,
    started_at REAL,
    status TEXT CHECK (status IS NULL OR
                       status IN ('ok', 'failed', 'timeout', 'nonconverged')),
    outputs TEXT,
    message TEXT,
    diagnostics TEXT,
    wall_time REAL,
    simulator TEXT,
    simulator_version TEXT,
    finished_at REAL,
    origin TEXT,
    source TEXT,
    same_as INTEGER
);
"""


def default_store(network: Network, model_name: str) -> Path:
    """``<spec folder>/campaigns/<model>.sqlite``, the store a campaign uses by default."""
    return network.path(Path("campaigns") / f"{model_name}.sqlite")


def model_fingerprint(model: Model) -> dict[str, Any]:
    """What a store's runs depend on: the model's input and parameter boxes (name, bounds,
    unit, log scale, declaration order), its outputs and its simulator reference (the
    timeout aside)."""
    def box(variables) -> list[list[Any]]:  # "log" appended only for log-scale inputs
        return [[v.name, float(v.lower), float(v.upper), v.unit]
                + (["log"] if getattr(v, "scale", "linear") == "log" else [])
                for v in variables]

    return {"model": model.name, "inputs": box(model.inputs),
            "parameters": box(model.parameters), "outputs": list(model.output_names),
            "simulator": model.simulator.model_dump(mode="json", exclude={"timeout"})}


def fingerprint_hash(fingerprint: Mapping[str, Any]) -> str:
    return hashlib.sha256(_canonical(fingerprint).encode()).hexdigest()


def input_hash(inputs: Mapping[str, float]) -> str:
    """Content hash of one run's inputs (order-preserving canonical JSON, exact floats)."""
    return hashlib.sha256(json.dumps(list(inputs.items())).encode()).hexdigest()


def describe_change(old: Mapping[str, Any], new: Mapping[str, Any]) -> str:
    """One phrase saying how two model fingerprints differ."""
    changes = []
    for group in ("inputs", "parameters"):
        before = {v[0]: v for v in old.get(group, [])}
        after = {v[0]: v for v in new.get(group, [])}
        for name in after.keys() - before.keys():
            changes.append(f"{group[:-1]} '{name}' added")
        for name in before.keys() - after.keys():
            changes.append(f"{group[:-1]} '{name}' removed")
        for name in before.keys() & after.keys():
            if before[name][1:3] != after[name][1:3]:
                changes.append(f"bounds of '{name}' changed from {before[name][1:3]} to "
                               f"{after[name][1:3]}")
            if before[name][3] != after[name][3]:
                changes.append(f"unit of '{name}' changed from '{before[name][3]}' to "
                               f"'{after[name][3]}'")
            if before[name][4:] != after[name][4:]:
                changes.append(f"scale of '{name}' changed to "
                               f"{(after[name][4:] or ['linear'])[0]}")
        if not changes and [v[0] for v in old.get(group, [])] != list(after):
            changes.append(f"order of the {group} changed")
    if old.get("outputs") != new.get("outputs"):
        changes.append(f"outputs changed from {old.get('outputs')} to {new.get('outputs')}")
    before, after = _flat(old.get("simulator") or {}), _flat(new.get("simulator") or {})
    for key in sorted(before.keys() | after.keys()):
        if before.get(key) != after.get(key):
            changes.append(f"simulator {key}: {_shown(before.get(key))} -> "
                           f"{_shown(after.get(key))}")
    return "; ".join(sorted(changes)) or "the model spec changed"


def _flat(mapping: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """A nested mapping as ``{"options.mesh": value}``: a change names its own key."""
    out: dict[str, Any] = {}
    for key, value in mapping.items():
        if isinstance(value, Mapping):  # an empty one adds no key
            out.update(_flat(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


def _shown(value: Any) -> str:
    return "(unset)" if value is None else str(value)


class RunStore:
    """An open campaign store (use as a context manager, or call :meth:`close`).

    Parameters
    ----------
    path : path
        The SQLite file.
    readonly : bool
        Open for reading only (no WAL switch, works in read-only folders).
    """

    def __init__(self, path: str | Path, *, readonly: bool = False):
        self.path = Path(path)
        self.readonly = readonly
        self._lease: Lease | None = None
        if readonly and not self.path.is_file():
            raise CampaignError(f"no campaign store at '{self.path}'")
        try:
            if readonly:
                self._db = sqlite3.connect(f"file:{self.path.resolve()}?mode=ro", uri=True)
            else:
                make_folder(self.path.parent)
                self._db = sqlite3.connect(self.path, timeout=30)
        except sqlite3.Error as err:
            raise store_error(self.path, err) from None
        try:
            if not readonly:
                self._db.execute("PRAGMA journal_mode=WAL")
                self._db.execute("PRAGMA synchronous=NORMAL")
                self._db.executescript(_SCHEMA + LEASE_SCHEMA)
                _add_provenance_columns(self._db)
            self._db.execute("SELECT idx, status FROM runs LIMIT 1")
            columns = {row[1] for row in self._db.execute("PRAGMA table_info(runs)")}
        except sqlite3.Error as err:
            self._db.close()
            raise store_error(self.path, err) from None
        # a store read before runs could be imported has no origin column: all simulated
        self._simulated = _SIMULATED if "origin" in columns else "1"
        # the rows that are runs of their own (not a design point an imported run holds)
        self._own = ("same_as IS NULL" if "same_as" in columns
                     else _OWN_UNLINKED if "origin" in columns else "1")

    def take_lease(self) -> None:
        """Hold the store for this process until :meth:`close` (see
        :mod:`calnet.campaign.lease`); a CampaignError naming the holder when another live
        campaign holds it."""
        self._lease = Lease(self._db, self.path)

    def __enter__(self) -> RunStore:
        return self

    def __exit__(self, kind: object, *exc: object) -> None:
        try:
            self.close()
        except sqlite3.Error:
            if kind is None:  # else the error in flight is the one to report
                raise

    def close(self) -> None:
        """Commit, give the lease back, checkpoint the WAL into the main file and close."""
        if self._db is None:
            return
        try:
            if not self.readonly:
                self._db.commit()
                if self._lease is not None:
                    self._lease.release(self._db)
                    self._lease = None
                try:  # best effort: another reader may hold the WAL open, which is fine
                    self._db.execute("PRAGMA wal_checkpoint(TRUNCATE)")
                    self._db.execute("PRAGMA journal_mode=DELETE")
                except sqlite3.OperationalError:
                    pass
        finally:
            self._db.close()
            self._db = None

    @contextmanager
    def snapshot(self) -> Iterator[None]:
        """Within the block, every read sees the store as it was at the first: a
        campaign writing it meanwhile changes nothing that the block reads."""
        self._db.execute("BEGIN")
        try:
            yield
        finally:
            self._db.rollback()

    # ---------------------------------------------------------------- metadata
    def meta(self) -> dict[str, str]:
        return dict(self._db.execute("SELECT key, value FROM meta"))

    def set_meta(self, values: Mapping[str, Any]) -> None:
        with self._db:
            self._db.executemany("INSERT OR REPLACE INTO meta VALUES (?, ?)",
                                 [(k, v if isinstance(v, str) else json.dumps(v))
                                  for k, v in values.items()])

    # ---------------------------------------------------------------- the plan
    def planned(self) -> int:
        """Number of design runs (simulated or to simulate; imported runs aside)."""
        return self._db.execute(f"SELECT COUNT(*) FROM runs WHERE {self._simulated}"
                                ).fetchone()[0]

    def imported(self) -> int:
        """Number of imported runs."""
        return self._db.execute(f"SELECT COUNT(*) FROM runs WHERE NOT {self._simulated}"
                                ).fetchone()[0]

    def next_index(self) -> int:
        """The index a new run gets: one past the largest in the store (0 when empty)."""
        return self._db.execute("SELECT COALESCE(MAX(idx) + 1, 0) FROM runs").fetchone()[0]

    def design_rows(self) -> list[dict[str, Any]]:
        """The design runs (not the imported ones) as :meth:`rows` gives them, by index,
        those whose point an imported run holds included."""
        return [r for r in self.rows(linked=True) if r.get("origin") in (None, "simulated")]

    def plan(self, rows: Iterable[tuple[int, Mapping[str, float]]], *, seed: int,
             source: str = "lhs") -> None:
        """Add design rows ``(index, inputs)`` placed by the design ``source``; existing
        indices must hold the same inputs."""
        known = dict(self._db.execute("SELECT idx, input_hash FROM runs"))
        new = []
        for index, inputs in rows:
            digest = input_hash(inputs)
            if index in known:
                if known[index] != digest:
                    raise CampaignError(f"{self.path}: run {index} holds other inputs than "
                                        "the design asks for; use a new --store or --fresh")
                continue
            new.append((index, digest, _dumps(inputs), seed, source))
        with self._db:
            self._db.executemany("INSERT INTO runs (idx, input_hash, inputs, seed, origin, "
                                 "source) VALUES (?, ?, ?, ?, 'simulated', ?)", new)

    def add_imported(self, runs: Iterable[Mapping[str, Any]], *, seed: int, source: str) -> int:
        """Insert finished runs read from the file ``source``, each a mapping with
        ``inputs``, ``status``, ``outputs`` and optionally ``message``, ``simulator``,
        ``simulator_version``, ``wall_time``; indices follow the store's last. Returns the
        number inserted (one transaction: all or none)."""
        start, now = self.next_index(), time.time()
        new = [(start + k, input_hash(r["inputs"]), _dumps(r["inputs"]), seed, r["status"],
                _dumps(r["outputs"]), r.get("message", ""), _dumps({}), r.get("wall_time"),
                r.get("simulator"), r.get("simulator_version"), now, source)
               for k, r in enumerate(runs)]
        with self._db:
            self._db.executemany(
                "INSERT INTO runs (idx, input_hash, inputs, seed, status, outputs, message, "
                "diagnostics, wall_time, simulator, simulator_version, finished_at, origin, "
                "source) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, 'imported', ?)", new)
        return len(new)

    def unfinished(self) -> list[tuple[int, dict[str, float], bool]]:
        """``(index, inputs, was_in_flight)`` of every run without a status, by index."""
        rows = self._db.execute("SELECT idx, inputs, started_at FROM runs WHERE status IS NULL "
                                f"AND {self._own} ORDER BY idx")
        return [(i, json.loads(s), started is not None) for i, s, started in rows]

    def reset_failed(self) -> int:
        """Forget the outcome of every design run that is not ``ok``, so it runs again
        (imported runs keep theirs: there is nothing to run them again with)."""
        with self._db:
            cur = self._db.execute("UPDATE runs SET status = NULL, started_at = NULL "
                                   "WHERE status IS NOT NULL AND status != 'ok' AND "
                                   f"{self._simulated}")
        return cur.rowcount

    def link(self, index: int, imported: int) -> None:
        """Make the unfinished design run ``index`` stand for the imported run
        ``imported``, which holds its point: it is not simulated, and is neither counted
        nor read apart from that run."""
        with self._db:
            self._db.execute("UPDATE runs SET same_as = ?, started_at = NULL WHERE idx = ? "
                             "AND status IS NULL", (imported, index))

    def imported_not_ok(self) -> dict[str, int]:
        """Imported runs per status other than ``ok`` (which :meth:`reset_failed`
        keeps)."""
        rows = self._db.execute("SELECT status, COUNT(*) FROM runs WHERE status IS NOT NULL "
                                f"AND status != 'ok' AND NOT {self._simulated} GROUP BY 1")
        return {k: int(n) for k, n in rows}

    def mark_started(self, indices: Iterable[int]) -> None:
        now = time.time()
        with self._db:
            self._db.executemany("UPDATE runs SET started_at = ? WHERE idx = ?",
                                 [(now, i) for i in indices])

    def record(self, rec: RunRecord, *, simulator: str, version: str) -> None:
        """Commit one finished run."""
        with self._db:
            self._db.execute(
                "UPDATE runs SET status = ?, outputs = ?, message = ?, diagnostics = ?, "
                "wall_time = ?, simulator = ?, simulator_version = ?, finished_at = ? "
                "WHERE idx = ?",
                (rec.status, _dumps(rec.outputs), rec.message, _dumps(rec.diagnostics),
                 rec.wall_time, simulator, version, time.time(), rec.index))

    # ---------------------------------------------------------------- reading
    def versions(self) -> dict[str, int]:
        """Simulator version -> number of finished design runs made with it (imported runs
        aside: they come from wherever the user made them)."""
        rows = self._db.execute("SELECT COALESCE(simulator_version, ''), COUNT(*) FROM runs "
                                f"WHERE status IS NOT NULL AND {self._simulated} GROUP BY 1")
        return {v: int(n) for v, n in rows}

    def status_counts(self) -> dict[str, int]:
        rows = self._db.execute("SELECT COALESCE(status, 'unfinished'), COUNT(*) FROM runs "
                                f"WHERE {self._own} GROUP BY 1")
        return {k: int(n) for k, n in rows}

    def rows(self, *, linked: bool = False) -> list[dict[str, Any]]:
        """Every run as a dict (JSON columns decoded), by index; with ``linked``, also
        the design rows whose point an imported run holds (``same_as``)."""
        where = "" if linked else f"WHERE {self._own} "
        cur = self._db.execute(f"SELECT * FROM runs {where}ORDER BY idx")
        names = [d[0] for d in cur.description]
        out = []
        for values in cur:
            row = dict(zip(names, values, strict=True))
            for key in ("inputs", "outputs", "diagnostics"):
                row[key] = json.loads(row[key]) if row[key] is not None else None
            out.append(row)
        return out


_SIMULATED = "COALESCE(origin, 'simulated') = 'simulated'"

# a store without the same_as column gave a design run at an imported run's point a copy
# of that run's result, with this message; such a row is the imported run again
_COPIED = "the inputs of imported run %"
_OWN_UNLINKED = (f"NOT (COALESCE(origin, 'simulated') = 'simulated' AND status IS NOT NULL "
                 f"AND message LIKE '{_COPIED}')")


def _add_provenance_columns(db: sqlite3.Connection) -> None:
    """Give a store made before runs could be imported its ``origin`` and ``source``
    columns (NULL in its rows: simulated by the Latin hypercube), and one made before
    design runs could stand for imported runs its ``same_as`` column (its copies of
    imported results become links to those runs)."""
    have = {row[1] for row in db.execute("PRAGMA table_info(runs)")}
    with db:
        for column in ("origin", "source"):
            if column not in have:
                db.execute(f"ALTER TABLE runs ADD COLUMN {column} TEXT")
        if "same_as" not in have:
            db.execute("ALTER TABLE runs ADD COLUMN same_as INTEGER")
            db.execute(
                "UPDATE runs SET same_as = (SELECT i.idx FROM runs AS i WHERE "
                "i.input_hash = runs.input_hash AND i.origin = 'imported' ORDER BY i.idx "
                "LIMIT 1), status = NULL, outputs = NULL, message = NULL, diagnostics = NULL, "
                f"wall_time = NULL, finished_at = NULL WHERE {_SIMULATED} AND status IS NOT "
                f"NULL AND message LIKE '{_COPIED}' AND EXISTS (SELECT 1 FROM runs AS i "
                "WHERE i.input_hash = runs.input_hash AND i.origin = 'imported')")


# primary SQLite result codes (https://sqlite.org/rescode.html)
_UNWRITABLE = {3: "permission denied", 8: "it is read-only", 10: "a disk I/O error (is its "
               "disk full or read-only?)", 13: "no space left on its disk",
               14: "it cannot be opened for writing (is its folder read-only?)"}
_BUSY = (5, 6)
_CORRUPT = 11  # SQLITE_CORRUPT: "database disk image is malformed"


def store_error(path: Path, err: sqlite3.Error) -> CampaignError:
    """The one-line error of a store that SQLite refused: cannot be written (full,
    read-only), locked, or not a store at all."""
    code = (getattr(err, "sqlite_errorcode", None) or 0) & 0xFF
    if code in _UNWRITABLE and not path.is_file():  # nothing there to keep
        return CampaignError(f"cannot create the campaign store '{path}': "
                             f"{_UNWRITABLE[code]} ({err}); make its folder writable, or "
                             "pass a --store in a writable folder")
    if code in _UNWRITABLE:
        return CampaignError(f"cannot write the campaign store '{path}': {_UNWRITABLE[code]} "
                             f"({err}); the store is kept as it is: free some space or make "
                             "it writable, then run again (or copy it to a writable disk "
                             "and pass that --store)")
    if code in _BUSY:
        return CampaignError(f"the campaign store '{path}' is locked by another process "
                             f"({err}); wait for it to finish, then run again")
    if code == _CORRUPT:
        return CampaignError(f"the campaign store '{path}' is damaged ({err}): its runs "
                             "cannot be read; restore it from a copy, or simulate again "
                             "with --fresh (which replaces it)")
    return CampaignError(f"'{path}' is not a calnet campaign store ({err}); pass another "
                         "--store, or --fresh to replace it")


@contextmanager
def store_errors(path: Path) -> Iterator[None]:
    """Turn SQLite's errors on the store at ``path`` into :func:`store_error`'s."""
    try:
        yield
    except sqlite3.Error as err:
        raise store_error(path, err) from None


def _dumps(obj: Any) -> str:
    return json.dumps(obj, allow_nan=True)


def _canonical(obj: Any) -> str:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"))


def is_finite(value: Any) -> bool:
    return isinstance(value, (int, float)) and math.isfinite(value)
