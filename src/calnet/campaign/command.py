"""``calnet campaign``: the Typer command over :func:`calnet.campaign.run_campaign`.

Registered in :mod:`calnet.cli` by :func:`calnet.cli.campaign_command`, which checks its paths.
Import-light: the spec, the driver, Dask and UM-Bridge load when the command runs.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Annotated, Any, Literal

import typer

from calnet.campaign.interrupt import sigterm_exits
from calnet.errors import CampaignError, CampaignWarning, UsageError


@sigterm_exits
def campaign(
    spec: Annotated[Path, typer.Argument(
        metavar="SPEC", show_default=False, help="network YAML, or a folder with network.yaml")],
    model: Annotated[str | None, typer.Option(
        "--model", "-m", metavar="NAME", help="model to simulate (default: every model, "
        "parents first)")] = None,
    runs: Annotated[int | None, typer.Option(
        metavar="N", min=1, help="runs in the design (default: the spec's); more than the "
        "store has augments it, fewer keeps all it has")] = None,
    workers: Annotated[int | None, typer.Option(
        metavar="K", min=1, help="parallel runs on this machine")] = None,
    scheduler: Annotated[str | None, typer.Option(
        metavar="ADDR", help="a running Dask scheduler, e.g. tcp://host:8786")] = None,
    store: Annotated[Path | None, typer.Option(
        metavar="FILE", help="SQLite store (default: campaigns/MODEL.sqlite beside the "
        "spec)")] = None,
    executor: Annotated[Literal["auto", "in-process", "processes", "dask"], typer.Option(
        metavar="KIND", help="where runs execute: auto, in-process, processes or dask")
    ] = "auto",
    seed: Annotated[int | None, typer.Option(
        metavar="SEED", min=0, help="design seed (default: the spec's)")] = None,
    fresh: Annotated[bool, typer.Option(
        "--fresh", help="delete the store and simulate everything again")] = False,
    retry_failed: Annotated[bool, typer.Option(
        "--retry-failed", help="run again the simulated runs that did not finish ok "
                               "(imported runs keep their status)")] = False,
    import_: Annotated[Path | None, typer.Option(
        "--import", metavar="FILE", help="import finished runs from a .csv or .parquet "
        "table into the store (no simulation); needs --model")] = None,
    export: Annotated[Path | None, typer.Option(
        metavar="FILE", help="also write the runs to a .csv or .parquet file")] = None,
    export_only: Annotated[bool, typer.Option(
        "--export-only", help="write the store's runs to --export FILE as they are, "
                              "simulating nothing")] = False,
    no_progress: Annotated[bool, typer.Option(
        "--no-progress", help="no progress bar (or lines, when not a terminal)")] = False,
) -> None:
    """Simulate each model's design into a store; run again to resume.

    Finished runs are kept, runs that were in flight when a campaign stopped are run again,
    so an interrupted campaign (Ctrl-C, a killed job) resumes where it stopped. With
    --workers K, K local processes (or a Dask LocalCluster with --executor dask) share
    the runs. With --import FILE, the finished runs of a table go into the store instead;
    with --export-only, the store's runs go to the --export file, finished or not.
    Ctrl-C exits with 130, SIGTERM with 143, the finished runs kept.
    """
    from rich.console import Console

    from calnet.campaign.campaign import import_runs, run_campaign
    from calnet.campaign.executors import executor_kind
    from calnet.campaign.failures import common_failures, store_failure_note
    from calnet.campaign.table import check_export, export_runs
    from calnet.spec import load_spec

    network = load_spec(spec)
    names = [model] if model else list(network.order)
    try:  # options that cannot work are usage errors, before any store is read
        if export:
            check_export(export)
        if not export_only:  # which refuses the options it does not take itself
            executor_kind(executor, workers=workers, scheduler=scheduler)
    except CampaignError as err:
        raise UsageError(str(err)) from None
    if export_only:
        _export_only(network, names, store, export, Console(highlight=False),
                     {"--runs": runs, "--workers": workers, "--scheduler": scheduler,
                      "--fresh": fresh, "--retry-failed": retry_failed, "--import": import_},
                     seed)
        return
    if import_ and (fresh or retry_failed or runs):
        raise UsageError("--import only adds runs to a store; import first, then run "
                         "`calnet campaign` again for --runs/--retry-failed (or give a new "
                         "--store for an empty one)")
    if len(names) > 1 and (import_ or store or export):
        raise UsageError(("--import reads one model's runs" if import_ else
                          "--store and --export name one file") + "; give --model NAME too")
    console = Console(highlight=False)
    useless, skipped, why = [], [], {}
    for name in names:
        if any(a in useless for a in network.ancestors(name)):
            skipped.append(name)  # no chain design, and nothing to feed its inputs
            continue
        if import_:
            summary = import_runs(network, name, import_, store=store, seed=seed)
        else:
            summary = run_campaign(network, name, runs=runs, workers=workers,
                                   scheduler=scheduler, store=store, executor=executor,
                                   seed=seed, progress=not no_progress, fresh=fresh,
                                   retry_failed=retry_failed)
        print_summary(summary, console)
        if export:
            console.print(f"exported to {export_runs(summary.store_path, export)}",
                          soft_wrap=not console.is_terminal)
        if (summary.planned or summary.imported) and not summary.n_ok:
            useless.append(name)
            why[name] = "; ".join(common_failures(summary.store_path))
        elif summary.planned or summary.imported:  # shown at the end, with the warnings
            note = store_failure_note(summary.store_path, network.model(name))
            if note:
                warnings.warn(note, CampaignWarning, stacklevel=2)
    if useless:
        after = (f"; {', '.join(skipped)}, downstream of {'it' if len(useless) == 1 else 'them'},"
                 " not simulated" if skipped else "")
        said = "; ".join(f"{name}: {why[name]}" for name in useless if why[name])
        raise CampaignError(f"no run of {', '.join(useless)} finished ok ({said}){after}; "
                            "fix the simulator, then run again "
                            "with --retry-failed (a store that holds no ok run starts afresh "
                            "by itself when the model's spec has changed)")


def _export_only(network: Any, names: list[str], store: Path | None, export: Path | None,
                 console: Any, given: dict[str, Any], seed: int | None) -> None:
    """``--export-only``: one model's store, as it is, to ``export``; a store of another
    model is refused, one made from another spec of the model or another seed is
    exported with a warning that says so."""
    from calnet.campaign.campaign import _difference, _model
    from calnet.campaign.store import RunStore, default_store
    from calnet.campaign.table import write_export

    if not export:
        raise UsageError("--export-only writes a store to a file: give --export FILE")
    used = [flag for flag, value in given.items() if value]
    if used:
        raise UsageError(f"--export-only simulates and imports nothing: drop "
                         f"{' and '.join(used)}")
    if len(names) > 1:
        raise UsageError("--export-only exports one model's store: give --model NAME")
    model = _model(network, names[0])
    path = store or default_store(network, names[0])
    if not path.is_file():
        spec = network.source or network.root
        raise CampaignError(f"no campaign store for '{names[0]}' at '{path}'"
                            + ("" if store else f"; run `calnet campaign {spec} --model "
                                                f"{names[0]}` first"))
    with RunStore(path, readonly=True) as db:
        meta = db.meta()
    if meta.get("model") and meta["model"] != model.name:
        raise CampaignError(f"the store '{path}' holds runs of model '{meta['model']}', not "
                            f"of '{model.name}'; give --model {meta['model']} (or that "
                            "model's store)")
    want = network.settings.seed if seed is None else seed
    difference = _difference(meta, model, want) if meta else None
    if difference is not None:
        kind, change = difference
        warnings.warn(f"the store '{path}' was made from "
                      + (f"a different '{model.name}' spec ({change})" if kind == "spec"
                         else f"seed {meta.get('seed')}, not {want}")
                      + "; it is exported as it is", CampaignWarning, stacklevel=2)
    written, counts = write_export(path, export)  # the counts of what it wrote
    console.print(f"[bold]{names[0]}[/]: {sum(counts.values())} runs in {path} ("
                  + ", ".join(f"{k} {n}" for k, n in sorted(counts.items()))
                  + f"), exported to {written}")


def print_summary(summary: Any, console: Any) -> None:
    """A few lines: counts per status, throughput, the first failures. Not on a
    terminal (a log file, a pipe) no line is wrapped, so that grep finds it whole."""
    soft = not getattr(console, "is_terminal", True)
    counts = ", ".join(f"{k} {n}" for k, n in sorted(summary.status_counts.items()))
    rate = summary.ran / summary.wall_time if summary.wall_time > 0 else 0.0
    if summary.imported:
        runs = "run" if summary.imported == 1 else "runs"
        console.print(f"[bold]{summary.model}[/]: imported {summary.imported} {runs}",
                      soft_wrap=soft)
    if summary.planned == 0:
        pass  # imported runs only: no design to report on
    elif summary.ran == 0 and summary.skipped == summary.planned:
        console.print(f"[bold]{summary.model}[/]: complete, all {summary.planned} runs "
                      f"finished (seed {summary.seed}); nothing to run", soft_wrap=soft)
    else:
        console.print(f"[bold]{summary.model}[/]: {summary.planned} runs planned, "
                      f"{summary.skipped} already finished, {summary.ran} run now "
                      f"({summary.rerun_in_flight} re-run after an interruption) in "
                      f"{summary.wall_time:.1f} s ({rate:.2f} runs/s, {summary.executor}, "
                      f"{summary.workers} worker(s), seed {summary.seed}"
                      + (f", {summary.design} design)" if summary.design else ")"),
                      soft_wrap=soft)
    console.print(f"  store {_shown(summary.store_path)}: {counts}", soft_wrap=soft)
    for index, message in sorted(summary.failures.items())[:5]:
        console.print(f"  [yellow]run {index}[/]: {message}", soft_wrap=True)
    more = max(summary.n_failed, len(summary.failures)) - min(len(summary.failures), 5)
    if more > 0:
        console.print(f"  ... {more} more not ok (see the store)", soft_wrap=soft)
    for note in summary.notes:
        console.print(f"  [yellow]note[/]: {note}", soft_wrap=True)


def _shown(path: Path) -> str:
    """``path`` relative to the working directory where it lies beneath it, else whole."""
    try:
        return str(Path(path).relative_to(Path.cwd()))
    except (ValueError, OSError):
        return str(path)
