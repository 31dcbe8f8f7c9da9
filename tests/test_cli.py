"""What every command line has: a version, help that reads at 80 columns, no banners."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from importlib.metadata import version

import pytest
import typer
from typer.testing import CliRunner

import calnet
from calnet.cli import app

COMMANDS = sorted(typer.main.get_command(app).commands)


@pytest.mark.parametrize("flag", ["--version", "-V"])
def test_version(flag):
    result = CliRunner().invoke(app, [flag])
    assert result.exit_code == 0, result.output
    assert result.output == f"calnet {version('calnet')}\n"
    assert calnet.__version__ == version("calnet")


def _check_help(text: str, where: str) -> None:
    lines = text.splitlines()
    assert lines, where
    assert all(len(line) <= 80 for line in lines), (where, max(lines, key=len))
    assert "<bool>" not in text, where  # a flag shows its names, not a type
    assert "…" not in text, where  # nothing cut off (a default, a long word)
    assert not re.search(r"\[default: (False|True|no-\w+)\]", text), where


@pytest.mark.parametrize("command", [None, *COMMANDS])
def test_help_at_80_columns(command):
    args = [command, "--help"] if command else ["--help"]
    result = CliRunner().invoke(app, args, env={"COLUMNS": "80", "TERMINAL_WIDTH": None})
    assert result.exit_code == 0, result.output
    _check_help(result.output, command or "calnet")


def test_command_list_has_one_line_per_command():
    result = CliRunner().invoke(app, ["--help"], env={"COLUMNS": "80"})
    panel = result.output.split("Commands")[1].splitlines()[1:]
    rows = [line for line in panel if line.startswith("│")]
    assert [row.split()[1] for row in rows] == list(typer.main.get_command(app).commands)


def _env(**extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in ("COLUMNS", "LINES",
                                                            "TERMINAL_WIDTH")}
    src = os.path.join(os.path.dirname(calnet.__file__), os.pardir)
    env["PYTHONPATH"] = os.pathsep.join([os.path.abspath(src), env.get("PYTHONPATH", "")])
    return {**env, **extra}


def test_help_when_piped():
    """Help written to a pipe (no terminal, no COLUMNS): the same checks, every command."""
    code = ("import sys\nfrom calnet.cli import app\n"
            "for cmd in sys.argv[1:]:\n"
            "    try:\n"
            "        app([cmd, '--help'] if cmd != '-' else ['--help'], prog_name='calnet')\n"
            "    except SystemExit:\n"
            "        pass\n"
            "    print('=====')\n")
    out = subprocess.run([sys.executable, "-c", code, "-", *COMMANDS], capture_output=True,
                         text=True, env=_env(), timeout=120)
    assert out.returncode == 0, out.stderr
    pages = out.stdout.split("=====\n")[:-1]
    assert len(pages) == 1 + len(COMMANDS)
    for command, page in zip(["calnet", *COMMANDS], pages, strict=True):
        assert "Usage:" in page, command
        _check_help(page, command)


BANNER = "undergoing a major refactor"


def test_arviz_banner_is_kept_out(tmp_path):
    """ArviZ warns once a day at import (a stamp file in the user's cache) that it is
    being refactored; calnet imports it without that notice. A fresh cache folder makes
    the notice due; the bare import shows that it is."""

    def stderr_of(code: str, cache: str) -> str:
        out = subprocess.run([sys.executable, "-W", "always", "-c", code], text=True,
                             capture_output=True, env=_env(XDG_CACHE_HOME=str(tmp_path / cache),
                                                           CALNET_JAX_CACHE="off"),
                             timeout=120)
        assert out.returncode == 0, out.stderr
        return out.stdout + out.stderr

    if BANNER not in stderr_of("import arviz", "bare"):
        pytest.skip("this ArviZ has no refactor notice")
    code = ("from calnet.calibration.diagnostics import import_arviz\n"
            "import_arviz().from_dict(posterior={'x': [[0.0, 1.0]]})\n")
    assert BANNER not in stderr_of(code, "calnet")


@pytest.mark.parametrize(("argv", "message"), [
    (["simulate", "solidification", "--set", "S=0.3", "--set", "S=0.4"],
     "--set gives S twice; give each name once"),
    (["predict", "examples/ninb", "--at", "P=200,P=210,v=0.5"],
     "--at gives P twice; give each name once"),
    (["predict", "examples/ninb", "--at", "P=abc,v=0.5"], "--at P: 'abc' is not a number"),
    (["predict", "examples/ninb", "--at", "P=200,v=inf"], "--at v: 'inf' is not a finite"),
    (["predict", "examples/ninb", "--at", "P200"], "--at expects NAME=VALUE, got 'P200'"),
    (["predict", "examples/ninb", "--at", ","], "--at is empty"),
    (["predict", "examples/ninb"], "give the settings to predict at"),
    (["simulate", "solidification", "--set", "S=fast"], "--set S: 'fast' is not a number"),
    (["simulate", "solidification", "--option", "variant"], "--option expects NAME=VALUE"),
    (["simulate", "nosuch"], "unknown built-in simulator 'nosuch'"),
    (["simulate", "solidification", "--set", "X=3"], "'solidification' has no input or "
     "parameter ['X']"),
])
def test_a_malformed_option_value_is_a_one_line_usage_error(argv, message):
    """Exit code 2, as Typer's own usage errors, and one line naming the bad value."""
    result = CliRunner().invoke(app, argv, terminal_width=400)
    assert result.exit_code == 2, result.output
    assert result.output.startswith(f"error: {message}"), result.output
    assert len(result.output.strip().splitlines()) == 1, result.output


@pytest.mark.parametrize("argv, message", [
    (["melt_pool", "--set", "P=-5", "--set", "v=0.5"],
     "melt_pool: inputs ['P'] must be finite and positive"),
    (["melt_pool", "--set", "P=-5", "--set", "v=0.5", "--option", "time_limit=5"],
     "melt_pool: inputs ['P'] must be finite and positive"),  # not blamed on the option
    (["phase_field", "--set", "S=0.1", "--set", "G=-1e7"], "must be finite and > 0"),
    (["solidification", "--set", "S=-1", "--set", "G=1e7"],
     "S must be finite and > 0 (in m/s), got -1")])
def test_simulate_a_value_the_model_cannot_take_is_a_failed_run(argv, message):
    res = CliRunner().invoke(app, ["simulate", *argv])
    assert res.exit_code == 1, res.output
    def no_nan(word):  # strict JSON: a failed run's outputs are null, never NaN
        raise AssertionError(f"{word} in {res.stdout}")

    doc = json.loads(res.stdout, parse_constant=no_nan)
    assert doc["status"] == "failed" and message in doc["message"]
    assert "internal error" not in res.output and "Traceback" not in res.output
    assert "lies outside the box" in res.stderr and "is tested over" in res.stderr


def test_simulate_says_what_it_defaults_and_what_lies_outside_the_bounds():
    res = CliRunner().invoke(app, ["simulate", "solidification", "--set", "S=50"])
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout)
    assert doc["status"] == "ok"
    assert doc["units"]["lambda"] == "um" and doc["units"]["S"] == "m/s"  # with the numbers
    assert ("G not given: G=1.1e+07 K/m (the middle of the box solidification is tested "
            "over)") in res.stderr
    assert "S=50 m/s lies outside the box [0.05, 0.6] that solidification is tested over" \
        in res.stderr
    quiet = CliRunner().invoke(app, ["simulate", "solidification", "--set", "S=0.3", "--set",
                                     "G=1e7"])
    assert quiet.exit_code == 0 and quiet.stderr == ""


def test_a_read_only_output_folder_is_said_in_words(tmp_path, monkeypatch):
    import errno
    from pathlib import Path

    mkdir = Path.mkdir

    def refuse(self, *args, **kwargs):  # the folder under tmp_path is on a read-only disk
        if tmp_path in self.parents:
            raise OSError(errno.EROFS, "Read-only file system", str(self))
        return mkdir(self, *args, **kwargs)

    monkeypatch.setattr(Path, "mkdir", refuse)
    ninb = Path(__file__).parents[1] / "examples" / "ninb"
    res = CliRunner().invoke(app, ["surrogates", str(ninb), "--out", str(tmp_path / "x")])
    assert res.exit_code == 1, res.output
    assert res.output.strip() == (f"error: cannot write '{tmp_path / 'x'}': the file system "
                                  "is read-only (write to another folder)")


def test_a_ctrl_c_that_python_drops_still_exits_130(python_sigint):
    """A KeyboardInterrupt dropped where it was raised (Python drops it inside a gc
    callback) still ends the command with 130 and one line, not with 0."""
    import os
    import signal
    import time

    import typer

    from calnet.cli import user_errors

    def calibrate_like() -> None:
        try:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(30)  # ended by the interrupt as soon as it is delivered
        except KeyboardInterrupt:
            pass  # dropped
        print("finished")

    cmd = typer.Typer()
    cmd.command("calibrate")(user_errors(calibrate_like))
    cmd.command("other")(lambda: None)
    result = CliRunner().invoke(cmd, ["calibrate"])
    assert result.exit_code == 130, result.output
    assert result.stderr.strip() == "interrupted"  # one line; no campaign runs to keep here


@pytest.mark.parametrize(("name", "args", "said"), [
    ("run", [], "the same command resumes them (later stages start again)"),
    ("run", ["--fresh"], "the same command without --fresh resumes them (later stages"),
    ("campaign", [], "the same command resumes them"),
    ("campaign", ["--fresh"], "the same command without --fresh resumes them")])
def test_an_interrupted_run_or_campaign_says_which_command_resumes_it(name, args, said):
    """``--fresh`` deletes the finished runs: the command that resumes them is the same
    one without it."""
    import typer

    from calnet.cli import user_errors

    def command(fresh: bool = typer.Option(False, "--fresh")) -> None:
        raise KeyboardInterrupt

    command.__name__ = name
    cmd = typer.Typer()
    cmd.command(name)(user_errors(command))
    cmd.command("other")(lambda: None)
    result = CliRunner().invoke(cmd, [name, *args])
    assert result.exit_code == 130, result.output
    text = " ".join(result.stderr.split())
    assert text.startswith("interrupted: finished simulation runs are kept; " + said), text
    assert ("later stages" in text) == (name == "run")


def test_calnet_debug_shows_the_traceback_and_keeps_exit_code_3(monkeypatch):
    import typer

    from calnet.cli import user_errors

    def broken() -> None:
        raise ZeroDivisionError("a bug")

    cmd = typer.Typer()
    cmd.command("broken")(user_errors(broken))
    cmd.command("other")(lambda: None)
    monkeypatch.setenv("CALNET_DEBUG", "1")
    result = CliRunner().invoke(cmd, ["broken"])
    assert result.exit_code == 3, result.output
    assert "Traceback" in result.stderr and "internal error: ZeroDivisionError" in result.stderr


def test_seed_reaches_the_stages_after_the_campaign(monkeypatch, tmp_path):
    """``--seed`` of run and calibrate seeds the chains (and, for run, the stages after the
    campaign) without touching the spec, whose settings.seed the campaign designs keep."""
    import calnet.calibration.calibrate_network as calibrate_network
    import calnet.pipeline as pipeline

    seen = {}

    def run_pipeline(spec, **kwargs):
        seen["run"] = kwargs["seed"]

    monkeypatch.setattr(pipeline, "run_pipeline", run_pipeline)
    result = CliRunner().invoke(app, ["run", "examples/ninb", "--out", str(tmp_path),
                                      "--seed", "7"])
    assert result.exit_code == 0 and seen["run"] == 7, result.output

    class Stop(Exception):
        pass

    def calibrate(network, sur, **kwargs):
        seen["calibrate"] = kwargs["seed"]
        raise Stop

    import calnet.surrogates.fit_network as fit_network

    monkeypatch.setattr(fit_network.Surrogates, "load", classmethod(lambda cls, d: None))
    monkeypatch.setattr(fit_network, "check_surrogates", lambda *a: None)
    monkeypatch.setattr(calibrate_network, "calibrate", calibrate)
    result = CliRunner().invoke(app, ["calibrate", "examples/ninb", "--out",
                                      str(tmp_path / "p"), "--seed", "3"])
    assert isinstance(result.exception, Stop) or seen.get("calibrate") == 3, result.output
    assert seen["calibrate"] == 3


def _signalled(script: str, *signals) -> tuple[int, str, float]:
    """Run ``script`` in a Python process; once it prints "ready", send ``signals`` 1.5 s
    apart. Its exit code, its stderr, and the seconds it took to end after the last."""
    import time

    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "ready"
        for i, sig in enumerate(signals):
            if i:
                time.sleep(1.5)
            t0 = time.monotonic()
            proc.send_signal(sig)
        _, err = proc.communicate(timeout=30)
    finally:
        proc.kill()
    return proc.returncode, err, time.monotonic() - t0


_HOLD = """
import contextlib, sys, time
import typer
from calnet.campaign.interrupt import sigterm_exit
from calnet.interrupts import program_running
try:
    with sigterm_exit("run"):
        with ({hold}):
            print("ready", flush=True)
            time.sleep(60)
except typer.Exit as done:  # as the command line ends
    sys.exit(done.exit_code)
"""


@pytest.mark.parametrize("in_flight", [True, False])
def test_sigterm_while_a_compiled_program_runs_ends_at_once(in_flight):
    """A batch system's SIGTERM while the sampler's program runs (which nothing can stop)
    ends calnet run at once with 143 and one line, instead of waiting for the program;
    elsewhere it unwinds as Ctrl-C does, with the same code."""
    import signal

    hold = "program_running()" if in_flight else "contextlib.nullcontext()"
    code, err, took = _signalled(_HOLD.format(hold=hold), signal.SIGTERM)
    assert code == 143 and took < 10, err
    text = " ".join(err.split())
    said = "ended at once" in text
    assert said == in_flight and "finished simulation runs are kept" in text, text
    assert "Traceback" not in err


def test_the_sampler_marks_its_program_in_flight(monkeypatch):
    import calnet.calibration.sampling as sampling
    from calnet.interrupts import program_in_flight

    seen = []
    monkeypatch.setattr(sampling.jax, "block_until_ready",
                        lambda x: seen.append(program_in_flight()) or x)
    assert sampling._finished("out", "joint", None) == "out"
    assert seen == [True] and not program_in_flight()


def test_a_warning_or_error_with_brackets_is_printed_whole():
    """Text such as 'settings.compare: [reference]' is not taken for console markup."""
    import warnings as w

    from calnet.cli import user_errors
    from calnet.errors import CalnetError

    def warns() -> None:
        w.warn("try settings.compare: [reference]", UserWarning, stacklevel=1)

    def fails() -> None:
        raise CalnetError("give [bold] or [reference]")

    cmd = typer.Typer()
    cmd.command("warns")(user_errors(warns))
    cmd.command("fails")(user_errors(fails))
    said = CliRunner().invoke(cmd, ["warns"])
    assert "settings.compare: [reference]" in said.stderr, said.stderr
    failed = CliRunner().invoke(cmd, ["fails"])
    assert failed.exit_code == 1 and "give [bold] or [reference]" in failed.stderr


def test_a_ctrl_c_after_the_run_finished_says_its_results_are_complete(tmp_path, monkeypatch,
                                                                        python_sigint):
    """Ctrl-C as calnet run ends (its folder complete) still exits 130, but does not say
    that later stages start again."""
    import signal
    import time

    import calnet.pipeline as pipeline
    from calnet.cli import app

    def finished(*args, **kwargs):
        try:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(30)  # ended by the interrupt as soon as it is delivered
        except KeyboardInterrupt:
            pass  # dropped, as in a clean-up; the latch still has it
        return {}

    monkeypatch.setattr(pipeline, "run_pipeline", finished)
    result = CliRunner().invoke(app, ["run", "examples/ninb", "--out", str(tmp_path)])
    assert result.exit_code == 130, result.output
    text = " ".join(result.stderr.split())
    assert text == f"interrupted after the run had finished: its results in '{tmp_path}' are " \
                   "complete", text


_TWICE = """
import time
import calnet.calibration.sampling as sampling
from calnet.interrupts import ending_allowed


def chains(pending):  # chains that run on; ready once the sampler waits for them
    print("ready", flush=True)
    time.sleep(60)


sampling.jax.block_until_ready = chains
with ending_allowed("kept"):
    sampling._finished("out", "joint", None)
"""


def test_a_second_ctrl_c_while_the_chains_run_ends_a_command_at_once(python_sigint):
    """The first Ctrl-C waits for the chains in flight and says that a second ends the
    process; the second does, with 130 and one line (the child inherits SIGINT handled,
    not ignored as in a shell's background job)."""
    import signal

    code, err, took = _signalled(_TWICE, signal.SIGINT, signal.SIGINT)
    assert code == 130 and took < 10, err
    lines = err.strip().splitlines()
    assert lines[0] == ("joint: stopping once the chains in flight end (a running program "
                        "cannot be interrupted; Ctrl-C again ends the process at once)"), err
    assert lines[-1] == ("interrupted (Ctrl-C again while the chains ran): ended at once; "
                         "kept"), err


_LEFT_RUNNING = """
import sys, threading, time
import jax  # a compiled program may be in flight: the exit must not wait or clean up
import calnet.cli as cli

def interrupted(prog_name=None):
    threading.Thread(target=time.sleep, args=(60,)).start()  # work left running
    print("said before the exit", flush=False)
    raise SystemExit(CODE)

cli.app = interrupted
cli.main()
"""


@pytest.mark.parametrize("code", [130, 143])
def test_the_console_script_ends_at_once_after_an_interrupt(code):
    """After Ctrl-C (130) or SIGTERM (143) the ``calnet`` script exits at once, with the
    code, its output flushed: the interpreter's clean-up would wait for (or crash under)
    work still running in other threads, such as an XLA program. Other exits are left
    to the interpreter."""
    import time

    t0 = time.monotonic()
    out = subprocess.run([sys.executable, "-c", _LEFT_RUNNING.replace("CODE", str(code))],
                         capture_output=True, text=True, timeout=50)
    assert out.returncode == code, out.stderr
    assert out.stdout == "said before the exit\n"
    assert time.monotonic() - t0 < 30


def test_the_console_script_is_main():
    """``calnet`` and ``python -m calnet`` run :func:`calnet.cli.main`."""
    from importlib.metadata import entry_points

    (script,) = [e for e in entry_points(group="console_scripts") if e.name == "calnet"]
    assert script.value == "calnet.cli:main"
    out = subprocess.run([sys.executable, "-m", "calnet", "--version"], capture_output=True,
                         text=True, timeout=60)
    assert out.returncode == 0 and out.stdout.startswith("calnet "), out.stderr


_LEFT_POOL = """
import multiprocessing, time
from concurrent.futures import ProcessPoolExecutor
import jax  # the exit after an interrupt is then immediate
import calnet.cli as cli

def interrupted(prog_name=None):
    pool = ProcessPoolExecutor(2, mp_context=multiprocessing.get_context("spawn"))
    pool.submit(time.sleep, 0.1).result()  # a campaign's workers, their queues' semaphores
    workers = list(pool._processes.values())
    pool.shutdown(wait=False, cancel_futures=True)  # as the campaign's executor does
    for worker in workers:
        worker.terminate()
        worker.join()
    raise SystemExit(130)

if __name__ == "__main__":
    cli.app = interrupted
    cli.main()
"""


def test_an_interrupted_run_with_worker_processes_says_nothing_of_leaked_semaphores(
        tmp_path):
    """The immediate exit after Ctrl-C leaves a campaign's process pool to
    multiprocessing's resource tracker, which cleans it up; its warning about "leaked
    semaphore objects" is not printed."""
    script = tmp_path / "left_pool.py"
    script.write_text(_LEFT_POOL)
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 130, out.stderr
    assert "resource_tracker" not in out.stderr and "leaked" not in out.stderr, out.stderr
