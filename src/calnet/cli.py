"""The ``calnet`` command line: thin Typer commands over the stage verbs.

Every user error (:class:`calnet.errors.CalnetError`) is printed as one line, without a
traceback; spec errors and malformed option values (:class:`UsageError`) exit with code
2, as Typer's own usage errors do, other errors with code 1.
"""

from __future__ import annotations

import csv as csv_mod
import functools
import inspect
import json
import math
import os
import sys
import time
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Annotated, Any, Literal

import typer
from rich.console import Console
from rich.markup import escape
from rich.measure import Measurement
from rich.table import Table
from typer.core import TyperCommand, TyperGroup

from calnet import __version__
from calnet.calibration.devices import configure_host_devices, enable_compilation_cache
from calnet.errors import CalnetError, SpecError, UsageError
from calnet.files import make_folder, replacing
from calnet.interrupts import ending_allowed, latch


def _reflow(text: str | None) -> str | None:
    """Docstring paragraphs as single lines, so that help wraps them to the terminal."""
    if not text:
        return text
    paragraphs = inspect.cleandoc(text).split("\n\n")
    return "\n\n".join(" ".join(p.split()) for p in paragraphs)


class _ReadableHelp:
    """Help that reads well at 80 columns, on a terminal or in a pipe: a flag shows its
    names only (``--json``, not ``--json <bool>``), and docstring paragraphs wrap to the
    width instead of keeping the source's line breaks."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.help = _reflow(self.help)
        for param in self.params:
            _hide_flag_type(param)

    def get_help_option(self, ctx: Any) -> Any:
        option = super().get_help_option(ctx)
        if option is not None:
            _hide_flag_type(option)
        return option


def _hide_flag_type(param: Any) -> None:
    if getattr(param, "is_flag", False) and param.metavar is None:
        param.metavar = ""


class _Command(_ReadableHelp, TyperCommand):
    pass


class _Group(_ReadableHelp, TyperGroup):
    pass


class App(typer.Typer):
    """A Typer app whose commands have calnet's help layout (see :class:`_ReadableHelp`)."""

    def __init__(self, **kwargs: Any) -> None:
        kwargs.setdefault("cls", _Group)
        super().__init__(add_completion=False, pretty_exceptions_enable=False, **kwargs)

    def command(self, *args: Any, **kwargs: Any) -> Any:
        kwargs.setdefault("cls", _Command)
        return super().command(*args, **kwargs)


app = App(no_args_is_help=True,
          help="Bayesian calibration of networks of coupled simulation models.")


class _Console(Console):
    """A Rich console that prints a table at its full width where stdout is not a
    terminal (a pipe, a file) and ``COLUMNS`` is not set; Rich would cut it to 80
    columns there. ``COLUMNS``, when set, is the width on a terminal or off it."""

    def print(self, *objects: Any, **kwargs: Any) -> None:
        if self.is_terminal or self._environ.get("COLUMNS", "").isdigit() or not any(
                isinstance(o, Table) for o in objects):
            super().print(*objects, **kwargs)
            return
        options = self.options.update_width(1 << 16)
        natural = max(Measurement.get(self, options, o).maximum for o in objects)
        held = self._width
        self.width = max(natural, 1)
        try:
            super().print(*objects, **kwargs)
        finally:
            self._width = held


console = _Console(stderr=False, highlight=False, emoji=False)  # ":x:" in python:x:f is text
err_console = Console(stderr=True, highlight=False, emoji=False)

SpecArg = Annotated[Path, typer.Argument(
    metavar="SPEC", show_default=False, help="network YAML, or a folder with network.yaml")]


def _print_version(value: bool) -> None:
    if value:
        print(f"calnet {__version__}")
        raise typer.Exit()


@app.callback()
def _main(
    version: Annotated[bool, typer.Option(
        "--version", "-V", is_eager=True, callback=_print_version,
        help="print the version and exit")] = False,
) -> None:
    """Bayesian calibration of networks of coupled simulation models."""
    configure_host_devices(4)  # before jax starts: chains run in parallel (pmap)
    enable_compilation_cache()  # compiled samplers and predictors reused across runs


_FINISHED: list[Path] = []  # calnet run's folder once its run has finished


def user_errors(func: Callable[..., Any]) -> Callable[..., Any]:
    """Turn calnet errors into one-line messages with exit codes; show warnings briefly."""

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                with latch() as interrupted, ending_allowed():
                    result = func(*args, **kwargs)
                    interrupted()  # a Ctrl-C that Python dropped still ends in 130
            except SpecError as err:
                _show_warnings(caught)
                err_console.print(f"[bold red]error:[/] {escape(str(err))}", soft_wrap=True)
                for line in err.more:  # the spec's other problems, one line each
                    err_console.print(f"[bold red]error:[/] {escape(f'{err.file}: {line}')}",
                                      soft_wrap=True)
                raise typer.Exit(2) from None
            except UsageError as err:
                _show_warnings(caught)
                err_console.print(f"[bold red]error:[/] {escape(str(err))}", soft_wrap=True)
                raise typer.Exit(2) from None
            except CalnetError as err:
                _show_warnings(caught)
                err_console.print(f"[bold red]error:[/] {escape(str(err))}", soft_wrap=True)
                raise typer.Exit(1) from None
            except typer.Exit:
                _show_warnings(caught)
                raise
            except KeyboardInterrupt:
                _show_warnings(caught)
                from calnet.campaign.interrupt import resume_note

                kept = (": " + resume_note(func.__name__, bool(kwargs.get("fresh")))
                        if func.__name__ in ("run", "campaign") else "")
                if func.__name__ == "run" and _FINISHED:
                    kept = (f" after the run had finished: its results in '{_FINISHED[-1]}' "
                            "are complete")
                err_console.print(f"[bold red]interrupted[/]{escape(kept)}", soft_wrap=True)
                raise typer.Exit(130) from None
            except Exception as err:
                if os.environ.get("CALNET_DEBUG"):  # the traceback; the same exit code
                    import traceback

                    traceback.print_exc()
                _show_warnings(caught)
                if isinstance(err, OSError) and err.filename:  # a path given, e.g. --out a file
                    from calnet.files import write_cause

                    cause = write_cause(err)
                    err_console.print(
                        f"[bold red]error:[/] {escape(f'cannot write {err.filename!r}: {cause}')}"
                        if cause else f"[bold red]error:[/] {escape(str(err))}; check the paths "
                        "given (--out, --output, ...): folders where folders are expected, "
                        "writable", soft_wrap=True)
                    raise typer.Exit(1) from None
                err_console.print(f"[bold red]internal error:[/] {type(err).__name__}: "
                                  f"{escape(str(err))}\n"
                                  "This is a bug in calnet; set CALNET_DEBUG=1 for the "
                                  "traceback and report it.", soft_wrap=True)
                raise typer.Exit(3) from None
        _show_warnings(caught)
        return result

    return wrapper


@contextmanager
def _working(what: str) -> Iterator[Callable[[str], None]]:
    """Yields ``note(text)``: a spinner showing the latest note on a terminal; elsewhere
    (a pipe, a log file) plain lines on stderr: the start, each note, ``done in N s``."""
    if console.is_terminal:
        with console.status(what) as status:
            yield lambda text: status.update(f"{what}: {text}")
        return

    def say(text: str) -> None:
        err_console.print(text, markup=False, highlight=False, soft_wrap=True)

    t0 = time.perf_counter()
    say(f"{what} ...")
    yield lambda text: say(f"{what}: {text}")
    say(f"{what}: done in {time.perf_counter() - t0:.1f} s")


def _show_warnings(caught: list[warnings.WarningMessage]) -> None:
    seen = set()
    for w in caught:
        text = str(w.message)
        if text in seen or issubclass(w.category, DeprecationWarning):
            continue
        seen.add(text)
        err_console.print(f"[yellow]warning:[/] {escape(text)}", soft_wrap=True)


@app.command()
@user_errors
def check(spec: SpecArg) -> None:
    """Validate a spec and its import tables; print the network."""
    from calnet.describe import describe_network, import_problems
    from calnet.spec import load_spec

    network = load_spec(spec)
    _imports_finish(network)
    describe_network(network, console)
    problems = import_problems(network) + _template_problems(network)
    if problems:
        (field, msg), *others = problems
        raise SpecError(msg, file=network.source, field=field,
                        more=[f"{f}: {m}" for f, m in others])


IMPORT_LIMIT_S = 10.0
"""Seconds that ``calnet check`` gives a Python simulator's module to import."""


def _imports_finish(network: Any) -> None:
    """Raise :class:`CalnetError` for a Python simulator whose module does not finish
    importing within :data:`IMPORT_LIMIT_S` in a fresh Python (the search path of this
    one, then the spec's folder, as a campaign imports it; the modules side by side).
    ``check`` imports the modules to see that their functions exist; one that waits at
    import would hold it forever."""
    from concurrent.futures import ThreadPoolExecutor

    from calnet.campaign.runners import SLOW_IMPORT, probe_callable

    root = str(Path(network.root).resolve())
    probes: dict[str, str] = {}  # model -> module
    for model in network.models:
        sim = model.simulator
        module = sim.target.partition(":")[0] if sim.kind == "python" else ""
        if module and module not in sys.modules and module not in probes.values():
            probes[model.name] = module  # not imported here already, nor probed
    with ThreadPoolExecutor(max(1, len(probes))) as pool:
        answers = dict(zip(probes, pool.map(
            lambda m: probe_callable(f"{m}:_", (root,), timeout=IMPORT_LIMIT_S)[1],
            probes.values()), strict=True))
    slow = [name for name, problem in answers.items()
            if problem == SLOW_IMPORT.format(module=probes[name], timeout=IMPORT_LIMIT_S)]
    if slow:
        raise CalnetError("; ".join(
            f"{name}: importing module '{probes[name]}' (python:"
            f"{network.model(name).simulator.target}) did not finish within "
            f"{IMPORT_LIMIT_S:g} s" for name in slow)
            + ", so check stopped before importing it here. Move the work the module does "
            "at import (a sleep, a licence check, a solver start-up) into the function: "
            "each campaign run imports the module, and waits as long (up to the model's "
            "timeout)")


def _template_problems(network: Any) -> list[tuple[str, str]]:
    """``(field, message)`` for each command simulator whose argument template the
    campaign refuses (a ``{name}`` that is not an input, parameter or option), found
    as the campaign finds it: by making the simulator, which runs nothing."""
    from calnet.campaign.runners import make_simulator
    from calnet.errors import CampaignError

    out = []
    for model in network.models:
        if model.simulator.kind != "command":
            continue
        try:
            make_simulator(network, model, workdir=Path(network.root) / "campaigns")
        except CampaignError as err:
            out.append((f"models.{model.name}.simulator.argv", str(err)))
    return out


def _blocking_file(path: Path) -> Path | None:
    """The first of the folders above ``path`` that exists and is not a folder (a file),
    where nothing can be made; None when there is none."""
    for parent in reversed(path.parents):
        if parent.exists() and not parent.is_dir():
            return parent
    return None


def _folder_option(value: str, flag: str) -> Path:
    """The path a folder option (``--out DIR``) names; a :class:`UsageError` where it is
    empty, a file, or inside a file (a folder that does not exist is made later)."""
    if not value.strip():
        raise UsageError(f"{flag} is empty; give a folder, e.g. {flag} out")
    path = Path(value)
    blocked = _blocking_file(path / "x")
    if blocked == path:
        raise UsageError(f"{flag} '{value}' is a file, not a folder; give a folder (one that "
                         "does not exist is made)")
    if blocked is not None:
        raise UsageError(f"{flag} '{value}': '{blocked}' is a file, not a folder; give a "
                         "path in a folder")
    return path


def _file_option(path: Path | None, flag: str, example: str) -> None:
    """A :class:`UsageError` where the path a file option (``--store FILE``) names is a
    folder (an empty value included: Typer reads it as ``.``) or lies inside a file."""
    if path is None:
        return
    if path.is_dir():
        raise UsageError(f"{flag} '{path}' is a folder, not a file; give a file, e.g. "
                         f"{flag} {path / example}")
    blocked = _blocking_file(path)
    if blocked is not None:
        raise UsageError(f"{flag} '{path}': '{blocked}' is a file, not a folder; give a "
                         "path in a folder")


def _parse_sets(values: list[str], flag: str = "--set") -> dict[str, float]:
    """``["NAME=VALUE", ...]`` -> ``{NAME: float}``; one-line errors naming ``flag``."""
    out = {}
    for item in values:
        key, sep, val = item.partition("=")
        if not sep or not key.strip():
            raise UsageError(f"{flag} expects NAME=VALUE, got '{item}'")
        if key.strip() in out:
            raise UsageError(f"{flag} gives {key.strip()} twice; give each name once")
        try:
            value = float(val)
        except ValueError:
            raise UsageError(f"{flag} {key.strip()}: '{val}' is not a number; write e.g. "
                             f"{flag} {key.strip()}=0.5") from None
        if not math.isfinite(value):
            raise UsageError(f"{flag} {key.strip()}: '{val}' is not a finite number")
        out[key.strip()] = value
    return out


def _parse_at(text: str) -> dict[str, float]:
    """``"P=200,v=0.5"`` -> ``{"P": 200.0, "v": 0.5}`` (the ``--at`` syntax)."""
    out = _parse_sets([s.strip() for s in text.split(",") if s.strip()], "--at")
    if not out:
        raise UsageError("--at is empty; write e.g. --at P=200,v=0.5")
    return out


def _parse_options(values: list[str]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for item in values:
        key, sep, val = item.partition("=")
        if not sep:
            raise UsageError(f"--option expects NAME=VALUE, got '{item}'")
        try:
            out[key] = json.loads(val)
        except json.JSONDecodeError:
            out[key] = val
    return out


@app.command()
@user_errors
def simulate(
    name: Annotated[str, typer.Argument(
        metavar="NAME", help="built-in simulator: melt_pool, phase_field or solidification")],
    set_: Annotated[list[str], typer.Option(
        "--set", metavar="NAME=VALUE", help="an input or parameter (repeatable)")] = [],  # noqa: B006
    option: Annotated[list[str], typer.Option(
        metavar="NAME=VALUE", help="a simulator option (repeatable)")] = [],  # noqa: B006
) -> None:
    """Run one built-in simulation and print its outputs as JSON.

    Inputs and parameters not given take the middle of the box the simulator is tested
    over (docs/physics.md; a warning names the inputs); a value outside that box runs,
    with a warning; one the model cannot take (not finite, not positive) gives status
    "failed" and exit code 1, its outputs null. --option NAME=VALUE sets one of the
    simulator's numerical options (docs/physics.md; an unknown name is refused with the
    list of known ones). A run reports its progress on stderr (a line at least every
    10 s).
    """
    from calnet.simulators.registry import builtin_info, builtin_names

    if name not in builtin_names():
        raise UsageError(f"unknown built-in simulator '{name}'; choose one of "
                         f"{builtin_names()}")
    info = builtin_info(name)
    values = _parse_sets(set_)
    unknown = [k for k in values if k not in info.inputs + info.parameters]
    if unknown:
        raise UsageError(f"'{name}' has no input or parameter {unknown}; it takes "
                         f"{list(info.inputs + info.parameters)}")
    inputs = {**info.defaults(), **values}
    options = _parse_options(option)
    _check_option_names(name, info.simulate, options)

    def unit(k: str) -> str:
        u = info.units.get(k, "1")
        return f" {u}" if u != "1" else ""

    missing = [k for k in info.inputs if k not in values]
    if missing:
        warnings.warn(f"{', '.join(missing)} not given: "
                      + ", ".join(f"{k}={inputs[k]:g}{unit(k)}" for k in missing)
                      + f" (the middle of the box {name} is tested over); give inputs "
                      "with --set NAME=VALUE",
                      stacklevel=1)
    for k, x in values.items():
        lo, hi = info.bounds.get(k, (-math.inf, math.inf))
        if not lo <= x <= hi:
            warnings.warn(f"{k}={x:g}{unit(k)} lies outside the box [{lo:g}, {hi:g}] "
                          f"that {name} is tested over (docs/physics.md)", stacklevel=1)
    from calnet.progress import Lines

    lines, extra = Lines(name), {}
    if "progress" in inspect.signature(info.simulate).parameters:
        extra["progress"] = lines.update  # progress lines on stderr
    try:
        # and a line after every quiet 10 s, so that a long step does not look hung
        with lines.heartbeat(lambda: "running"):
            result = info.simulate(inputs, **options, **extra)
    except (TypeError, ValueError) as err:
        if not options:
            raise
        given = ", ".join(f"{k}={v!r}" for k, v in options.items())
        text = str(err) if str(err).startswith(name) else f"{name}: {err}"
        raise UsageError(f"{text} (--option {given}); fix the option names or values "
                         "(docs/physics.md lists each simulator's)") from None
    if lines.elapsed() >= lines.every_s:  # a run long enough to have reported progress
        lines.note(f"{result.status}")
    doc = {"simulator": name, "version": info.version, "inputs": inputs,
           "status": result.status, "message": result.message, "outputs": result.outputs,
           "units": {k: info.units.get(k, "1") for k in (*inputs, *result.outputs)},
           "diagnostics": result.diagnostics}
    print(json.dumps(_finite_or_null(doc), indent=2, default=_json_default))
    if result.status != "ok":
        raise typer.Exit(1)


def _finite_or_null(obj: Any) -> Any:
    """``obj`` with every NaN or infinite float as None: strict JSON has no NaN."""
    if isinstance(obj, dict):
        return {k: _finite_or_null(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite_or_null(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def _say_run_is_stale(out: Path) -> None:
    """Warn where ``calnet calibrate`` wrote the posterior of a ``calnet run`` folder
    (``RUN/posterior``): the run's report and metrics describe the posterior it replaced,
    while ``calnet predict --run RUN`` reads the new one."""
    run = out.resolve().parent
    made = [name for name in ("report.html", "metrics.json") if (run / name).is_file()]
    if out.resolve().name != "posterior" or not made:
        return
    err_console.print(f"[yellow]warning:[/] {escape(str(out))} is the posterior of the run in "
                      f"'{escape(str(run))}', whose {' and '.join(made)} describe the "
                      "posterior this calibration replaced (calnet predict --run reads the "
                      "new one); calnet run SPEC --out "
                      f"{escape(str(run))} writes them again", soft_wrap=True)


def _check_option_names(name: str, simulate: Callable[..., Any],
                        options: dict[str, Any]) -> None:
    """A :class:`UsageError` for an ``--option`` that the built-in simulator's function
    does not take: one its signature does not name, where it takes no others
    (``**options``, which it checks itself), and ``progress``, which calnet passes."""
    params = list(inspect.signature(simulate).parameters.values())[1:]  # after the inputs
    named = [p.name for p in params if p.name != "progress"
             and p.kind in (p.KEYWORD_ONLY, p.POSITIONAL_OR_KEYWORD)]
    open_ = any(p.kind is p.VAR_KEYWORD for p in params)
    unknown = [k for k in options if k == "progress" or (k not in named and not open_)]
    if unknown:
        takes = f"it takes {named}" if named else "it takes none"
        raise UsageError(f"'{name}' has no option {unknown}; {takes}")


def _json_default(obj: Any) -> Any:
    try:
        return obj.item()
    except AttributeError:
        return str(obj)


def _campaign_options(kw: dict[str, Any]) -> None:
    """Refuse, as usage errors (exit 2), ``calnet campaign`` paths no file can have, before
    the command reads a store (the command refuses options that do not go together)."""
    _file_option(kw["store"], "--store", f"{kw['model'] or 'MODEL'}.sqlite")
    _file_option(kw["export"], "--export", "runs.csv")


def campaign_command() -> Callable[..., Any]:
    """``calnet campaign`` as the command line runs it: :func:`calnet.campaign.command
    .campaign` after :func:`_campaign_options`, its errors one line each
    (:func:`user_errors`)."""
    from calnet.campaign.command import campaign

    @functools.wraps(campaign)
    def checked(**kwargs: Any) -> Any:
        _campaign_options(kwargs)
        return campaign(**kwargs)

    return user_errors(checked)


app.command("campaign")(campaign_command())


@app.command()
@user_errors
def surrogates(
    spec: SpecArg,
    folder: Annotated[str, typer.Option(
        "--out", metavar="DIR", help="folder for the GPs and parity plots")
    ] = "out/surrogates",
    no_cv: Annotated[bool, typer.Option("--no-cv", help="skip cross-validation")] = False,
) -> None:
    """Fit a GP surrogate per output needed; print the CV table."""
    from calnet.pipeline import surrogate_stage
    from calnet.spec import load_spec

    out = _folder_option(folder, "--out")
    network = load_spec(spec)
    out.mkdir(parents=True, exist_ok=True)  # a bad --out fails now, not after the fits
    with _working("fitting surrogates") as note:
        sur, _ = surrogate_stage(network, folder=out, figures=out, cv=not no_cv,
                                 progress=note)
    from calnet.report.build import surrogate_label

    table = Table("output (unit)", "runs", "excluded", "k", "MAPE %", "RMSE (output's unit)",
                  "95% coverage")
    for key, s in sur.items.items():
        cv = s.cv.metrics() if s.cv else {}
        table.add_row(surrogate_label(network, key, s.gp.transform, s.gp.mean), str(s.n_runs),
                      str(s.n_excluded), str(cv.get("k", "-")),
                      *(f"{cv[k]:.4g}" if cv.get(k) is not None else "-"
                        for k in ("mape", "rmse", "coverage95")))
    console.print(table)
    console.print(f"surrogates and plots written to {out}")


@app.command()
@user_errors
def calibrate(
    spec: SpecArg,
    mode: Annotated[Literal["segmented", "joint"] | None, typer.Option(
        metavar="MODE", help="segmented or joint (default: the spec's)")] = None,
    plug: Annotated[Literal["mode", "posterior"] | None, typer.Option(
        metavar="PLUG", help="segmented: mode or posterior (default: the spec's)")] = None,
    surrogates_dir: Annotated[Path, typer.Option(
        "--surrogates", metavar="DIR", help="written by calnet surrogates")
    ] = Path("out/surrogates"),
    folder: Annotated[str, typer.Option(
        "--out", metavar="DIR", help="folder for posteriors and plots")] = "out/posterior",
    seed: Annotated[int | None, typer.Option(
        metavar="SEED", min=0, help="seed of the chains (default: the spec's "
        "settings.seed)")] = None,
) -> None:
    """Calibrate the network (KOH per model, NUTS).

    Writes the posteriors (ArviZ netCDF; draws and summary also as CSV), a summary
    table with diagnostics, and prior-vs-posterior plots per model.
    """
    from calnet.calibration.calibrate_network import calibrate as run_calibration
    from calnet.pipeline import record_calibration
    from calnet.report.build import posterior_figures
    from calnet.report.posterior_csv import write_posterior_csv
    from calnet.spec import load_spec
    from calnet.surrogates.fit_network import Surrogates, check_surrogates

    out = _folder_option(folder, "--out")
    network = load_spec(spec)
    if plug and (mode or network.settings.calibration.mode) == "joint":
        raise UsageError("--plug applies to segmented calibration only; this calibration is "
                         "joint" + ("" if mode else " (the spec's settings.calibration.mode)")
                         + ": add --mode segmented, or leave --plug out")
    sur = Surrogates.load(surrogates_dir)
    check_surrogates(network, sur, surrogates_dir)
    out.mkdir(parents=True, exist_ok=True)  # a bad --out fails now, not after sampling
    with _working("calibrating") as note:
        post = run_calibration(network, sur, mode=mode, plug=plug, seed=seed,
                               progress=note)
    result = record_calibration(network, post, folder=out)
    summary = result.models
    doc = {**summary, "surrogate_check": result.surrogate_check,
           "seed": network.settings.seed if seed is None else seed}
    (out / "summary.json").write_text(json.dumps(doc, indent=1, default=_json_default))
    write_posterior_csv(out, result.theta, summary)
    _say_run_is_stale(out)
    if not post.calibrated:
        kept = (f"the parameters of {', '.join(post.prior_only)} keep their priors "
                f"({post.n_draws} prior draws)" if post.prior_only
                else "the posterior is empty (0 parameters)")
        console.print(f"no data sets: nothing to calibrate; {kept}. Written to {out}; "
                      "calnet predict and calnet run predict from it", soft_wrap=True)
        return
    if not post.theta:
        sampled = [ds for ds, h in post.hyper.items() if h]
        what = (f"sampled the discrepancy and noise of {', '.join(sampled)} only" if sampled
                else "nothing to sample (known noise, no discrepancy)")
        console.print(f"no calibration parameters: {what}. Written to {out}", soft_wrap=True)
        return
    table = Table("model", "parameter", "range", "mode", "mean", "95% interval", "unit",
                  "R-hat", "ESS bulk", title=f"{post.mode} calibration"
                  + (f", upstream plugged in by its {post.plug}" if post.mode == "segmented"
                     else ""))
    for model, s in summary.items():
        if s.get("prior_only"):
            table.add_row(model, "(no data: prior kept)", *[""] * 7)
            continue
        if not s["parameters"]:  # only its data's discrepancy and noise were sampled
            table.add_row(model, "(no parameters)", *[""] * 5, f"{s['max_rhat']:.3f}",
                          f"{s['min_ess_bulk']:.0f}")
            continue
        for name, r in s["parameters"].items():
            table.add_row(model, name, f"[{r['lower']:g}, {r['upper']:g}]", f"{r['mode']:.4g}",
                          f"{r['mean']:.4g}", f"[{r['q2.5']:.4g}, {r['q97.5']:.4g}]",
                          r["unit"], f"{r.get('rhat', float('nan')):.3f}",
                          f"{r.get('ess_bulk', float('nan')):.0f}")
    posterior_figures(result, out)
    console.print(table)
    for model, s in summary.items():
        if not s.get("prior_only") and s["divergences"]:
            console.print(f"[yellow]{model}: {s['divergences']} divergent transitions[/]")
    console.print(f"posteriors (ArviZ netCDF, network_posterior.*), summary.json, "
                  f"posterior_draws.csv, posterior_summary.csv and prior-vs-posterior plots "
                  f"written to {out}")


@app.command()
@user_errors
def predict(
    spec: SpecArg,
    at: Annotated[list[str], typer.Option(
        "--at", metavar="NAME=VALUE,...", help="one point, e.g. P=200,v=0.5 (repeatable)")
    ] = [],  # noqa: B006
    csv: Annotated[Path | None, typer.Option(
        metavar="FILE", help="CSV of points, one column per input (others are ignored)")
    ] = None,
    dataset: Annotated[list[str], typer.Option(
        "--dataset", "-d", metavar="NAME", help="data set, or model.output with a surrogate, "
        "to predict (repeatable; default: every data set and settings.predict output)")
    ] = [],  # noqa: B006
    run_dir: Annotated[Path, typer.Option(
        "--run", metavar="DIR", help="folder written by calnet run")
    ] = Path("out"),
    draws: Annotated[int, typer.Option(metavar="N", min=1, help="posterior draws used")] = 200,
    seed: Annotated[int | None, typer.Option(
        metavar="SEED", min=0, help="default: the spec's")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="print JSON, not a table")] = False,
    output: Annotated[Path | None, typer.Option(
        metavar="FILE", help="also write the predictions as CSV")] = None,
) -> None:
    """Predict outputs at new settings, with 95 % bands.

    A data set's output is predicted as a new measurement (calibrated chain, discrepancy,
    noise); a simulator output (-d model.output, e.g. one listed in settings.predict) as
    the simulator would give it, by Monte Carlo through the linked surrogates. Each point
    comes with its uncertainty budget: the shares of the parameters, each emulator, the
    discrepancy and the noise.
    """
    from calnet.emulation import predict_output
    from calnet.predict import (
        largest_shares,
        link_notes,
        load_run,
        prediction_targets,
        settings_matrix,
        shared_inputs,
        shares_per_point,
    )
    from calnet.predict import predict as run_predict
    from calnet.spec import load_spec

    _file_option(output, "--output", "predictions.csv")
    network = load_spec(spec)
    rows = [_parse_at(a) for a in at] + (_read_points(csv) if csv else [])
    if not rows:
        raise UsageError("give the settings to predict at: --at P=200,v=0.5 (repeatable) "
                          "or --csv points.csv")
    sur, post = load_run(network, run_dir)
    for name in sorted({d for d in dataset if dataset.count(d) > 1}):
        warnings.warn(f"-d {name} is given twice; it is predicted once", stacklevel=1)
    names = prediction_targets(network, sur, post, list(dict.fromkeys(dataset)))
    seed = network.settings.seed if seed is None else seed
    if post.n_draws and draws > post.n_draws:  # more would repeat draws, at their cost
        warnings.warn(f"--draws {draws} is more than the posterior's {post.n_draws} draws; "
                      f"using {post.n_draws}", stacklevel=1)
        draws = post.n_draws
    results, table_rows = [], []
    # a point may carry inputs that only some of the targets take, and names (CSV
    # columns) that none takes: those are ignored, with a warning
    skip = {k for row in rows for k in row}
    extra = [k for k in dict.fromkeys(k for row in rows for k in row)
             if k not in shared_inputs(network, names, rows)]
    _warn_extra(network, names, extra, kept=output is not None)
    for name in names:
        x, notes = settings_matrix(network, name, rows, skip=skip)
        notes += link_notes(network, sur, post, name, x)
        for note in dict.fromkeys(notes):
            warnings.warn(note, stacklevel=1)
        # settings_matrix has warned of settings outside the bounds
        pred = (predict_output(network, sur, post, name, x, seed=seed, warn_outside=False)
                if "." in name
                else run_predict(network, sur, post, name, x, n_draws=draws, seed=seed,
                                 warn_outside=False))
        results.append(pred.to_dict() | {"variance_share_per_point": shares_per_point(pred)})
        model, out_name = pred.observes.split(".")
        unit = network.model(model).output(out_name).unit
        for i, top in enumerate(largest_shares(pred)):
            table_rows.append((f"{name} (simulator)" if "." in name
                               else f"{name}: {pred.observes} (measured)",
                               ", ".join(f"{k.split('.', 1)[1]}={v:g}" for k, v
                                         in zip(pred.input_keys, x[i], strict=True)),
                               f"{pred.mean[i]:.4g}", f"[{pred.lower[i]:.4g}, "
                               f"{pred.upper[i]:.4g}]", unit,
                               ", ".join(f"{k} {v:.0%}" for k, v in top)))
    if output:
        _write_predictions(output, results, [{k: row.get(k, "") for k in extra}
                                             for row in rows])
    if as_json:
        print(json.dumps({"predictions": results}, indent=2, default=_json_default))
        return
    table = Table("prediction", "settings", "mean", "95% band", "unit",
                  "largest variance shares")
    for r in table_rows:
        table.add_row(*r)
    console.print(table)
    if output:
        console.print(f"predictions written to {output}")


def _warn_extra(network: Any, targets: list[str], extra: list[str], kept: bool) -> None:
    """One warning naming the given names (``--at`` or ``--csv`` columns) that no target
    takes (``kept``: they are copied to ``--output``)."""
    if not extra:
        return
    from calnet.predict import target_model

    keys = list(dict.fromkeys(k for t in targets for k in
                              network.process_input_keys(target_model(network, t))))
    bare = [k.split(".", 1)[1] for k in keys]
    takes = ", ".join(bare if len(set(bare)) == len(bare) else keys)
    verb = "it takes" if len(targets) == 1 else "they take"
    warnings.warn(f"{'not used' if kept else 'ignored'} {', '.join(extra)}: not process "
                  f"inputs of {', '.join(targets)} ({verb} {takes})"
                  + ("; copied to --output beside each point" if kept else ""), stacklevel=1)


def _read_points(path: Path) -> list[dict[str, float | str]]:
    """:func:`calnet.predict.read_points`, refusing a header that names a column twice."""
    from calnet.predict import read_points
    from calnet.spec.data import repeated_header

    twice = repeated_header(path) if path.is_file() else None
    if twice:
        raise UsageError(f"--csv {path}: column '{twice}' appears twice in the header; give "
                         "each column its own name")
    return read_points(path)


def _write_predictions(path: Path, results: list[dict], extras: list[dict]) -> None:
    """The predictions as CSV, a row per point and target: the point's number (from 1,
    in the order of --at then --csv), the columns it carried that no target takes (an
    ID, say), then the target, its inputs and the prediction."""
    make_folder(path.parent)
    names = list(dict.fromkeys(k for e in extras for k in e))
    with replacing(path) as tmp, tmp.open("w", newline="") as fh:
        writer = csv_mod.writer(fh)
        keys = list(dict.fromkeys(k for r in results for k in r["inputs"]))
        writer.writerow(["point", *names, "dataset", "output", *keys, "mean", "lower95",
                         "upper95"])
        for r in results:
            for i, (x, m, lo, hi) in enumerate(zip(r["x"], r["mean"], r["lower95"],
                                                   r["upper95"], strict=True)):
                given = dict(zip(r["inputs"], x, strict=True))
                writer.writerow([i + 1, *(extras[i].get(k, "") for k in names),
                                 r["dataset"], r["observes"],
                                 *(given.get(k, "") for k in keys), m, lo, hi])


@app.command()
@user_errors
def verify(
    spec: SpecArg,
    run_dir: Annotated[Path, typer.Option(
        "--run", metavar="DIR", help="folder written by calnet run")
    ] = Path("out"),
    k: Annotated[int, typer.Option(
        "-k", "--points", metavar="K", min=1, help="posterior points to run")] = 8,
    seed: Annotated[int | None, typer.Option(
        metavar="SEED", min=0, help="default: the spec's")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="print JSON, not tables")] = False,
) -> None:
    """Run the simulators at posterior points; check the surrogates.

    z = (simulator - mean) / sd on the modelled scale; writes RUN/verify.json.
    Disagreements are reported, not errors.
    """
    from calnet.calibration.persist import load_posterior
    from calnet.predict import load_surrogates
    from calnet.spec import load_spec
    from calnet.verify import Z_LIMIT
    from calnet.verify import verify as run_verify

    network = load_spec(spec)
    sur = load_surrogates(network, run_dir)
    post = load_posterior(run_dir / "posterior", network)
    seed = network.settings.seed if seed is None else seed
    with _working("running the simulators") as note:
        result = run_verify(network, sur, post, k=k, seed=seed, workdir=run_dir / "verify",
                            progress=note)
    doc = json.dumps(result.to_dict(), indent=1, default=_json_default)
    (run_dir / "verify.json").write_text(doc)
    if as_json:
        print(doc)
        return
    table = Table("surrogate", "point", "simulator", "surrogate mean ± sd", "z",
                  title="surrogates against the simulators at posterior points "
                  "(modelled scale: ln for log outputs)")
    for p in result.points:
        label = p.surrogate + (" (ln)" if result.checks[p.surrogate].transform == "log" else "")
        if p.status != "ok":
            table.add_row(label, str(p.point), f"[red]{p.status}[/]: {p.message}",
                          f"{p.mean:.4g} ± {p.sd:.2g}", "-")
            continue
        z = f"{p.z:+.2f}"
        table.add_row(label, str(p.point), f"{p.simulator:.4g}", f"{p.mean:.4g} ± {p.sd:.2g}",
                      f"[red]{z}[/]" if abs(p.z) > Z_LIMIT else z)
    console.print(table)
    summary = Table("surrogate", "n", "failed", "RMSE (modelled scale)", "max |z|",
                    f"|z| > {Z_LIMIT:g}")
    for c in result.checks.values():
        label = c.surrogate + (" (ln)" if c.transform == "log" else "")
        if not c.n:  # nothing to measure: no simulator run finished
            summary.add_row(label, "0", str(c.n_failed), "-", "-", "-")
            continue
        summary.add_row(label, str(c.n), str(c.n_failed), f"{c.rmse:.3g}",
                        f"{c.max_abs_z:.2f}", f"{c.share_beyond:.0%}")
    console.print(summary)
    for c in result.checks.values():
        text = c.verdict
        if c.n and c.n_failed:  # a verdict on fewer points than were asked for says so
            text += (f" at the {c.n} of {c.n + c.n_failed} points whose simulator run "
                     "finished")
        console.print(f"{c.surrogate}: " + (escape(text) if c.agrees
                                            else f"[yellow]{escape(text)}[/]"),
                      soft_wrap=True)
        if c.note:
            console.print(f"{c.surrogate}: {escape(c.note)}", soft_wrap=True)
    for f in result.fits.values():  # the simulator against the observations
        text = f.summary()
        console.print(f"{f.dataset}: " + (escape(text) if f.fits
                                           else f"[yellow]{escape(text)}[/]"),
                      soft_wrap=True)
    for note in result.notes:
        console.print(f"note: {escape(note)}", soft_wrap=True)
    console.print(f"written to {run_dir / 'verify.json'}")
    unchecked = [c for c in result.checks.values() if not c.n]
    if unchecked:
        raise CalnetError(
            "verify: the simulator failed at every point of "
            + ", ".join(f"{c.surrogate} ({c.n_failed})" for c in unchecked)
            + f", so {'those surrogates were' if len(unchecked) > 1 else 'it was'} not "
            "checked; see the messages above, fix the "
            "simulator (calnet simulate MODEL --set ...) and run calnet verify again")


@app.command()
@user_errors
def run(
    spec: SpecArg,
    out: Annotated[str, typer.Option(metavar="DIR", help="output folder")] = "out",
    fresh: Annotated[bool, typer.Option(
        "--fresh", help="simulate every model again into OUT/campaigns (deleting the "
        "stores there; the stores beside the spec are left as they are, and an OUT "
        "whose campaigns folder is theirs is refused). Without it, OUT/campaigns is used "
        "when it holds this network's stores, else the stores beside the spec")] = False,
    quick: Annotated[bool, typer.Option(
        "--quick", help="fewer draws, restarts and folds, for a fast look (the report says "
        "which results are indicative only)")] = False,
    seed: Annotated[int | None, typer.Option(
        metavar="SEED", min=0, help="seed of the stages after the campaign: surrogate "
        "fits, chains, predictions (default: the spec's settings.seed, which the campaign "
        "designs keep)")] = None,
) -> None:
    """Run every stage on SPEC and write the report to OUT.

    Ctrl-C exits with 130, SIGTERM with 143; finished campaign runs are kept either way.
    """
    from calnet.campaign.interrupt import sigterm_exit
    from calnet.pipeline import run_pipeline

    _FINISHED.clear()
    folder = _folder_option(out, "--out")
    with sigterm_exit("run", fresh):
        run_pipeline(spec, out=folder, fresh=fresh, quick=quick, console=console, seed=seed)
        _FINISHED.append(folder)  # a Ctrl-C from here on comes after a complete run


_INTERRUPTED_EXITS = (130, 143)  # Ctrl-C, SIGTERM


def main(prog_name: str | None = None) -> None:
    """The ``calnet`` console script: :data:`app`, and after an interrupt an immediate
    exit. An interrupt can leave a compiled (XLA) program running in the background (one
    dispatched but not yet waited for, or compiling in another thread), and the
    interpreter's clean-up at a normal exit then crashes under it (a segmentation fault
    instead of the exit code). What the command keeps is on disk by then: the latch
    (:func:`calnet.interrupts.latch`) unwinds the work before the exit code is set."""
    _quiet_resource_tracker()
    try:
        app(prog_name=prog_name)
    except SystemExit as stop:
        if stop.code in _INTERRUPTED_EXITS and "jax" in sys.modules:
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(stop.code)
        raise


def _quiet_resource_tracker() -> None:
    """Keep multiprocessing's resource tracker from warning of "leaked semaphore objects"
    after an interrupt: the immediate exit above leaves a campaign's process pool to it,
    which it cleans up as it should, and its warning would only alarm. The tracker is a
    child process: the rule reaches it through ``PYTHONWARNINGS`` (as it reaches the
    simulators a campaign starts, where it matches nothing of theirs)."""
    rule = "ignore:resource_tracker:UserWarning"
    rules = [r for r in os.environ.get("PYTHONWARNINGS", "").split(",") if r]
    if rule not in rules:
        os.environ["PYTHONWARNINGS"] = ",".join([*rules, rule])


if __name__ == "__main__":  # pragma: no cover
    main()
