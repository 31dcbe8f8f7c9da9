"""Simulator adapters: every kind of simulator spoken through one small protocol.

``simulator(inputs) -> SimResult`` (:class:`calnet.simulators.base.Simulator`), with a
``name`` and a ``version`` that the store records. Four kinds:

- :class:`BuiltinRunner`, the built-in physics models (``melt_pool``, ``solidification``);
- :class:`CallableRunner`, a Python function given as ``module:function``;
- :class:`CommandRunner`, an external program run from an argument-list template (never a
  shell string), one working directory per run;
- :class:`UMBridgeRunner`, a model on a UM-Bridge server.

Adapters are small frozen dataclasses, so they pickle to process-pool and Dask workers.
:func:`execute_run` is the task every executor runs: it times one run, turns exceptions,
NaN, missing outputs and outputs that are no number into a recorded status, and enforces
the timeout. A timeout on a Python call (built-in, callable, UM-Bridge) is enforced by
running the call in a child Python process that is killed when the time is up; without a
timeout the call runs in the worker itself. What a run prints outside the campaign's
process goes to its logs (:mod:`calnet.campaign.logs`).
"""

from __future__ import annotations

import ast
import importlib
import importlib.util
import json
import os
import pickle
import re
import select
import signal
import subprocess
import sys
import threading
import time
import traceback
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field
from importlib.machinery import SOURCE_SUFFIXES, PathFinder
from pathlib import Path
from typing import Any

import numpy as np

from calnet.campaign import logs, reaper
from calnet.campaign.executors import replace_this_worker
from calnet.errors import CampaignError
from calnet.simulators.base import STATUSES, SimResult, Simulator, as_float, not_numbers
from calnet.simulators.registry import builtin_info
from calnet.spec.models import Model
from calnet.spec.network import Network


@dataclass(frozen=True)
class RunRecord:
    """The outcome of run ``index``, as the store keeps it.

    Attributes
    ----------
    index : int
        Row of the design.
    status : {"ok", "failed", "timeout", "nonconverged"}
    outputs : dict of str to float
    message : str
        Why the run is not ``ok``.
    diagnostics : dict
        The simulator's free-form diagnostics (JSON-serialisable).
    wall_time : float
        Seconds the run took, timeout handling included.
    """

    index: int
    status: str
    outputs: dict[str, float]
    message: str
    diagnostics: dict[str, Any]
    wall_time: float


# --------------------------------------------------------------------------- adapters
@dataclass(frozen=True)
class BuiltinRunner:
    """A built-in simulator of :mod:`calnet.simulators`, called with ``options``."""

    name: str
    version: str
    options: dict[str, Any] = field(default_factory=dict)

    def __call__(self, inputs: Mapping[str, float]) -> SimResult:
        return builtin_info(self.name).simulate(dict(inputs), **self.options)


@dataclass(frozen=True)
class CallableRunner:
    """A Python function ``module:function`` taking an inputs dict.

    It returns a :class:`SimResult` or a mapping of output values. The module is imported
    from ``sys.path`` (``PYTHONPATH`` in worker processes) or, failing that, from the
    folders in ``search_path`` (the spec's folder).
    """

    target: str
    version: str = ""
    options: dict[str, Any] = field(default_factory=dict)
    search_path: tuple[str, ...] = ()

    @property
    def name(self) -> str:
        return self.target

    def __call__(self, inputs: Mapping[str, float]) -> SimResult:
        out = load_callable(self.target, self.search_path)(dict(inputs), **self.options)
        if isinstance(out, SimResult):
            return out
        if not isinstance(out, Mapping):
            return SimResult({}, "failed", f"{self.target} returned {type(out).__name__}; "
                             "return a dict of outputs or a SimResult")
        # a 0-d array is its one number; execute_run checks the values
        return SimResult({str(k): v.item() if getattr(v, "shape", None) == () else v
                          for k, v in out.items()})


@dataclass(frozen=True)
class CommandRunner:
    """An external program, run without a shell.

    ``argv`` is a template: in each argument, ``{input_json}``, ``{output_json}``,
    ``{workdir}``, ``{run}`` and ``{<variable>}`` (any input, parameter or option) are
    replaced per run. With ``input_mode="json-file"`` the inputs are written to
    ``input.json`` in the run's working directory; with ``"args"`` only the template
    carries them. Outputs are read from ``output.json`` (``output_mode="json-file"``) or
    from standard output (``"stdout"``: its last line that is a JSON object, after any
    log lines), as a JSON object of output values, optionally with ``status`` and
    ``message``. Each run has its own working directory
    ``<workdir>/<run>``; the program runs there. A value of one of ``outputs`` (the
    model's) that is not a number fails the run, saying so; other keys that are not
    numbers are ignored.
    """

    argv: tuple[str, ...]
    workdir: str
    input_mode: str = "json-file"
    output_mode: str = "json-file"
    timeout: float | None = None
    options: dict[str, Any] = field(default_factory=dict)
    version: str = ""
    outputs: tuple[str, ...] = ()

    @property
    def name(self) -> str:
        return Path(self.argv[0]).name

    def __call__(self, inputs: Mapping[str, float], *, run: str = "run") -> SimResult:
        folder = Path(self.workdir) / run
        folder.mkdir(parents=True, exist_ok=True)
        in_path, out_path = folder / "input.json", folder / "output.json"
        out_path.unlink(missing_ok=True)
        if self.input_mode == "json-file":
            in_path.write_text(json.dumps(dict(inputs)))
        values = {**{k: str(v) for k, v in self.options.items()},
                  **{k: repr(float(v)) for k, v in inputs.items()},
                  "input_json": str(in_path), "output_json": str(out_path),
                  "workdir": str(folder), "run": run}
        argv = [_substitute(arg, values) for arg in self.argv]
        fds = logs.open_logs(folder)  # what the program prints goes to the run's logs
        try:
            proc = _run_killable(argv, folder, self.timeout, *(fds or ()))
        except FileNotFoundError:
            return SimResult({}, "failed", f"command '{argv[0]}' not found; give its full "
                             "path or put it on PATH")
        finally:
            for fd in fds or ():
                os.close(fd)
            logs.tidy(folder)
        if proc is None:
            return SimResult({}, "timeout", f"command exceeded its timeout of {self.timeout:g} s"
                             + logs.where(folder))
        if proc.returncode != 0:
            tail = (proc.stderr.strip().splitlines()[-logs.TAIL_LINES:] if fds is None
                    else logs.tail(folder))
            return SimResult({}, "failed", f"command {_ended(proc.returncode)}"
                             + (f": {' | '.join(tail)}" if tail else "") + logs.where(folder))
        if self.output_mode == "stdout":
            text = proc.stdout if fds is None else _read(folder / logs.LOGS[0])
        elif not out_path.is_file():
            return SimResult({}, "failed", f"command wrote no output file {out_path.name} "
                             "(in its run folder); write the outputs to {output_json} as a "
                             "JSON object, or set output_mode: stdout" + logs.where(folder))
        else:
            text = _read(out_path)
        result = _parse_outputs(text, self.output_mode, self.outputs)
        if result.status != "ok" and result.message:
            return SimResult(result.outputs, result.status,
                             result.message + logs.where(folder), result.diagnostics)
        return result


@dataclass(frozen=True)
class UMBridgeRunner:
    """A model on a UM-Bridge server: one input vector (inputs then parameters, in
    declaration order) -> one output vector (the model's outputs, in order).
    ``options`` go to the server as the model ``config``."""

    url: str
    model: str
    columns: tuple[str, ...]
    outputs: tuple[str, ...]
    options: dict[str, Any] = field(default_factory=dict)
    version: str = ""

    @property
    def name(self) -> str:
        return f"{self.url.rstrip('/')}/{self.model}"

    def __call__(self, inputs: Mapping[str, float]) -> SimResult:
        import requests
        import umbridge

        vector = [float(inputs[c]) for c in self.columns]
        try:
            client = umbridge.HTTPModel(self.url, self.model)
            out = client([vector], dict(self.options))
        except requests.exceptions.ConnectionError as err:
            return SimResult({}, "failed", f"no UM-Bridge server answers at {self.url} "
                             f"({type(err).__name__}); start it, or fix the url")
        except json.JSONDecodeError:
            return SimResult({}, "failed", f"the server at {self.url} did not answer as a "
                             "UM-Bridge server (not JSON); check the url")
        flat = [float(v) for block in out for v in block]
        if len(flat) != len(self.outputs):
            return SimResult({}, "failed", f"UM-Bridge model returned {len(flat)} values, "
                             f"expected {len(self.outputs)} ({list(self.outputs)})")
        return SimResult(dict(zip(self.outputs, flat, strict=True)))


# --------------------------------------------------------------------------- factory
def make_simulator(network: Network, model: Model, *, workdir: str | Path) -> Simulator:
    """The adapter of ``model``'s simulator reference.

    Parameters
    ----------
    network : Network
        For the spec's folder (Python modules, relative command paths).
    model : Model
        Its ``simulator`` reference is adapted.
    workdir : path
        Folder of the per-run working directories of a command simulator.
    """
    ref = model.simulator
    options = dict(ref.options)
    version = str(options.pop("version", ""))
    if ref.kind == "builtin":
        try:
            return BuiltinRunner(ref.name, builtin_info(ref.name).version, options)
        except Exception as err:
            raise CampaignError(str(err)) from None
    if ref.kind == "python":
        return CallableRunner(ref.target, version, options, (str(Path(network.root).resolve()),))
    if ref.kind == "command":
        _check_template(ref.argv, (*model.input_names, *model.parameter_names, *options))
        return CommandRunner(resolve_program(ref.argv, network), str(Path(workdir).absolute()),
                             ref.input_mode,
                             ref.output_mode, run_timeout(network, model), options, version,
                             model.output_names)
    return UMBridgeRunner(ref.url, ref.model, model.input_names + model.parameter_names,
                          model.output_names, options, version)


def run_timeout(network: Network, model: Model) -> float | None:
    """Seconds allowed per run: the simulator's own, else the model's or network's
    campaign setting, else none."""
    campaign = model.campaign or network.settings.campaign
    return model.simulator.timeout or campaign.timeout


VERSION_NAMES = ("__version__", "VERSION")  # a callable's module attributes, in order
PROBE_TIMEOUT = 60.0
"""Seconds a child process has to import a callable's module for its version, for a model
without a timeout (:func:`probe_callable`)."""


def simulator_version(sim: Simulator, *, timeout: float | None = None) -> str:
    """The version of ``sim``; for a callable, the module's ``__version__`` or ``VERSION``
    when the spec gives none.

    A user's module is never imported in this process, where its code could raise, end
    the interpreter or hang before any timeout applies: the version is read from the
    module's source when it is written there as a literal (``__version__ = "1.2"``),
    else from a module this process has already imported, else by importing it in a child
    process (:func:`probe_callable`) killed after ``timeout`` seconds (the model's run
    timeout; :data:`PROBE_TIMEOUT` without one). A module that cannot be found or
    imported has no version (""): its runs fail, saying why.
    """
    if not isinstance(sim, CallableRunner) or sim.version:
        return sim.version
    module_name = sim.target.partition(":")[0]
    module = sys.modules.get(module_name)
    if module is not None:
        return _version_of(module)
    written = _written_version(module_name, sim.search_path)
    if written is not None:
        return written
    limit = PROBE_TIMEOUT if timeout is None else timeout
    return probe_callable(sim.target, sim.search_path, limit)[0]


#: :func:`probe_callable`'s problem when the module's import ran past its limit
SLOW_IMPORT = "importing module '{module}' took more than {timeout:g} s"


def probe_callable(target: str, search_path: tuple[str, ...] = (),
                   timeout: float = PROBE_TIMEOUT) -> tuple[str, str]:
    """Import the module of ``module:function`` in a child process, killed after
    ``timeout`` seconds; returns ``(version, problem)``: the module's version ("" without
    one), and why the target cannot be called ("" when it can: the module imports and
    has the function). What the module prints on import is discarded.
    """
    module_name, _, func_name = target.partition(":")
    payload = json.dumps([[*sys.path, *search_path], module_name, func_name])
    proc = _run_killable([sys.executable, "-c", _PROBE], None, timeout,
                         stderr=subprocess.DEVNULL, stdin=payload)
    if proc is None:
        return "", SLOW_IMPORT.format(module=module_name, timeout=timeout)
    try:
        version, problem = json.loads(proc.stdout.strip().splitlines()[-1])
    except (IndexError, ValueError):
        return "", f"importing module '{module_name}' {_ended(proc.returncode)}"
    return str(version), str(problem)


# run by probe_callable's child: [sys.path, module, function] in on stdin, [version,
# problem] out on stdout (the module's own prints go to standard error)
_PROBE = """
import importlib, json, os, sys
path, module_name, func_name = json.loads(sys.stdin.read())
sys.path[:] = path
answer = os.fdopen(os.dup(1), "w")
os.dup2(2, 1)
try:
    module = importlib.import_module(module_name)
    version = getattr(module, "__version__", getattr(module, "VERSION", ""))
    problem = ("" if callable(getattr(module, func_name, None)) else
               f"module '{module_name}' has no function '{func_name}'")
except BaseException as err:
    version, problem = "", f"{type(err).__name__}: {err}".rstrip(": ")
answer.write(json.dumps([str(version), problem]) + "\\n")
answer.flush()
"""


def _version_of(module: Any) -> str:
    return str(getattr(module, VERSION_NAMES[0], getattr(module, VERSION_NAMES[1], "")))


def _written_version(module_name: str, search_path: tuple[str, ...]) -> str | None:
    """The version a module's source file states as a literal, read without running it:
    "" for a module that states none, or does not parse (its runs then fail, saying why);
    None when only importing it would tell (a version computed or imported, a module
    that is no Python source file or is not found without importing a package)."""
    origin = _module_source(module_name, search_path)
    if origin is None:
        return None
    try:
        tree = ast.parse(Path(origin).read_bytes())
    except (OSError, SyntaxError, ValueError):
        return ""
    bound: dict[str, ast.expr | None] = {}
    for node in tree.body:
        bound.update(_bindings(node))
    for name in VERSION_NAMES:
        if name in bound:
            value = bound[name]
            literal = isinstance(value, ast.Constant) and isinstance(value.value, (str, int, float))
            return str(value.value) if literal else None  # type: ignore[union-attr]
    return None if "*" in bound else ""


def _bindings(node: ast.stmt) -> dict[str, ast.expr | None]:
    """The version names a statement of a module's body binds: to the value of a plain
    assignment, to None when only running it tells; ``"*"`` for a star import."""
    if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
        return {}
    if not isinstance(node, (ast.Assign, ast.AnnAssign)) or node.value is None:
        return _bound_within(node)
    out: dict[str, ast.expr | None] = {}
    for target in node.targets if isinstance(node, ast.Assign) else [node.target]:
        if isinstance(target, ast.Name):
            out.update({target.id: node.value} if target.id in VERSION_NAMES else {})
        else:  # a, __version__ = ...
            out.update(_bound_within(target))
    return out


def _bound_within(node: ast.AST) -> dict[str, ast.expr | None]:
    """The version names (and ``"*"``) that anything within ``node`` binds, to None."""
    out: dict[str, ast.expr | None] = {}
    for sub in ast.walk(node):
        if isinstance(sub, ast.Name) and isinstance(sub.ctx, ast.Store):
            name = sub.id
        elif isinstance(sub, ast.alias):
            name = sub.asname or sub.name
        else:
            continue
        if name in (*VERSION_NAMES, "*"):
            out[name] = None
    return out


def _module_source(module_name: str, search_path: tuple[str, ...]) -> str | None:
    """The Python source file of ``module_name`` on ``sys.path`` or in ``search_path``,
    found without running any of the user's code (a package's ``__init__`` included);
    None when there is none to be found so."""
    top, *rest = module_name.split(".")
    try:
        spec = importlib.util.find_spec(top) or PathFinder.find_spec(top, list(search_path))
        for part in rest:
            if spec is None or not spec.submodule_search_locations:
                return None
            spec = PathFinder.find_spec(part, list(spec.submodule_search_locations))
    except (ImportError, ValueError):
        return None
    origin = spec.origin if spec is not None and spec.has_location else None
    return origin if origin and origin.endswith(tuple(SOURCE_SUFFIXES)) else None


def load_callable(target: str, search_path: tuple[str, ...] = ()) -> Any:
    """Import ``module:function``, trying ``sys.path`` first, then ``search_path``."""
    module_name, _, func_name = target.partition(":")
    module = _import(module_name, search_path)
    try:
        return getattr(module, func_name)
    except AttributeError:
        raise CampaignError(f"module '{module_name}' has no '{func_name}'; fix the "
                            f"simulator target '{target}'") from None


def _import(module_name: str, search_path: tuple[str, ...]) -> Any:
    """Import ``module_name`` from ``sys.path``, else from the folders of ``search_path``
    (appended to ``sys.path``)."""
    try:
        return importlib.import_module(module_name)
    except ModuleNotFoundError as err:
        if err.name != module_name.partition(".")[0] or not search_path:
            raise
        sys.path.extend(p for p in search_path if p not in sys.path)
        return importlib.import_module(module_name)


# --------------------------------------------------------------------------- one run
def execute_run(sim: Simulator, index: int, inputs: Mapping[str, float],
                timeout: float | None, expected: tuple[str, ...],
                log_folder: str | None = None) -> RunRecord:
    """Run ``sim`` once and return what the store records; never raises for a sim failure.

    Parameters
    ----------
    sim : Simulator
    index : int
        Run index (names a command's working directory ``run-00012``).
    inputs : mapping of str to float
    timeout : float or None
        Seconds; a Python call is then made in a child process that is killed on expiry.
    expected : tuple of str
        Outputs that must be present and finite for status ``ok``.
    log_folder : str, optional
        Where a Python call's standard output and error go (:mod:`calnet.campaign.logs`),
        for a call that does not share the campaign's process (a worker process's, or a
        timeout's child); None leaves them where they are (a timeout's child then sends
        them to its standard error). A command always writes logs in its run folder.
    """
    start = time.perf_counter()
    if isinstance(sim, CommandRunner):
        result = _guarded(lambda: sim(inputs, run=f"run-{index:05d}"))
    elif timeout is not None:
        result = call_in_child(sim, inputs, timeout, log_folder=log_folder)
    elif log_folder is not None:
        with logs.captured(Path(log_folder)), _cwd_kept():
            result = _guarded(lambda: sim(inputs))
    else:
        with _cwd_kept():
            result = _guarded(lambda: sim(inputs))
    status, outputs, message, diagnostics = _recorded(result, expected)
    return RunRecord(index, status, outputs, message, diagnostics,
                     time.perf_counter() - start)


def _recorded(result: SimResult, expected: tuple[str, ...]
              ) -> tuple[str, dict[str, float], str, dict[str, Any]]:
    """What the store keeps of ``result``: its status (failed for outputs that are
    missing or no finite number, or an unknown status), outputs as floats, message and
    JSON-serialisable diagnostics. Values the simulator made that cannot be read as such
    fail the run, saying so, rather than the campaign."""
    try:
        result = _checked(result, expected)
        if result.status not in STATUSES:
            result = SimResult(result.outputs, "failed", f"unknown status '{result.status}' "
                               f"(allowed {list(STATUSES)}): {result.message}",
                               result.diagnostics)
        outputs = {str(k): as_float(v) for k, v in result.outputs.items()}
    except Exception as err:
        return "failed", {}, f"cannot read the simulator's outputs: {_describe(err)}", {}
    try:
        diagnostics = _jsonable(result.diagnostics)
    except (TypeError, ValueError) as err:
        diagnostics = {"unreadable": f"{type(err).__name__}: {err}"}
    return result.status, outputs, result.message, diagnostics


def _checked(result: SimResult, expected: tuple[str, ...]) -> SimResult:
    """:meth:`SimResult.checked`, which also refuses a bool (True is no measurement) or
    None for a declared output."""
    if result.status != "ok":
        return result
    declared = expected or tuple(result.outputs)
    wrong = "; ".join(f"output '{k}' is {type(v).__name__} {v!r}, expected a number"
                      for k, v in result.outputs.items()
                      if k in declared and (v is None or isinstance(v, (bool, np.bool_))))
    if wrong:
        return SimResult(result.outputs, "failed", wrong, result.diagnostics)
    return result.checked(expected)


@contextmanager
def _cwd_kept() -> Iterator[None]:
    """Within the block, a simulator that changes the working directory (``os.chdir``)
    changes it for itself: it is set back on leaving."""
    try:
        cwd = os.getcwd()
    except OSError:  # it was removed: nothing to set back
        yield
        return
    try:
        yield
    finally:
        with suppress(OSError):
            if os.getcwd() != cwd:
                os.chdir(cwd)


def _guarded(call) -> SimResult:
    with _sigint_noted() as interrupted:
        try:
            result = call()
        except (Exception, SystemExit) as err:  # any simulator error (sys.exit too) is
            return SimResult({}, "failed", _describe(err))  # recorded, the campaign goes on
        except KeyboardInterrupt as err:
            # the user's Ctrl-C (or SIGTERM, raised as one) stops the campaign; a
            # KeyboardInterrupt the simulator raised itself is a failed run
            from calnet.campaign.interrupt import Terminated

            if interrupted() or isinstance(err, Terminated):
                raise
            return SimResult({}, "failed", _describe(err))
    if not isinstance(result, SimResult):
        return SimResult({}, "failed", f"simulator returned {type(result).__name__}, "
                         "expected a SimResult")
    return result


@contextmanager
def _sigint_noted() -> Iterator[Callable[[], bool]]:
    """Within the block, note whether SIGINT arrived (the handler in place still runs);
    yields the callable that says so. Where SIGINT raises no KeyboardInterrupt (ignored,
    as in a local worker process; default; off the main thread, where no signal handler
    runs) it always says no."""
    seen: list[int] = []
    if threading.current_thread() is not threading.main_thread():
        yield lambda: False
        return
    previous = signal.getsignal(signal.SIGINT)
    if not callable(previous):
        yield lambda: False
        return

    def note(signum: int, frame: Any) -> None:
        seen.append(signum)
        previous(signum, frame)

    signal.signal(signal.SIGINT, note)
    try:
        yield lambda: bool(seen)
    finally:
        signal.signal(signal.SIGINT, previous)


def _describe(err: BaseException) -> str:
    """A simulator's exception as a run's message: ``ValueError: bad mesh (at sim.py:12)``.

    The place is the last frame of the traceback outside calnet's adapters and Python's
    import machinery (none for an error those raised: a module not found, its syntax);
    calnet's own error (:class:`~calnet.errors.CampaignError`) is its message alone. A
    MemoryError says that memory ran out (and asks for a fresh worker process, which
    the leaked memory does not follow: :func:`~calnet.campaign.executors.replace_this_worker`);
    a KeyboardInterrupt says that the simulator raised it."""
    text = str(err)
    if isinstance(err, CampaignError):
        return text
    frame = [f for f in traceback.extract_tb(err.__traceback__) if not _internal(f.filename)
             ][-1:] if err.__traceback__ else []
    at = f"at {Path(frame[0].filename).name}:{frame[0].lineno}" if frame else ""
    if isinstance(err, MemoryError):
        replace_this_worker()
        return f"MemoryError (out of memory){': ' + text if text else ''}{' ' + at if at else ''}"
    name = type(err).__name__
    if isinstance(err, KeyboardInterrupt):
        name = "the simulator raised KeyboardInterrupt"
    if isinstance(err, ModuleNotFoundError) and not at:  # the simulator's module itself
        return (f"{name}: {text}; put the module beside the spec or on PYTHONPATH, or fix "
                "the simulator target")
    return f"{name}{': ' + text if text else ''}{f' ({at})' if at else ''}"


_INTERNAL = (os.path.dirname(os.path.abspath(__file__)),
             os.path.dirname(os.path.abspath(importlib.__file__)))


def _internal(filename: str) -> bool:
    """Whether a traceback's file is calnet's adapters' or Python's import machinery's."""
    return filename.startswith("<frozen ") or os.path.dirname(os.path.abspath(filename)) \
        in _INTERNAL


def call_in_child(sim: Simulator, inputs: Mapping[str, float], timeout: float, *,
                  startup_timeout: float = 300.0, log_folder: str | None = None) -> SimResult:
    """Call ``sim(inputs)`` in a fresh Python process, killed after ``timeout`` seconds.

    The clock starts once the child has imported the simulator (it says so on stdout), so
    a slow interpreter start on a busy machine does not count against the run. The child
    inherits this process's ``sys.path``; a crash of the child (segfault, ``os._exit``)
    is recorded as ``failed``. What the simulator prints goes to ``log_folder``'s logs,
    or without one to the child's standard error (never into the answer on stdout).
    """
    payload = pickle.dumps((list(sys.path), sim, dict(inputs), log_folder))
    argv = [sys.executable, "-c", "from calnet.campaign.runners import child_main; child_main()"]
    with _process_group(argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                        stderr=subprocess.PIPE) as proc:
        try:
            proc.stdin.write(payload)
            proc.stdin.close()
            proc.stdin = None
            ready = _wait_ready(proc, startup_timeout)
            out, err = proc.communicate(timeout=timeout if ready else 0.1)
        except subprocess.TimeoutExpired:
            _kill_group(proc)
            out, err = proc.communicate()
            if ready:
                folder = Path(log_folder) if log_folder else None
                if folder is not None:
                    logs.tidy(folder)  # the child had no time to
                return SimResult({}, "timeout", f"run exceeded its timeout of {timeout:g} s "
                                 "and was killed"
                                 + (logs.where(folder) if folder is not None else ""))
    if proc.returncode != 0 or not out:
        tail = err.decode(errors="replace").strip().splitlines()[-2:]
        folder = Path(log_folder) if log_folder else None
        if folder is not None and ready:  # the child's stderr went to its log
            tail = logs.tail(folder, lines=2) or tail
        what = "died" if ready else "did not start"
        return SimResult({}, "failed", f"simulator process {what} ({_code(proc.returncode)})"
                         + (f": {' | '.join(tail)}" if tail else "")
                         + (logs.where(folder) if folder is not None else ""))
    return pickle.loads(out)  # noqa: S301 (our own child's answer)


def _wait_ready(proc: subprocess.Popen, timeout: float) -> bool:
    """Wait for the child's one-byte "ready" mark on stdout."""
    fd = proc.stdout.fileno()
    readable, _, _ = select.select([fd], [], [], timeout)
    return bool(readable) and os.read(fd, 1) == _READY


_READY = b"\x00"


def child_main() -> None:
    """Entry point of :func:`call_in_child`'s process: pickle in on stdin, out on stdout."""
    path, sim, inputs, log_folder = pickle.loads(sys.stdin.buffer.read())  # noqa: S301
    sys.path[:] = path
    answer = os.fdopen(os.dup(1), "wb")  # the simulator's prints go elsewhere
    fds = logs.open_logs(Path(log_folder)) if log_folder else None
    os.dup2(fds[0] if fds else 2, 1)
    if fds:
        os.dup2(fds[1], 2)
    answer.write(_READY)
    answer.flush()
    result = _guarded(lambda: sim(inputs))
    for stream in (sys.stdout, sys.stderr):
        stream.flush()
    if log_folder:
        logs.tidy(Path(log_folder))
    answer.write(pickle.dumps(result))
    answer.flush()


def _run_killable(argv: list[str], cwd: Path | None, timeout: float | None,
                  stdout: int = subprocess.PIPE, stderr: int = subprocess.PIPE, *,
                  stdin: str | bytes | None = None, text: bool = True):
    """``subprocess.run`` in its own session (its output to ``stdout`` and ``stderr``:
    pipes, read into the result, or open files); on timeout kill the whole process group
    and return None."""
    with _process_group(argv, cwd=cwd, stdin=subprocess.PIPE if stdin else subprocess.DEVNULL,
                        stdout=stdout, stderr=stderr, text=text) as proc:
        try:
            out, err = proc.communicate(stdin, timeout=timeout)
        except subprocess.TimeoutExpired:
            _kill_group(proc)
            proc.communicate()
            return None
    return subprocess.CompletedProcess(argv, proc.returncode, out, err)


@contextmanager
def _process_group(argv: list[str], **kwargs: Any) -> Iterator[subprocess.Popen]:
    """``Popen`` in a new session (so its own process group), which is killed as a whole
    when the block is left by an exception, or by the reaper when this process dies."""
    proc = subprocess.Popen(argv, start_new_session=True, **kwargs)
    reaper.watch(proc.pid)
    try:
        yield proc
    finally:
        if proc.returncode is None:
            _kill_group(proc)
            proc.wait()
        reaper.unwatch(proc.pid)


def _code(returncode: int) -> str:
    """``exit code 3``, or ``killed by signal SIGSEGV (11)`` for a negative return code."""
    if returncode >= 0:
        return f"exit code {returncode}"
    try:
        name = signal.Signals(-returncode).name
    except ValueError:
        return f"killed by signal {-returncode}"
    return f"killed by signal {name} ({-returncode})"


def _ended(returncode: int) -> str:
    """``exited with code 3``, or ``was killed by signal SIGSEGV (11)``."""
    return (f"exited with code {returncode}" if returncode >= 0
            else f"was {_code(returncode)}")


def _kill_group(proc: subprocess.Popen) -> None:
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        proc.kill()


# --------------------------------------------------------------------------- helpers
_FIELD = re.compile(r"\{([A-Za-z_][A-Za-z0-9_]*)\}")


def _substitute(arg: str, values: Mapping[str, str]) -> str:
    """Replace ``{name}`` fields of one argument; unknown names are an error."""
    def one(match: re.Match) -> str:
        key = match.group(1)
        if key not in values:
            raise CampaignError(f"command argument '{arg}' names '{{{key}}}', which is not an "
                                f"input, parameter or option; known: {sorted(values)}")
        return values[key]

    return _FIELD.sub(one, arg)


def _check_template(argv: tuple[str, ...], names: tuple[str, ...]) -> None:
    known = {*names, "input_json", "output_json", "workdir", "run"}
    for arg in argv:
        unknown = [k for k in _FIELD.findall(arg) if k not in known]
        if unknown:
            raise CampaignError(f"command argument '{arg}' names {{{unknown[0]}}}, which is "
                                f"not an input, parameter or option; known: {sorted(known)}")


def resolve_program(argv: tuple[str, ...], network: Network) -> tuple[str, ...]:
    """Absolute paths for a command's files, relative to the spec's folder.

    The program, when given as a relative path (``./sim.sh``, ``bin/sim``), and every
    later argument that names an existing file or folder beside the spec (``sim.py``,
    ``meshes/plate.msh``; not an option ``-x``, not a template ``{...}``), since the
    program runs in its run's own folder.
    """
    root = Path(network.root).resolve()
    program = argv[0]
    if os.sep in program and not os.path.isabs(program):
        program = str(root / program)
    return (program, *(_beside_spec(arg, root) for arg in argv[1:]))


def _beside_spec(arg: str, root: Path) -> str:
    if not arg or arg.startswith("-") or _FIELD.search(arg) or os.path.isabs(arg):
        return arg
    path = root / arg
    return str(path) if path.exists() else arg


def _read(path: Path) -> str:
    try:
        return path.read_text()
    except FileNotFoundError:
        return ""


def _parse_outputs(text: str, mode: str, expected: tuple[str, ...] = ()) -> SimResult:
    where = "standard output" if mode == "stdout" else "output.json"
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as err:
        doc = _last_json_line(text) if mode == "stdout" else None
        if doc is None and mode == "stdout":
            return SimResult({}, "failed", "no line of standard output is a JSON object "
                             f"(it read {_excerpt(text)}); print the outputs as one JSON "
                             "object on a line of their own, such as {\"y\": 1.5}")
        if doc is None:
            return SimResult({}, "failed", f"cannot read a JSON object from {where} ({err}; "
                             f"it holds {_excerpt(text)})")
    if not isinstance(doc, dict):
        return SimResult({}, "failed", f"{where} holds {type(doc).__name__}, expected a "
                         "JSON object of outputs")
    status = str(doc.pop("status", "ok"))
    message = str(doc.pop("message", ""))
    # numbers as read (execute_run checks them: one too large for a float is named)
    outputs = {k: v for k, v in doc.items() if isinstance(v, (int, float)) or v is None}
    wrong = "; ".join([*(f"output '{k}' in {where} is bool {doc[k]!r}, expected a number"
                         for k in expected if isinstance(doc.get(k), bool)),
                       *filter(None, [not_numbers({k: doc[k] for k in expected if k in doc},
                                                  f" in {where}")])])
    if wrong and status == "ok":
        return SimResult(outputs, "failed", wrong)
    return SimResult(outputs, status, message)  # type: ignore[arg-type]  (execute_run
    # records an unknown status as failed, naming it)


def _last_json_line(text: str) -> dict[str, Any] | None:
    """The last line of a program's standard output that is a JSON object (the lines
    before it, a solver's log, are not read); None when no line is one."""
    for line in reversed(text.splitlines()):
        line = line.strip()
        if not line.startswith("{"):
            continue
        try:
            doc = json.loads(line)
        except json.JSONDecodeError:
            continue
        if isinstance(doc, dict):
            return doc
    return None


EXCERPT = 80  # characters of each end of a text a message quotes


def _excerpt(text: str) -> str:
    """``text`` for a message: empty, whole when short, else its start and its end."""
    if not text.strip():
        return "nothing"
    if len(text) <= 2 * EXCERPT + 5:
        return repr(text)
    return f"{text[:EXCERPT]!r} ... {text[-EXCERPT:]!r} ({len(text)} characters)"


def _jsonable(obj: Any) -> Any:
    """A JSON-serialisable copy (NumPy scalars/arrays to Python, others to strings)."""
    return json.loads(json.dumps(obj, default=_json_default))


def _json_default(obj: Any) -> Any:
    if hasattr(obj, "tolist"):
        return obj.tolist()
    return str(obj)
