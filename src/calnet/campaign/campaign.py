"""The campaign driver: design, simulate, store (method.md section 2).

``run_campaign(network, model)`` plans the model's design over its ``(x, theta)`` box
(a Latin hypercube, a quasi-random sequence, a file of points, or chain-aware:
:mod:`calnet.campaign.planning`), imports the spec's run table if it names one, runs
every planned run that the store has not finished, commits each run as it finishes and
returns a :class:`CampaignSummary`. Calling it again resumes: finished runs (whatever
their status) are kept, runs that were in flight when a campaign died are run again.
Asking for more runs than the store plans augments the design (new points fill the
gaps, the old ones stay). ``import_runs`` only imports a table of finished runs.
"""

from __future__ import annotations

import hashlib
import json
import math
import sqlite3
import time
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import calnet
from calnet.campaign.executors import WorkerDied, executor_kind, make_executor
from calnet.campaign.importing import ImportedRuns, import_into, point_finder, read_runs
from calnet.campaign.lease import holder as lease_holder
from calnet.campaign.logs import logs_note, tidy
from calnet.campaign.planning import (
    DesignChoice,
    choose_design,
    design_conflict,
    fallback_note,
    fewer_note,
    plan,
    settings_of,
    spec_design,
    target_runs,
)
from calnet.campaign.progress_bar import campaign_progress
from calnet.campaign.runners import (
    BuiltinRunner,
    CallableRunner,
    RunRecord,
    execute_run,
    make_simulator,
    run_timeout,
    simulator_version,
)
from calnet.campaign.store import (
    RunStore,
    default_store,
    describe_change,
    fingerprint_hash,
    model_fingerprint,
    store_errors,
)
from calnet.errors import CampaignError, CampaignWarning, SpecError, UnknownModel
from calnet.files import shown_path, why
from calnet.spec.models import Model
from calnet.spec.network import Network

FAILURES_KEPT = 20  # messages of failed runs a CampaignSummary keeps


@dataclass(frozen=True)
class CampaignSummary:
    """What a campaign call did.

    Attributes
    ----------
    model : str
    store_path : Path
        Absolute.
    planned : int
        Runs in the design.
    skipped : int
        Runs already finished before this call (kept, not re-run).
    ran : int
        Runs finished by this call.
    rerun_in_flight : int
        Of those, runs that a previous, interrupted campaign had started.
    status_counts : dict of str to int
        Over the whole store (``unfinished`` when runs remain).
    failures : dict of int to str
        Run index -> message of the runs of this call that are not ``ok`` (the first
        :data:`FAILURES_KEPT` to finish), by index.
    wall_time : float
        Seconds this call took.
    executor : str
    workers : int
    seed : int
    imported : int
        Runs imported by this call (``campaign.import`` or ``--import``).
    design : str
        The store's design (``lhs``, ``sobol``, ``halton``, ``chain``, ``file:<name>``).
    n_failed : int
        Runs of this call that did not finish ``ok`` (all of them, not only those in
        ``failures``).
    notes : tuple of str
        What else happened, one line each: fewer runs asked for than the store plans
        (all of them kept), imported runs not ``ok`` that
        ``retry_failed`` keeps as they are, a worker process that died (and the runs in
        flight with it, run again).
    """

    model: str
    store_path: Path
    planned: int
    skipped: int
    ran: int
    rerun_in_flight: int
    status_counts: dict[str, int]
    failures: dict[int, str] = field(default_factory=dict)
    wall_time: float = 0.0
    executor: str = ""
    workers: int = 1
    seed: int = 0
    imported: int = 0
    design: str = ""
    n_failed: int = 0
    notes: tuple[str, ...] = ()

    @property
    def n_ok(self) -> int:
        return self.status_counts.get("ok", 0)

    @property
    def complete(self) -> bool:
        return "unfinished" not in self.status_counts


def run_campaign(network: Network, model_name: str, *, runs: int | None = None,
                 workers: int | None = None, scheduler: str | None = None,
                 store: str | Path | None = None, executor: str = "auto",
                 seed: int | None = None, progress: bool | Callable[[str], None] = True,
                 fresh: bool = False,
                 retry_failed: bool = False) -> CampaignSummary:
    """Run (or resume) the simulation campaign of one model.

    Parameters
    ----------
    network : Network
    model_name : str
    runs : int, optional
        Size of the design; default the model's ``campaign.runs`` (or the network's), or
        the store's planned size when that is larger. More than the store plans augments it;
        fewer keeps the store's design whole, which ``notes`` of the summary says.
    workers : int, optional
        Parallel runs; with ``executor="auto"``, more than 1 means local processes.
    scheduler : str, optional
        Address of a running Dask scheduler (``tcp://host:8786``); implies Dask.
    store : path, optional
        The SQLite store; default :func:`~calnet.campaign.default_store`.
    executor : {"auto", "in-process", "processes", "dask"}
        ``dask`` without ``scheduler`` starts a ``LocalCluster`` of ``workers`` workers.
    seed : int, optional
        Design seed; default ``network.settings.seed``. Seed 0 is a seed.
    progress : bool or callable
        Show progress: a Rich bar (done / failed / rate / ETA) on a terminal, plain lines
        on stderr otherwise (a line at every 10 % of the runs, and one at least every
        10 s, naming the runs in flight and how long the oldest has been); a callable
        gets those lines instead.
    fresh : bool
        Delete the store first and simulate everything again.
    retry_failed : bool
        Run again the simulated runs that finished with a status other than ``ok``;
        imported runs keep theirs, which ``notes`` of the summary says.

    Returns
    -------
    CampaignSummary

    Raises
    ------
    CampaignError
        Unknown model, a store made with another seed or another model spec, bad options.
    KeyboardInterrupt
        Re-raised after the finished runs are committed; call again to resume.
    """
    model = _model(network, model_name)
    executor_kind(executor, workers=workers, scheduler=scheduler)  # bad options fail first
    seed = network.settings.seed if seed is None else int(seed)
    path = _store_path(network, model_name, store)
    asked = spec_design(network, model)  # a bad design file or run table fails first
    table = _spec_table(network, model)
    if fresh or _stale_without_results(path, network, model, seed):
        held = lease_holder(path)
        if held:
            raise CampaignError(held)
        remove_store(path)
    sim = make_simulator(network, model, workdir=path.with_suffix(".work"))
    version = simulator_version(sim, timeout=run_timeout(network, model))
    start = time.perf_counter()
    done = _complete_readonly(path, network, model, seed, runs, sim.name, version,
                              retry_failed or table is not None, start, asked)
    if done is not None:  # nothing to run: the store is read, never written
        return done
    with store_errors(path), RunStore(path) as db:
        db.take_lease()
        _claim(db, network, model, seed, sim.name, version)
        imported = import_into(db, table, seed=seed, model=model)[0] if table is not None else 0
        choice = choose_design(network, model, db.meta(), asked)
        problem = design_conflict(choice, db.meta(), path)
        if problem:
            raise CampaignError(problem)
        _warn_fallback(network, model, choice, db.meta(), path)
        total = plan(db, network, model, choice,
                     target_runs(runs, network, model, choice, db.planned(), db.imported()),
                     seed)
        fewer = fewer_note(runs, network, model, choice, total)
        notes: list[str] = [fewer] if fewer else []
        if retry_failed:
            db.reset_failed()
            notes += _kept_imported(db)
        todo = _link_imported(db, model, db.unfinished())
        _check_versions(db, model.name, shown_path(path, network.root), sim.name, version,
                        bool(todo))
        skipped = total - len(todo)
        in_flight = sum(was for _, _, was in todo)
        timeout = run_timeout(network, model)
        failures: dict[int, str] = {}
        n_failed = 0
        undeclared: set[str] = set()  # outputs not in the spec, warned about once
        # a user's Python function without a timeout runs in a worker process, so that
        # one ending the interpreter is recorded as failed instead of ending the campaign
        isolate = isinstance(sim, CallableRunner) and timeout is None
        work = path.with_suffix(".work").absolute()
        with _tidied(work, [i for i, _, _ in todo]), \
                make_executor(executor, workers=workers, scheduler=scheduler,
                              isolate=isolate) as ex, \
                campaign_progress(progress, model_name, total, skipped, db) as shown:
            # what a simulator prints goes to its run's logs, unless the run shares this
            # process (the console's) or runs on Dask workers (threads of their process)
            capture = timeout is not None or ex.name == "processes"
            tasks = ((sim, i, inputs, timeout, model.output_names,
                      str(work / f"run-{i:05d}") if capture else None)
                     for i, inputs, _ in todo)

            def submitted(task: tuple) -> None:
                db.mark_started([task[1]])
                shown.started(task[1])

            def died(lost: list[tuple], code: str) -> None:
                notes.append(_died_note(sorted(t[1] for t in lost), code))
                shown.note(notes[-1])

            for task, result in ex.run(execute_run, tasks, on_submit=submitted,
                                       on_died=died):
                rec = result if isinstance(result, RunRecord) else _worker_died(task[1], result)
                db.record(rec, simulator=sim.name, version=version)
                if rec.status == "ok" and not isinstance(sim, BuiltinRunner):
                    undeclared = _warn_undeclared(model, rec, undeclared)
                n_failed += rec.status != "ok"
                if rec.status != "ok" and len(failures) < FAILURES_KEPT:
                    failures[rec.index] = f"{rec.status}: {rec.message}"
                shown.finished(rec.index, rec.status)
        note = logs_note(work, [i for i, _, _ in todo])
        notes += [note] if note else []
        counts, label = db.status_counts(), db.meta().get("design_kind", "")
    return CampaignSummary(model_name, path, total, skipped, len(todo), in_flight,
                           counts, dict(sorted(failures.items())), time.perf_counter() - start,
                           ex.name, ex.workers, seed, imported, label, n_failed, tuple(notes))


def _store_path(network: Network, model_name: str, store: str | Path | None) -> Path:
    """The store's absolute path (``store``, else the default one), fixed once: a
    simulator that changes the working directory does not move it."""
    return (Path(store) if store is not None else default_store(network, model_name)).absolute()


@contextmanager
def _tidied(work: Path, indices: list[int]) -> Iterator[None]:
    """On leaving the block, however it is left, remove the empty logs and empty folders
    of the runs ``indices`` in the work folder ``work``, which a run whose process was
    killed (an interrupt, a worker that died, a timeout) had no time to remove."""
    try:
        yield
    finally:
        if work.is_dir():
            for index in indices:
                tidy(work / f"run-{index:05d}")
        with suppress(OSError):
            work.rmdir()  # only when empty


def _kept_imported(db: RunStore) -> list[str]:
    """The line saying that ``--retry-failed`` keeps the imported runs that are not
    ``ok`` as they are (none without such runs)."""
    counts = db.imported_not_ok()
    if not counts:
        return []
    n = sum(counts.values())
    by = ", ".join(f"{k} {v}" for k, v in sorted(counts.items()))
    runs = "run" if n == 1 else "runs"
    return [f"--retry-failed runs again the simulated runs only: {n} imported {runs} not ok "
            f"({by}) {'is' if n == 1 else 'are'} kept as imported; to simulate "
            f"{'its point' if n == 1 else 'those points'}, give "
            f"{'it' if n == 1 else 'them'} as a design file (campaign.design) to a new "
            "--store"]


def _died_note(indices: list[int], code: str) -> str:
    """The line saying that a worker process died while the runs ``indices`` were
    running (the runs only queued are not named: they are not suspected)."""
    runs = (f"run {indices[0]}" if len(indices) == 1
            else f"runs {', '.join(map(str, indices))}")
    again = "it is run again alone" if len(indices) == 1 else "they are run again, one at a time"
    return (f"a worker process died{code} with {runs} running; {again} (a run that ends "
            "its process again is recorded failed)")


def _warn_undeclared(model: Model, rec: RunRecord, said: set[str]) -> set[str]:
    """Warn (once per campaign and name) about the outputs a run of the user's simulator
    returned that ``model`` does not declare (a built-in one returns all it computes);
    return the names warned about so far."""
    new = sorted(set(rec.outputs) - set(model.output_names) - said)
    if new:
        names, it = ", ".join(f"'{k}'" for k in new), "it" if len(new) == 1 else "them"
        warnings.warn(f"{model.name}: the simulator returned {names} (run {rec.index} "
                      f"first), not declared in models.{model.name}.outputs; the store "
                      f"keeps {it}, calnet uses only the declared outputs "
                      f"({', '.join(model.output_names)}): declare {it} to use {it}, or "
                      f"stop returning {it}", CampaignWarning, stacklevel=3)
    return said | set(new)


def _link_imported(db: RunStore, model: Model, todo: list) -> list:
    """The unfinished design runs ``todo`` less those whose point an imported run holds
    (the same inputs, or within round-off: :func:`~calnet.campaign.importing.point_finder`):
    each of those stands for that run (:meth:`RunStore.link`) instead of simulating the
    point again, which would only repeat it (and repeated points make cross-validation
    look better than it is)."""
    held = [r for r in db.rows() if r.get("origin") == "imported" and r["status"] is not None]
    if not held or not todo:
        return todo
    find = point_finder(model, held)
    left = []
    for index, inputs, was in todo:
        row, _ = find(inputs)
        if row is None:
            left.append((index, inputs, was))
        else:
            db.link(index, int(row["idx"]))
    return left


def import_runs(network: Network, model_name: str, table: str | Path, *,
                store: str | Path | None = None, seed: int | None = None) -> CampaignSummary:
    """Import a table of finished runs into a model's store (simulating nothing).

    Parameters
    ----------
    network : Network
    model_name : str
    table : path
        ``.csv`` or ``.parquet``: one column per input, parameter and output, an optional
        ``status`` (``ok`` where absent); see :mod:`calnet.campaign.importing`.
    store : path, optional
        Default :func:`~calnet.campaign.default_store`.
    seed : int, optional
        The store's seed (default ``network.settings.seed``), checked like a campaign's.

    Returns
    -------
    CampaignSummary
        ``imported`` runs added; runs the store already held are skipped, so importing
        the same file again adds nothing.

    Raises
    ------
    CampaignError
        A bad table (one line naming the file, column and row), a store of another model
        or seed, a row whose inputs the store holds with another result.
    """
    model = _model(network, model_name)
    seed = network.settings.seed if seed is None else int(seed)
    path = _store_path(network, model_name, store)
    runs = read_runs(Path(table), model, strict=network.settings.strict)
    sim = make_simulator(network, model, workdir=path.with_suffix(".work"))
    start = time.perf_counter()
    with store_errors(path), RunStore(path) as db:
        db.take_lease()
        _claim(db, network, model, seed, sim.name,
               simulator_version(sim, timeout=run_timeout(network, model)))
        added, _ = import_into(db, runs, seed=seed, model=model)
        planned, counts = db.planned(), db.status_counts()
        label = db.meta().get("design_kind", "")
    return CampaignSummary(model_name, path, planned, planned, 0, 0, counts, {},
                           time.perf_counter() - start, "none", 0, seed, added, label)


def _spec_table(network: Network, model: Model) -> ImportedRuns | None:
    """The spec's ``campaign.import`` table, read and validated; None without one."""
    name = settings_of(network, model).import_
    if name is None:
        return None
    table = network.path(name)
    if not table.is_file():
        raise SpecError(f"no run table '{table}'; give a .csv or .parquet file of finished "
                        "runs, relative to the spec", file=network.source or None,
                        field=f"models.{model.name}.campaign.import")
    return read_runs(table, model, strict=network.settings.strict,
                     shown=shown_path(table, network.root))


def _complete_readonly(path: Path, network: Network, model: Model, seed: int,
                       runs: int | None, simulator: str, version: str, write: bool,
                       start: float, asked: DesignChoice | None) -> CampaignSummary | None:
    """The summary of a store that needs no work (same spec and seed, every planned run
    finished, no more runs asked for), read without writing a byte; else None. A run
    table to import, or a design file, is checked against the store on the writing path
    (``write``, or ``asked`` a design file)."""
    if write or not path.is_file() or (asked is not None and asked.points is not None):
        return None
    try:
        with RunStore(path, readonly=True) as db:
            meta = db.meta()
            planned, imported = db.planned(), db.imported()
            if not meta or _foreign(meta, model, seed, path) or planned + imported == 0:
                return None
            choice = choose_design(network, model, meta, asked)
            if (design_conflict(choice, meta, path)
                    or target_runs(runs, network, model, choice, planned, imported) > planned
                    or db.unfinished()):
                return None
            _check_versions(db, model.name, shown_path(path, network.root), simulator,
                            version, False)
            counts = db.status_counts()
    except (CampaignError, sqlite3.DatabaseError):
        return None  # let the writing path give the full diagnosis
    _warn_fallback(network, model, choice, meta, path)
    fewer = fewer_note(runs, network, model, choice, planned)
    return CampaignSummary(model.name, path, planned, planned, 0, 0, counts, {},
                           time.perf_counter() - start, "none", 0, seed, 0,
                           meta.get("design_kind") or choice.label,
                           notes=(fewer,) if fewer else ())


def _warn_fallback(network: Network, model: Model, choice: DesignChoice,
                   meta: dict[str, str], path: Path) -> None:
    note = fallback_note(network, model, choice, meta, shown_path(path, network.root))
    if note:
        warnings.warn(note, CampaignWarning, stacklevel=3)


def _stale_without_results(path: Path, network: Network, model: Model, seed: int) -> bool:
    """Whether ``path`` is a store of another spec or seed of the model that holds no
    ``ok`` run, hence nothing worth keeping (a simulator that failed everywhere, then
    fixed in the spec): the campaign then starts it afresh, with a
    :class:`~calnet.errors.CampaignWarning` naming what changed, instead of asking for
    ``--fresh``."""
    if not path.is_file():
        return False
    try:
        with RunStore(path, readonly=True) as db:
            meta, counts = db.meta(), db.status_counts()
    except sqlite3.DatabaseError:
        return False  # not a store: the writing path says so
    if not meta or meta.get("model") != model.name or counts.get("ok", 0):
        return False
    difference = _difference(meta, model, seed)
    if difference is None:
        return False
    warnings.warn(f"the store '{shown_path(path, network.root)}' of '{model.name}' held no "
                  f"ok run and was made from another spec ({difference[1]}); it is started "
                  "afresh", CampaignWarning, stacklevel=3)
    return True


def _check_versions(db: RunStore, model: str, shown: str, simulator: str, version: str,
                    more_to_run: bool) -> None:
    """Refuse to mix simulator versions in one design; warn when a finished store is old.

    ``shown`` names the store in the message (:func:`calnet.files.shown_path`), so that
    the warning, which ``calnet run`` keeps in metrics.json, does not depend on where the
    spec folder is."""
    stored = db.versions()
    other = {v: n for v, n in stored.items() if v and version and v != version}
    if not other:
        unknown = {v: n for v, n in stored.items() if v != version and not (v and version)}
        if unknown:  # one side states no version: nothing says whether the runs differ
            made = ", ".join(f"{n} runs with {simulator} {v}" if v else
                             f"{n} runs with {simulator} stating no version"
                             for v, n in sorted(unknown.items()))
            installed = f"is {version}" if version else "states no version"
            warnings.warn(f"the campaign store of '{model}' ({shown}) holds {made}; the "
                          f"installed {simulator} {installed}, so whether its results "
                          "changed is not known: if they did, re-simulate with --fresh",
                          CampaignWarning, stacklevel=3)
        return
    made = ", ".join(f"{n} runs with {simulator} {v}" for v, n in sorted(other.items()))
    msg = (f"the campaign store of '{model}' ({shown}) holds {made}; the installed "
           f"{simulator} is {version}")
    if more_to_run:
        raise CampaignError(msg + "; finishing it would mix two versions in one design. "
                            "Re-simulate with --fresh (or a new --store), or install the "
                            "version that made it")
    warnings.warn(msg + "; its runs are used as they are (re-simulate with --fresh to use "
                  "the installed version)", CampaignWarning, stacklevel=3)


def remove_store(path: Path) -> None:
    """Delete a store and its WAL files."""
    for suffix in ("", "-wal", "-shm"):
        try:
            Path(f"{path}{suffix}").unlink(missing_ok=True)
        except OSError as err:
            raise CampaignError(f"cannot delete the store '{path}' for --fresh: "
                                f"{why(err)}") from None


def _model(network: Network, name: str) -> Model:
    try:
        return network.model(name)
    except KeyError:
        raise UnknownModel(f"no model named '{name}'; choose one of "
                            f"{[m.name for m in network.models]}") from None


def _claim(db: RunStore, network: Network, model: Model, seed: int, simulator: str,
           version: str) -> None:
    """Check that ``db`` belongs to this model and seed, or stamp a new store."""
    fp = model_fingerprint(model)
    meta = db.meta()
    if meta:
        problem = _foreign(meta, model, seed, db.path)
        if problem:
            raise CampaignError(problem)
    else:
        db.set_meta({"schema": "1", "model": model.name, "model_hash": fingerprint_hash(fp),
                     "model_spec": json.dumps(fp), "seed": str(seed),
                     "created_at": time.strftime("%Y-%m-%dT%H:%M:%S%z")})
    db.set_meta({"calnet_version": calnet.__version__, "simulator": simulator,
                 "simulator_version": version, "spec": network.source,
                 "spec_sha256": _file_hash(network.source)})


def _difference(meta: dict[str, str], model: Model,
                seed: int) -> tuple[str, str] | None:
    """How the model spec and seed that made a store (its ``meta``) differ from
    ``model`` and ``seed``: ``("spec", what changed)`` or ``("seed", "seed A -> B")``
    (the spec first); None when they do not."""
    fp = model_fingerprint(model)
    if meta.get("model_hash") != fingerprint_hash(fp):
        return "spec", describe_change(json.loads(meta.get("model_spec", "{}")), fp)
    if str(meta.get("seed")) != str(seed):
        return "seed", f"seed {meta.get('seed')} -> {seed}"
    return None


def _foreign(meta: dict[str, str], model: Model, seed: int, path: Path) -> str | None:
    """Why a store with metadata ``meta`` is not this model's with this seed (None: it is)."""
    difference = _difference(meta, model, seed)
    if difference is None:
        return None
    kind, change = difference
    if kind == "spec":
        return (f"the store '{path}' was made from a different '{model.name}' spec "
                f"({change}); simulate again with --fresh: {_WAYS_OUT}; or keep its runs: "
                f"export them (`calnet campaign SPEC --model {model.name} --export-only "
                f"--export runs.csv`), then import them into a new --store (`calnet campaign "
                f"SPEC --model {model.name} --store NEW.sqlite --import runs.csv`), where "
                "the new spec's campaign goes on from them")
    return (f"the store '{path}' was made with seed {meta.get('seed')}, not {seed}; "
            f"to keep it, set settings.seed back to {meta.get('seed')} (calnet campaign: "
            f"--seed {meta.get('seed')}); for the new seed, simulate again with --fresh: "
            f"{_WAYS_OUT}")


# the fixes of a store of another spec or seed, for calnet campaign and calnet run
_WAYS_OUT = ("`calnet campaign SPEC --fresh` simulates the stores beside the spec again, "
             "`calnet run SPEC --fresh --out OUT` those in OUT/campaigns (which later runs "
             "with that --out use); or give calnet campaign a new --store")


def _file_hash(path: str) -> str:
    """sha256 of the spec file ("" for a network built in Python)."""
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest() if path else ""
    except OSError:
        return ""


def _worker_died(index: int, err: Any) -> RunRecord:
    if isinstance(err, WorkerDied):
        return RunRecord(index, "failed", {}, str(err), {}, math.nan)
    return RunRecord(index, "failed", {}, f"the worker running it died ({type(err).__name__}: "
                     f"{err}); set a timeout to run each simulation in its own process",
                     {}, math.nan)
