"""``calnet run``: every stage in order, from the spec to the report.

campaign (the stores beside the spec, or in ``out/campaigns``: :func:`campaign_stores`)
-> surrogates -> calibration -> prediction -> validation, with the sensitivity (Sobol
indices, process maps) beside it -> report (HTML, metrics.json, posteriors, figures).
A network without data sets is emulated only: nothing is calibrated or validated, and the
report shows the outputs of ``settings.predict`` predicted through the chain.
"""

from __future__ import annotations

import os
import threading
import time
import warnings
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import ExitStack, contextmanager, suppress
from dataclasses import replace
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.progress import BarColumn, Progress, TaskID, TextColumn, TimeElapsedColumn

from calnet.calibration.calibrate_network import NetworkPosterior
from calnet.calibration.diagnostics import import_arviz
from calnet.calibration.persist import save_posterior
from calnet.calibration.sampling import cache_info
from calnet.calibration.summary import calibration_result
from calnet.campaign import default_store, load_runs, run_campaign
from calnet.campaign.failures import common_failures, commonest_failure, store_failure_note
from calnet.emulation import output_slices
from calnet.errors import (
    CalibrationWarning,
    CalnetError,
    CampaignError,
    CampaignWarning,
    UsageError,
)
from calnet.explore import explore
from calnet.files import mark_complete, mark_incomplete
from calnet.interrupts import latch
from calnet.parallel import map_threads, one_blas_thread
from calnet.predict import predict_data
from calnet.report.build import write_outputs
from calnet.report.metrics import run_environment, write_run_info
from calnet.report.reference import read_reference
from calnet.results import CalibrationResult, CampaignSummary, RunResults
from calnet.spec import Network, load_spec, read_all
from calnet.spec.models import SamplerSettings
from calnet.surrogates.fit_network import (
    Surrogates,
    check_cross_validation,
    cross_validate_surrogates,
    fit_surrogates,
)
from calnet.surrogates.plots import parity_plots
from calnet.validation import baseline_check, baselines, compare_variants, validate_dataset

STAGES = ("campaign", "surrogates", "calibration", "prediction", "validation", "report")
"""The stages of ``calnet run``, in order; ``validation`` also computes the sensitivity."""


def _quick_sampler(s: SamplerSettings) -> SamplerSettings:
    return s.model_copy(update={"warmup": min(s.warmup, 300), "draws": min(s.draws, 300),
                                "thin": 1})


#: a finished run's files that describe it as a whole, removed when another run starts in
#: its folder
PREVIOUS_RESULTS = ("report.html", "metrics.json", "run_info.json", "verify.json")


def run_pipeline(spec: str | Path, *, out: Path, fresh: bool = False, quick: bool = False,
                 console: Console | None = None, loo_max: int | None = None,
                 seed: int | None = None) -> dict:
    """Run every stage on ``spec`` and write ``out/report.html``, ``out/metrics.json`` and
    ``out/run_info.json``. An earlier run's in ``out`` (and its ``verify.json``) are
    removed when the run starts, so that a run stopped early leaves none to be mistaken
    for its own.

    ``metrics.json`` holds the results only, so that two runs with the same seed write
    the same bytes; ``run_info.json`` holds how this run went (stage timings, compile
    and sampling times, paths, host, versions).

    Parameters
    ----------
    fresh : bool
        Delete the stores in ``out/campaigns`` and simulate every model again into them,
        leaving the stores beside the spec as they are (an ``out`` whose ``campaigns``
        folder is the spec's own raises :class:`~calnet.errors.UsageError`). Without it,
        the stores in ``out/campaigns`` are used (resumed) when it holds one of this
        network's, else the stores beside the spec (:func:`campaign_stores`).
    quick : bool
        Fewer draws, restarts and folds: a fast look (used by the tests).
    console : rich.console.Console, optional
        Where the progress bar and the closing line go. When it is not a terminal,
        progress goes to stderr as plain lines instead: each stage's start, its notes
        (the model or data set at work, sampling every 10 s, leave-one-out refits...)
        and its end with the seconds it took.
    loo_max : int, optional
        Most points per data set whose leave-one-out is re-calibrated exactly where PSIS
        is unreliable (Pareto k > 0.7; default 15, 12 with ``quick``).
    seed : int, optional
        Seed of the stages after the campaign (the surrogates' restarts and folds, the
        chains, the predictions; default ``settings.seed``, recorded in run_info.json).
        The campaign designs keep ``settings.seed``, so the stores stay valid.

    Returns
    -------
    dict
        The metrics written to ``metrics.json``.
    """
    console = console or Console()
    t_start = time.perf_counter()
    started = datetime.now(UTC)
    caught: list = []
    try:  # the spec's and the data's warnings, in the report too
        with warnings.catch_warnings(record=True) as caught:
            network = load_spec(spec)
            out = Path(out)
            if fresh:
                _check_fresh(network, out)
            for sub in ("figures", "posterior", "surrogates"):
                (out / sub).mkdir(parents=True, exist_ok=True)
            # an earlier run's results in this folder: this run writes its own at the
            # end, and one stopped before then must not leave the old ones to be read as
            # its own (calnet verify's check of the earlier posterior included)
            for name in PREVIOUS_RESULTS:
                (out / name).unlink(missing_ok=True)
            ctx = _Context(network, out, quick, fresh, loo_max if loo_max is not None
                           else (12 if quick else 15))
            if seed is not None:
                ctx.seed = int(seed)
    finally:
        early = _recorded(caught)
    ctx.spec_warnings = [_without_location(text, network) for text in early]
    timings: dict[str, float] = {}
    ctx.run_info["timings_s"] = timings
    ctx.run_info["seed"] = ctx.seed
    # ArviZ imports matplotlib.pyplot, whose import records warnings (catch_warnings with
    # record=True sets process-wide state): imported first in a stage's thread while the
    # main thread enters and leaves its own warning contexts, it can leave the main
    # thread's warnings recorded into a list that nobody reads. Import it before any stage
    # starts a thread.
    import_arviz()
    with _display(console) as show, latch() as interrupted, ctx.held:

        def note(text: str) -> None:
            interrupted()
            show.note(text)

        ctx.say = show.note  # on the way out of an interrupted run: no interrupt check

        for i, stage in enumerate(STAGES):
            interrupted()
            mark_incomplete(out, stage)
            show.start(stage, i)
            t0 = time.perf_counter()
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always", CalibrationWarning)
                getattr(ctx, stage)(note)
            ctx.warnings += _recorded(caught)
            timings[stage] = round(time.perf_counter() - t0, 2)
            timings["total"] = round(time.perf_counter() - t_start, 2)  # so far
            show.done(stage, timings[stage])
    _write_run_info(ctx, spec, started)
    mark_complete(out)
    console.print(f"report: {out / 'report.html'}  metrics: {out / 'metrics.json'}  "
                  f"total wall time {timings['total']:.1f} s", soft_wrap=True)
    return ctx.results.to_metrics()


def campaign_stores(network: Network, models: list[str], out: Path, *,
                    fresh: bool = False) -> dict[str, Path]:
    """Where ``calnet run`` keeps the campaign stores of ``models``: in ``out/campaigns``
    with ``fresh`` (its stores are deleted and simulated again), or when it holds a store
    of one of them (a run made with ``fresh`` and this ``out``); else beside the spec
    (:func:`calnet.campaign.default_store`, the shipped stores)."""
    own = {name: out / "campaigns" / f"{name}.sqlite" for name in models}
    if fresh or any(path.is_file() for path in own.values()):
        return own
    return {name: default_store(network, name) for name in models}


def _check_fresh(network: Network, out: Path) -> None:
    """Raise :class:`~calnet.errors.UsageError` where ``fresh`` would delete the stores
    beside the spec: ``out/campaigns`` is the spec's own campaigns folder (``out`` is the
    spec's folder)."""
    names = [n for n in network.order if network.needed_outputs(n)]
    fresh = campaign_stores(network, names, out, fresh=True)
    if any(path.resolve() == default_store(network, name).resolve()
           for name, path in fresh.items()):
        raise UsageError(
            f"--fresh simulates every model again into OUT/campaigns, but with --out "
            f"'{out}' that is the campaigns folder beside the spec "
            f"('{default_store(network, names[0]).parent}'), whose stores it would delete; "
            "give another --out (e.g. --out out), or drop --fresh to use and resume "
            "those stores")


def surrogate_stage(network: Network, *, folder: Path, figures: Path, **fit) -> tuple[
        Surrogates, dict[str, Path]]:
    """Fit the network's surrogates (:func:`calnet.surrogates.fit_network.fit_surrogates`
    with the keywords ``fit``), write them to ``folder`` and their parity plots to
    ``figures``: ``(surrogates, {model.output: plot})``, as ``calnet surrogates`` does
    (``calnet run`` cross-validates beside the calibration: :meth:`_Context.surrogates`)."""
    sur = fit_surrogates(network, **fit)
    sur.save(folder)
    return sur, parity_plots(network, sur, figures)


def record_calibration(network: Network, post: NetworkPosterior, *, folder: Path,
                       sampler: SamplerSettings | None = None) -> CalibrationResult:
    """Write ``post`` to ``folder`` (the stages' netCDFs and what ``calnet predict`` needs)
    and return its :class:`calnet.results.CalibrationResult`. ``calnet run`` and ``calnet
    calibrate`` both call it."""
    save_posterior(post, folder, network)
    return calibration_result(network, post, sampler=sampler)


def _write_run_info(ctx: _Context, spec: str | Path, started: datetime) -> None:
    """``out/run_info.json``: what changes from run to run, kept out of metrics.json."""
    stages = {"+".join(s.models): {"compile_s": s.idata.posterior.attrs.get("compile_time"),
                                   "sampling_s": s.idata.posterior.attrs.get("sampling_time")}
              for s in ctx.post.stages}
    info = {"spec": str(Path(spec).resolve()), "out": str(ctx.out.resolve()),
            "started": started.isoformat(timespec="seconds"),
            "finished": datetime.now(UTC).isoformat(timespec="seconds"),
            **ctx.run_info, "calibration_stages": stages,
            "campaign_stores": {k: str(v.resolve()) for k, v in ctx.stores.items()},
            "compiled_sampler_cache": cache_info(), **run_environment()}
    write_run_info(ctx.out / "run_info.json", info)


@contextmanager
def _display(console: Console) -> Iterator[_Bar | _Lines]:
    """A Rich bar over the stages on a terminal, plain lines on stderr anywhere else."""
    if not console.is_terminal:
        yield _Lines(Console(stderr=True))
        return
    columns = (TextColumn("[bold]{task.description}"), BarColumn(),
               TextColumn("{task.fields[note]}"), TimeElapsedColumn())
    with Progress(*columns, console=console, transient=False) as bar:
        yield _Bar(bar, bar.add_task("calnet run", total=len(STAGES), note=""))


class _Bar:
    """Stage progress on one Rich bar; a stage's notes replace each other beside it."""

    def __init__(self, bar: Progress, task: TaskID):
        self.bar, self.task = bar, task

    def start(self, stage: str, index: int) -> None:
        self.bar.update(self.task, description=stage, note="")

    def note(self, text: str) -> None:
        self.bar.update(self.task, note=text)

    def done(self, stage: str, seconds: float) -> None:
        self.bar.advance(self.task)


class _Lines:
    """Stage progress as plain lines (a pipe, a log file): start, notes, end."""

    def __init__(self, console: Console):
        self.console, self.stage = console, ""

    def _print(self, text: str) -> None:
        self.console.print(text, markup=False, highlight=False, soft_wrap=True)

    def start(self, stage: str, index: int) -> None:
        self.stage = stage
        self._print(f"{stage} ({index + 1}/{len(STAGES)}) ...")

    def note(self, text: str) -> None:
        self._print(f"{self.stage}: {text}")

    def done(self, stage: str, seconds: float) -> None:
        self._print(f"{stage}: done in {seconds:.1f} s")


def _recorded(caught) -> list[str]:
    """The texts of recorded warnings (for the report and metrics.json), each warned
    again so that the command line shows them."""
    for w in caught:
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return [str(w.message) for w in caught]


def _without_location(text: str, network: Network) -> str:
    """``text`` with the spec's folder left out of its paths, so that metrics.json is the
    same wherever the spec is (``/a/b/data/x.csv`` -> ``data/x.csv``)."""
    if network.source:
        text = text.replace(network.source, Path(network.source).name)
    root = str(Path(network.root))
    return text if root == "." else text.replace(root + os.sep, "")


class _Context:
    """What the stages pass to each other (mutable only here, at the edge)."""

    def __init__(self, network: Network, out: Path, quick: bool, fresh: bool, loo_max: int):
        self.network, self.out, self.quick, self.fresh, self.loo_max = (
            network, out, quick, fresh, loo_max)
        self.seed = network.settings.seed
        self.run_info: dict = {}  # what varies between runs with the same seed
        self.warnings: list[str] = []
        self.spec_warnings: list[str] = []  # given while the spec and the data were read
        self.data = read_all(network)
        self.stores: dict[str, Path] = {}
        self.figures: dict[str, Path] = {}
        self.campaigns: dict[str, CampaignSummary] = {}
        self.emulated: dict = {}  # settings.predict outputs, from the prediction stage
        self.variants: dict = {}  # settings.compare: {variant: (network, posterior)}
        self.pending = None  # Future of the variants, calibrated in a thread
        self.cv_pending = None  # Future of the surrogates' cross-validation
        self.say = None  # progress lines that do not check for Ctrl-C (run_pipeline's)
        self.held = ExitStack()  # what the calibration sets for the rest of the run
        self.validated: dict = {}  # data set -> calnet.results.DatasetValidation
        self.comparison = None  # calnet.results.Comparison, with settings.compare
        self.explored: dict = {}  # data set -> calnet.explore.Exploration
        self.results: RunResults | None = None  # every stage's result, for the report
        self.sampler = (_quick_sampler(network.settings.sampler) if quick
                        else network.settings.sampler)

    # ------------------------------------------------------------ stages
    def campaign(self, note) -> None:
        names = [n for n in self.network.order if self.network.needed_outputs(n)]
        for name, store in campaign_stores(self.network, names, self.out,
                                           fresh=self.fresh).items():
            note(name)
            store.parent.mkdir(parents=True, exist_ok=True)
            # resumes: finished runs are skipped, so a complete shipped store costs nothing
            summary = run_campaign(self.network, name, store=store, progress=note,
                                   fresh=self.fresh)
            for text in summary.notes:  # where the runs' logs are, a worker that died
                warnings.warn(f"{name}: {text}", CampaignWarning, stacklevel=2)
            runs = load_runs(self.network, name, store=store)
            failed = store_failure_note(store, self.network.model(name))
            if not runs.status_counts.get("ok"):  # nothing to fit; the models after it
                # would get no chain design and be simulated for nothing
                why = "; ".join(common_failures(store)) or "see its store"
                raise CampaignError(
                    f"no run of '{name}' finished ok ({why}); the models after it were not "
                    f"simulated. Fix the simulator, then run 'calnet campaign SPEC --model "
                    f"{name} --retry-failed' and this command again")
            if failed:  # recorded with the stage, shown at the end of the run
                commonest = commonest_failure(store)
                warnings.warn(failed + (f"; the commonest outcome: {commonest}"
                                        if commonest else ""), CampaignWarning, stacklevel=2)
            self.stores[name] = Path(store)
            self.campaigns[name] = CampaignSummary(runs.n_total, runs.n_excluded,
                                                   dict(runs.status_counts))

    def surrogates(self, note) -> None:
        """The GPs the calibration needs; their cross-validation, which only the report
        needs and which costs about twice the fits, runs on in a thread beside the
        calibration's set-up and its sampler's compilation (which keep one core busy)
        and is collected at the end of the calibration stage. BLAS stays on one thread
        to the end of the run (:func:`map_threads`)."""
        cv = {"stores": self.stores, "seed": self.seed,
              "cv_folds": 5 if self.quick else None}
        check_cross_validation(self.network, stores=self.stores, cv_folds=cv["cv_folds"])
        self.sur = fit_surrogates(self.network, cv=False, progress=note,
                                  restarts=2 if self.quick else None, **cv)
        self.sur.save(self.out / "surrogates")
        stop = threading.Event()

        def before_fold():
            if stop.is_set():
                raise KeyboardInterrupt  # the run is on its way out

        self.held.enter_context(one_blas_thread())
        self.held.callback(self._drain_cv, stop)
        pool = ThreadPoolExecutor(max_workers=1)
        self.cv_pending = pool.submit(cross_validate_surrogates, self.network, self.sur,
                                      before_fold=before_fold, **cv)
        pool.shutdown(wait=False)
        note("cross-validation goes on beside the calibration")

    def _drain_cv(self, stop: threading.Event) -> None:
        """On the way out of a run that stops before the cross-validation is collected:
        no further fold starts; the one in flight ends."""
        if self.cv_pending is not None:
            stop.set()
            with suppress(BaseException):
                self.cv_pending.result()
            self.cv_pending = None

    def collect_cv(self) -> None:
        """The surrogates with their cross-validation (waits for it), saved again with
        it, and its parity plots."""
        if self.cv_pending is None:
            return
        try:
            self.sur = self.cv_pending.result()
        finally:
            self.cv_pending = None
        self.sur.save(self.out / "surrogates")
        parity = parity_plots(self.network, self.sur, self.out / "figures")
        self.figures.update({f"cv {key}": path for key, path in parity.items()})

    def calibration(self, note) -> None:
        from calnet.calibration.calibrate_network import calibrate
        from calnet.validation import (
            calibrate_variants,
            changes_nothing,
            same_as_spec,
            secondary_sampler,
        )

        train = {k: v.train for k, v in self.data.items()}
        variants = self.network.settings.compare if train else ()
        same = same_as_spec(self.network, variants)
        if same:
            warnings.warn("settings.compare: " + changes_nothing(
                same, "neither calibrated nor compared",
                " (its data sets' discrepancies already are so)"),
                CalibrationWarning, stacklevel=1)
            variants = tuple(v for v in variants if v not in same)
        # the variants of settings.compare are calibrated beside the spec's model, in a
        # thread that starts once the spec's sampler is compiled: their compilation then
        # runs beside its chains, not beside its compilation (two compilations at once
        # each took twice as long on 2 cores: benchmarks/README.md). The validation
        # stage, which compares them, collects them: until then they run beside the
        # rest of this stage and the prediction. BLAS stays on one thread to the end of
        # the run (self.held, which run_pipeline closes after the last stage).
        compiled, failed = threading.Event(), threading.Event()

        def after_compiled(*args, **kwargs):
            compiled.wait()
            return {} if failed.is_set() else calibrate_variants(*args, **kwargs)

        if variants:
            self.held.enter_context(one_blas_thread())
            self.held.callback(self._drain, variants, self.say or note)
            self.held.callback(failed.set)  # on the way out: what has not started, won't
            note("calibrating " + ", ".join(variants) + " beside the spec's model")
            pool = ThreadPoolExecutor(max_workers=1)
            self.pending = pool.submit(after_compiled, self.network, self.sur, train,
                                       variants, sampler=secondary_sampler(self.sampler),
                                       seed=self.seed)
            pool.shutdown(wait=False)
        with one_blas_thread():
            try:
                self.post = calibrate(self.network, self.sur, data=train, seed=self.seed,
                                      sampler=self.sampler, progress=note,
                                      compiled=compiled.set)
            except BaseException:
                failed.set()  # the variants are not calibrated: the run stops here
                raise
            finally:
                compiled.set()
        for text in self.post.info:  # segmented mode's set-up: not a problem
            note(text)
        self.collect_cv()
        self.calibrated = record_calibration(self.network, self.post,
                                             folder=self.out / "posterior",
                                             sampler=self.sampler)

    def _drain(self, variants, note) -> None:
        """On the way out of a run that stops before the validation (Ctrl-C, an error):
        a variant's chains in flight cannot be interrupted, and the process cannot end
        before them, so say so and wait here for them."""
        if self.pending is not None and not self.pending.done():
            note("stopping once the calibration of " + ", ".join(variants) + " in "
                 "flight ends (its chains cannot be interrupted)")
            with suppress(BaseException):
                self.pending.result()

    def collect_variants(self) -> dict:
        """The variants calibrated beside the spec's model (waits for them)."""
        if self.pending is not None:
            try:
                self.variants = self.pending.result()
            finally:
                self.pending = None
        return self.variants

    def prediction(self, note) -> None:
        def one(name):
            note(name)
            return predict_data(self.network, self.sur, self.post, self.data[name],
                                seed=self.seed)

        order = list(self.data)  # side by side, one thread per core
        self.predictions = dict(zip(order, map_threads(one, order), strict=True))
        self.emulated = {}
        for key in self.network.settings.predict:
            note(key)
            self.emulated[key] = output_slices(self.network, self.sur, self.post, key,
                                               seed=self.seed)

    def validation(self, note) -> None:
        """Leave-one-out, checks and the comparison of variants; beside them, in a second
        thread, the naive baselines' GP fits and then the sensitivity (Sobol indices and
        process maps), which need only the posterior: the leave-one-out and the Sobol
        programs compile on one core each. Everything ends inside this stage, so that
        the warnings of both threads are recorded with it."""
        def beside():
            naive = {name: baselines(self.network, d.train, d.test, seed=self.seed)
                     for name, d in self.data.items() if d.is_test.any()}
            explored = explore(self.network, self.sur, self.post, self.data,
                               seed=self.seed, quick=self.quick, progress=note)
            return naive, explored

        with one_blas_thread(), ThreadPoolExecutor(max_workers=1) as pool:
            other = pool.submit(beside)
            loo = {}
            for name, d in self.data.items():
                note(f"leave-one-out {name}")
                loo[name] = validate_dataset(
                    self.network, self.sur, self.post, d, self.predictions[name],
                    sampler=self.sampler, seed=self.seed, loo_max=self.loo_max,
                    progress=note)
            if self.collect_variants():
                note("comparison with " + ", ".join(self.variants))
                self.comparison = compare_variants(
                    self.network, self.sur, self.post, tuple(self.variants),
                    sampler=self.sampler, seed=self.seed, calibrated=self.variants,
                    spec_pointwise={name: np.asarray(v.loo["elpd_pointwise"])
                                    for name, v in loo.items()
                                    if "elpd_pointwise" in v.loo},
                    spec_refit={name: v.loo.get("refit", []) for name, v in loo.items()})
            naive, self.explored = other.result()
        self.validated = {name: replace(v, baselines_test=naive.get(name))
                          for name, v in loo.items()}
        for name, v in self.validated.items():
            said = baseline_check(name, v.test, v.baselines_test)
            if said:
                warnings.warn(said, CalibrationWarning, stacklevel=1)

    def report(self, note) -> None:
        note("figures, report.html, metrics.json")
        self.results = RunResults(
            network=self.network.name, quick=self.quick, campaigns=self.campaigns,
            surrogates=self.sur, calibration=self.calibrated, predictions=self.predictions,
            validation=self.validated, sensitivity=self.explored,
            predicted_outputs=self.emulated, comparison=self.comparison,
            # the spec's and data's warnings first, in the order given (the report's box
            # shows the first few), then the stages' in an order that does not depend on
            # the threads' timing
            warnings=tuple(dict.fromkeys(self.spec_warnings)) + tuple(
                sorted(set(self.warnings) - set(self.spec_warnings))),
            reference=read_reference(self.network.path(".")))
        write_outputs(self, self.results)


def require(condition: bool, message: str) -> None:
    if not condition:
        raise CalnetError(message)


__all__ = ["STAGES", "run_pipeline", "campaign_stores", "surrogate_stage",
           "record_calibration", "np"]
