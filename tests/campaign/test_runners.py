"""Simulator adapters: built-in, Python callable, external command, UM-Bridge."""

from __future__ import annotations

import math
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from campaign_helpers import HERE, toy_network

from calnet.campaign.runners import execute_run, make_simulator
from calnet.errors import CampaignError
from calnet.spec import parse_spec

POINT = {"x": 0.5, "a": 0.25, "b": -0.5}
EXPECTED = {"y": 0.5 * 0.5 + 0.25 * 0.5 - 0.5, "z": 1.0}


def _run(net, inputs=POINT, timeout=None, index=0):
    model = net.model(net.order[0])
    sim = make_simulator(net, model, workdir=Path(net.root) / "work")
    return execute_run(sim, index, inputs, timeout, model.output_names)


def test_builtin_solidification(tmp_path):
    box = {"lower": 1.0, "upper": 2.0}
    raw = {"models": {"solidification": {
        "simulator": "builtin:solidification",
        "inputs": {"S": {**box, "unit": "m/s"}, "G": {**box, "unit": "K/m"}},
        "parameters": {"sigma": {**box, "unit": "J/cm^2"}, "M": {**box, "unit": "cm^4/(J s)"},
                       "p_int": {**box, "unit": "cm^3/(J s)"}},
        "outputs": {"lambda": {"unit": "um"}, "k_V": {}}}}}
    net = parse_spec(raw, root=tmp_path)
    model = net.model("solidification")
    sim = make_simulator(net, model, workdir=tmp_path)
    rec = execute_run(sim, 0, {"S": 0.3, "G": 1e7, "sigma": 2e-6, "M": 7.5, "p_int": 15000},
                      None, model.output_names)
    assert rec.status == "ok" and sim.name == "solidification" and sim.version
    assert rec.outputs["lambda"] == pytest.approx(0.27, abs=0.01)


def test_callable_gets_options(tmp_path):
    spec = {"kind": "python", "target": "toy_sims:quadratic", "options": {"scale": 2.0}}
    rec = _run(toy_network(tmp_path, spec))
    assert rec.status == "ok"
    assert rec.outputs["y"] == pytest.approx(2 * EXPECTED["y"])


@pytest.mark.parametrize(("target", "inputs", "status", "message"), [
    ("crashy", {**POINT, "x": 0.9}, "failed", "RuntimeError: solver diverged"),
    ("nan_out", POINT, "failed", "non-finite outputs: 'y' = nan"),
    ("nonconverged", {**POINT, "a": 0.1}, "nonconverged", "residual"),
    ("exits", {**POINT, "x": 0.95}, "failed", "SystemExit: 4"),
])
def test_failures_are_results_not_exceptions(tmp_path, target, inputs, status, message):
    rec = _run(toy_network(tmp_path, f"python:toy_sims:{target}"), inputs)
    assert rec.status == status
    assert message in rec.message


@pytest.mark.parametrize(("kind", "message"), [
    ("str", "output 'y' is str 'abc', expected a number"),
    ("list", "output 'y' is list [1.0, 2.0], expected a number"),
    ("array", "output 'y' is ndarray of shape (1,), expected a number"),
    ("result", "output 'y' is str '1.5', expected a number"),
    ("numstr", "output 'y' is str '1.5', expected a number"),  # as in a command's JSON
    ("numpy", ""),
    ("0-d", ""),
])
def test_an_output_of_the_wrong_type_is_named(tmp_path, kind, message):
    spec = {"kind": "python", "target": "toy_sims:wrong_type", "options": {"kind": kind}}
    rec = _run(toy_network(tmp_path, spec))
    assert (rec.status, rec.message) == ("failed" if message else "ok", message)
    y = rec.outputs["y"]  # stored as before: the number, or NaN
    assert (y == 1.5) if kind in ("result", "numstr", "numpy", "0-d") else math.isnan(y)


def test_an_output_under_another_name_names_what_was_returned(tmp_path):
    spec = {"kind": "python", "target": "toy_sims:misnamed", "options": {"shape": "renamed"}}
    rec = _run(toy_network(tmp_path, spec))
    assert rec.status == "failed"
    assert rec.message == ("missing outputs ['y'] (it returned ['yy', 'z']); return each "
                           "declared output by its name")


def test_a_hung_call_is_killed_at_its_timeout(tmp_path):
    net = toy_network(tmp_path, "python:toy_sims:hangs")
    start = time.perf_counter()
    rec = _run(net, {**POINT, "x": 0.1}, timeout=1.0)
    assert rec.status == "timeout" and "timeout of 1 s" in rec.message
    assert time.perf_counter() - start < 30
    assert _run(net, POINT, timeout=30.0).outputs == pytest.approx(EXPECTED)


def test_a_hard_crash_in_the_child_is_recorded(tmp_path):
    rec = _run(toy_network(tmp_path, "python:toy_sims:dies"), {**POINT, "x": 0.95}, timeout=30)
    assert rec.status == "failed" and "exit code 7" in rec.message


def _command(*args, **kw):
    return {"kind": "command", "argv": [sys.executable, str(HERE / "cmd_sim.py"), *args], **kw}


def test_command_json_files_and_per_run_folder(tmp_path):
    net = toy_network(tmp_path, _command("json", "{input_json}", "{output_json}"))
    rec = _run(net, index=12)
    assert rec.status == "ok" and rec.outputs == pytest.approx(EXPECTED)
    assert (tmp_path / "work" / "run-00012" / "input.json").is_file()


@pytest.mark.parametrize("mode", ["args", "chatty"])
def test_command_args_and_stdout(tmp_path, mode):
    # chatty: the outputs are the last line of standard output that is a JSON object
    net = toy_network(tmp_path, _command(mode, "{x}", "{a}", "{b}", input_mode="args",
                                         output_mode="stdout"))
    rec = _run(net)
    assert rec.status == "ok" and rec.outputs == pytest.approx(EXPECTED)


def test_command_values_are_never_run_through_a_shell(tmp_path):
    evil = "$(touch pwned); touch pwned2 && echo"
    net = toy_network(tmp_path, _command("echo", "{label}", "{output_json}",
                                         options={"label": evil}))
    rec = _run(net)
    assert rec.status == "ok"
    folder = tmp_path / "work" / "run-00000"
    assert (folder / "output.json.txt").read_text() == evil
    assert not list(tmp_path.rglob("pwned*"))


@pytest.mark.parametrize(("mode", "timeout", "status", "message"), [
    ("fail", None, "failed", "exited with code 3: mesh generation failed"),
    ("hang", 1.0, "timeout", "timeout of 1 s"),
    ("status", None, "failed", "unknown status 'exploded'"),
    ("strnum", None, "failed", "output 'y' in standard output is str '1.5', expected a number"),
    ("nojson", None, "failed", "no line of standard output is a JSON object (it read "
     "'iteration 0 residual 1.000e+00\\niteration 1 residual 5.000e-01\\niteration 2 r"),
    ("nojson", None, "failed", "' ... 'ual 3.356e-03\\niteration 298 residual 3.344e-03\\n"
     "iteration 299 residual 3.333e-03\\n' (9790 characters)); print the outputs as one "
     "JSON object on a line of their own"),
])
def test_command_failures(tmp_path, mode, timeout, status, message):
    kw = {"timeout": timeout} if timeout else {}
    net = toy_network(tmp_path, _command(mode, output_mode="stdout", **kw))
    rec = _run(net)
    assert rec.status == status and message in rec.message
    assert rec.wall_time < 30


@pytest.mark.parametrize("script", ["cmd_sim.py", str(HERE / "cmd_sim.py")])
def test_command_paths_hold_from_a_relative_spec_path(tmp_path, monkeypatch, script):
    """``calnet campaign network.yaml`` from the spec's folder: the files calnet passes
    (``{input_json}``, ``{output_json}``) and a script beside the spec are given to the
    program, which runs in its run folder, as absolute paths."""
    from calnet.campaign import run_campaign
    from calnet.spec import load_spec

    (tmp_path / "cmd_sim.py").write_text((HERE / "cmd_sim.py").read_text())
    toy_network(tmp_path, {"kind": "command", "argv": [sys.executable, script, "json",
                                                       "{input_json}", "{output_json}"]},
                runs=3)
    monkeypatch.chdir(tmp_path)
    summary = run_campaign(load_spec("network.yaml"), "toy", progress=False)
    assert summary.status_counts == {"ok": 3}, summary.failures


def test_command_template_names_are_checked(tmp_path):
    net = toy_network(tmp_path, _command("json", "{inptu_json}"))
    with pytest.raises(CampaignError, match="names {inptu_json}"):
        make_simulator(net, net.model("toy"), workdir=tmp_path)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def umbridge_url():
    """A UM-Bridge server in a subprocess on a free loopback port; stopped at the end."""
    import requests

    port = _free_port()
    proc = subprocess.Popen([sys.executable, str(HERE / "umbridge_server.py"), str(port)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    url = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 60
        while True:
            try:
                with requests.get(f"{url}/Info", timeout=1) as response:
                    if response.ok:
                        break
            except requests.ConnectionError:
                pass
            if proc.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"UM-Bridge test server did not start: "
                                   f"{proc.stderr.read().decode()[-500:]}")
            time.sleep(0.1)
        yield url
    finally:
        proc.terminate()
        proc.wait(timeout=10)
        proc.stderr.close()


def test_umbridge_model(tmp_path, umbridge_url):
    net = toy_network(tmp_path, {"kind": "umbridge", "url": umbridge_url, "model": "forward",
                                 "options": {"scale": 3.0}})
    rec = _run(net)
    assert rec.status == "ok"
    assert rec.outputs["y"] == pytest.approx(3 * EXPECTED["y"])
    assert rec.outputs["z"] == pytest.approx(EXPECTED["z"])
    assert not math.isnan(rec.wall_time)


def test_umbridge_server_down_or_not_umbridge(tmp_path):
    """No server at the url, or a server that is no UM-Bridge server: each run is a
    failure that says so, not a raw ConnectionError / JSONDecodeError."""
    import http.server
    import threading

    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        free = s.getsockname()[1]
    net = toy_network(tmp_path, {"kind": "umbridge", "url": f"http://127.0.0.1:{free}",
                                 "model": "forward"})
    rec = _run(net)
    assert rec.status == "failed" and "no UM-Bridge server answers at" in rec.message

    class Page(http.server.BaseHTTPRequestHandler):  # answers every request with HTML
        def do_GET(self):
            self.send_response(200)
            self.end_headers()
            self.wfile.write(b"<html>hello</html>")

        do_POST = do_GET

        def log_message(self, *args):
            pass

    server = http.server.HTTPServer(("127.0.0.1", 0), Page)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        net = toy_network(tmp_path / "html", {"kind": "umbridge", "model": "forward",
                                              "url": f"http://127.0.0.1:{server.server_port}"})
        rec = _run(net)
    finally:
        server.shutdown()
    assert rec.status == "failed" and "did not answer as a UM-Bridge server" in rec.message


def test_numpy_scalars_in_a_sim_result_are_numbers():
    """A simulator's own SimResult may hold NumPy scalars (float32, int64): they are
    finite numbers, stored as Python floats; NaN of any type stays non-finite."""
    import numpy as np

    from calnet.simulators.base import SimResult

    res = SimResult({"y": np.float32(1.5), "z": np.int64(2)}).checked(("y", "z"))
    assert res.status == "ok" and res.outputs == {"y": 1.5, "z": 2.0}
    assert all(type(v) is float for v in res.outputs.values())
    bad = SimResult({"y": np.float32("nan"), "z": 1.0}).checked(("y", "z"))
    assert bad.status == "failed" and bad.message == "non-finite outputs: 'y' = nan"


@pytest.mark.parametrize(("kind", "message"), [
    ("bool", "output 'y' is bool True, expected a number"),
    ("none", "output 'y' is NoneType None, expected a number"),
    ("nan", "non-finite outputs: 'y' = nan"),
    ("inf", "non-finite outputs: 'y' = -inf"),
    ("huge", "output 'y' is an integer of about 1e400, too large for a float (at most "
     "1.8e+308)"),
])
def test_an_output_that_is_no_finite_number_says_what_it_is(tmp_path, kind, message):
    net = toy_network(tmp_path, {"kind": "python", "target": "toy_sims:odd_outputs",
                                 "options": {"kind": kind}})
    rec = _run(net)
    assert (rec.status, rec.message) == ("failed", message)


def test_a_command_output_true_is_no_number(tmp_path):
    from calnet.campaign.runners import _parse_outputs

    res = _parse_outputs('{"y": true, "z": 1}', "json-file", ("y", "z"))
    assert res.status == "failed"
    assert res.message == "output 'y' in output.json is bool True, expected a number"


@pytest.mark.parametrize(("executor", "timeout"), [("processes", None),
                                                   ("in-process", None), ("auto", 30.0)])
def test_a_keyboard_interrupt_the_simulator_raises_is_a_failed_run(tmp_path, executor,
                                                                   timeout):
    """No signal came: the simulator raised KeyboardInterrupt itself. The run is
    recorded failed, saying so, and the campaign goes on (in a worker process, in this
    process, in a timeout's child alike)."""
    from calnet.campaign import run_campaign

    net = toy_network(tmp_path, "python:toy_sims:raises_interrupt", runs=8, timeout=timeout)
    summary = run_campaign(net, "toy", executor=executor, progress=False)
    assert summary.complete and 0 < summary.n_failed < 8
    for message in summary.failures.values():
        assert message.startswith("failed: the simulator raised KeyboardInterrupt: solver "
                                  "caught Ctrl-C (at toy_sims.py:"), message


def test_a_ctrl_c_during_an_in_process_run_still_stops_the_campaign(tmp_path):
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        pytest.skip("signals reach the main thread only")
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt):
            _run(toy_network(tmp_path, "python:toy_sims:interrupted_by_user"))
    finally:
        signal.signal(signal.SIGINT, previous)


@pytest.mark.parametrize(("workers", "timeout"), [(1, None), (None, 30.0)])
def test_what_a_python_simulator_prints_goes_to_its_runs_logs(tmp_path, capfd, workers,
                                                               timeout):
    # a worker process (no timeout), or a timeout's child process
    from calnet.campaign import run_campaign

    net = toy_network(tmp_path, "python:toy_sims:chatty", runs=3, timeout=timeout)
    summary = run_campaign(net, "toy", workers=workers, progress=False)
    assert summary.status_counts == {"ok": 3}, summary.failures
    out, err = capfd.readouterr()
    assert "iteration" not in out + err and "from C" not in out + err
    work = tmp_path / "campaigns" / "toy.work"
    for run in range(3):
        logged = (work / f"run-{run:05d}" / "stdout.log").read_text().splitlines()
        assert logged[0] == "iteration 0 residual 1.0" and "from C" in logged
        assert (work / f"run-{run:05d}" / "stderr.log").read_text() == (
            "warning: mesh is coarse\n")
    assert summary.notes == (f"what the simulator printed is in {work}/run-NNNNN/stdout.log "
                             "and stderr.log (3 runs of this call, the first run 0)",)


def test_what_a_command_prints_goes_to_its_runs_logs(tmp_path):
    net = toy_network(tmp_path, _command("fail"))
    rec = _run(net, index=3)
    folder = tmp_path / "work" / "run-00003"
    assert rec.message == ("command exited with code 3: mesh generation failed (logs in "
                           f"{folder}: stderr.log)")
    assert (folder / "stderr.log").read_text() == "mesh generation failed\n"
    assert not (folder / "stdout.log").exists()  # an empty log is removed
    net = toy_network(tmp_path, _command("chatty", "{x}", "{a}", "{b}", input_mode="args",
                                         output_mode="stdout"))
    assert _run(net, index=4).status == "ok"
    assert "solver 2.1 starting" in (tmp_path / "work" / "run-00004" / "stdout.log").read_text()


@pytest.mark.parametrize("kind", ["nan", "text", "array", "bool", "none", "huge"])
def test_an_undeclared_output_that_is_no_finite_number_is_no_failure(tmp_path, kind):
    """The declared outputs are fine: the run is ok. An undeclared number is kept (NaN
    where it is none as a float), anything else is left out."""
    net = toy_network(tmp_path, {"kind": "python", "target": "toy_sims:extras",
                                 "options": {"kind": kind}})
    rec = _run(net)
    assert (rec.status, rec.message) == ("ok", "")
    assert {k: rec.outputs[k] for k in ("y", "z")} == pytest.approx(EXPECTED)
    if kind in ("nan", "huge"):
        assert math.isnan(rec.outputs["extra"])
    else:
        assert "extra" not in rec.outputs


@pytest.mark.parametrize(("mode", "status", "message"), [
    ("huge", "failed", "output 'y' is an integer of about 1e400, too large for a float"),
    ("extra", "ok", ""),
    ("killed", "failed", "command was killed by signal SIGKILL (9)"),
])
def test_command_outputs_and_ends_are_said_plainly(tmp_path, mode, status, message):
    rec = _run(toy_network(tmp_path, _command(mode, output_mode="stdout")))
    assert rec.status == status and rec.message.startswith(message), rec.message
    assert "Error" not in rec.message and "runners.py" not in rec.message


def test_a_command_that_writes_no_output_file_is_told_so(tmp_path):
    rec = _run(toy_network(tmp_path, _command("noout")))
    assert rec.status == "failed"
    assert rec.message.startswith("command wrote no output file output.json (in its run "
                                  "folder); write the outputs to {output_json}"), rec.message


@pytest.mark.parametrize(("target", "message"), [
    ("toy_sims:nosuchfn", "module 'toy_sims' has no 'nosuchfn'; fix the simulator target "
                          "'toy_sims:nosuchfn'"),
    ("no_such_toy_module:f", "ModuleNotFoundError: No module named 'no_such_toy_module'; "
                             "put the module beside the spec or on PYTHONPATH, or fix the "
                             "simulator target"),
])
def test_a_target_that_cannot_be_loaded_is_said_without_calnets_insides(tmp_path, target,
                                                                        message):
    rec = _run(toy_network(tmp_path, f"python:{target}"))
    assert (rec.status, rec.message) == ("failed", message)


def test_an_in_process_run_that_changes_directory_changes_it_for_itself(tmp_path,
                                                                        monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "elsewhere").mkdir()
    net = toy_network(tmp_path, {"kind": "python", "target": "toy_sims:moves",
                                 "options": {"to": str(tmp_path / "elsewhere")}})
    assert _run(net).status == "ok"
    assert Path.cwd() == tmp_path
