"""Graph queries on general DAGs and the Python API building the same objects as YAML."""

from __future__ import annotations

import pytest
import yaml
from typer.testing import CliRunner

from calnet.cli import app
from calnet.errors import SpecError
from calnet.spec import Input, Link, Model, Network, Output, SimulatorRef, parse_spec

SIM = SimulatorRef(kind="python", target="toy:f")


def _model(name: str, inputs: list[str], outputs: list[str]) -> Model:
    return Model(name=name, simulator=SIM,
                 inputs=[Input(name=i, lower=0, upper=1) for i in inputs],
                 outputs=[Output(name=o) for o in outputs])


def branch_network() -> Network:
    """thermal feeds micro and stress; micro and stress both feed property (4 models)."""
    models = [
        _model("property", ["lam", "sig"], ["y"]),  # declared first on purpose
        _model("thermal", ["P", "v"], ["G", "T"]),
        _model("micro", ["G", "S"], ["lam"]),
        _model("stress", ["T"], ["sig"]),
    ]
    links = [Link(**{"from": a, "to": b}) for a, b in [
        ("thermal.G", "micro.G"), ("thermal.v", "micro.S"), ("thermal.T", "stress.T"),
        ("micro.lam", "property.lam"), ("stress.sig", "property.sig")]]
    return Network(name="branch", models=models, links=links)


def test_branching_dag_order_and_queries():
    net = branch_network()
    order = net.order
    assert order[0] == "thermal" and order[-1] == "property"
    assert order.index("micro") < order.index("property") > order.index("stress")
    assert net.children("thermal") == ("micro", "stress")
    assert set(net.parents("property")) == {"micro", "stress"}
    assert net.ancestors("property") == ("thermal", "micro", "stress")
    assert net.process_inputs("property") == (("thermal", "P"), ("thermal", "v"))
    assert [v.name for v in net.free_inputs("micro")] == []
    assert [o.name for o in net.needed_outputs("thermal")] == ["G", "T"]


def test_yaml_and_python_api_build_equal_objects():
    raw = {"name": "branch", "models": [m.model_dump(by_alias=True) for m in
                                        branch_network().models],
           "links": [ln.model_dump(by_alias=True) for ln in branch_network().links]}
    assert parse_spec(raw, root=".", source="") == branch_network()


def test_spec_objects_are_frozen():
    net = branch_network()
    with pytest.raises(Exception, match="frozen"):
        net.name = "other"  # type: ignore[misc]


def test_two_links_into_one_input_rejected():
    models = [_model("a", ["x"], ["y"]), _model("b", ["x"], ["y"]), _model("c", ["u"], ["z"])]
    links = [Link(**{"from": "a.y", "to": "c.u"}), Link(**{"from": "b.y", "to": "c.u"})]
    with pytest.raises(ValueError, match="fed by 2 links") as info:
        Network(models=models, links=links)
    said = [line for line in str(info.value).splitlines() if "fed by" in line]
    assert len(said) == 1 and "(links[0], links[1])" in said[0], said  # once, not per link


def test_self_link_is_a_cycle():
    with pytest.raises(ValueError, match="cycle"):
        Network(models=[_model("a", ["x"], ["y"])], links=[Link(**{"from": "a.y", "to": "a.x"})])


# ---------------------------------------------------------------- the CLI
runner = CliRunner()


def test_cli_check_prints_branch_order(tmp_path):
    raw = {"name": "branch", "models": [m.model_dump(by_alias=True, exclude_defaults=True)
                                        for m in branch_network().models],
           "links": [ln.model_dump(by_alias=True) for ln in branch_network().links]}
    path = tmp_path / "net.yaml"
    path.write_text(yaml.safe_dump(raw))
    result = runner.invoke(app, ["check", str(path)])
    assert result.exit_code == 0, result.output
    order_line = next(line for line in result.output.splitlines() if line.startswith("order:"))
    assert order_line.startswith("order: thermal -> micro")
    assert order_line.endswith("property")
    assert "<- thermal.v (identity)" in result.output


def test_cli_check_error_is_one_line_exit_2(tmp_path):
    path = tmp_path / "net.yaml"
    path.write_text("models:\n  a: {simulator: 'python:m:f', inputs: {x: {lower: 2, upper: 1}},"
                    " outputs: {y: {}}}\n")
    result = runner.invoke(app, ["check", str(path)])
    assert result.exit_code == 2
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in result.output
    assert "models.a.inputs.x" in lines[0] and "lower (2) must be smaller" in lines[0]


def test_cli_out_that_is_a_file_is_a_one_line_usage_error(tmp_path):
    """``--out`` naming a file is the user's path, not an internal error (exit 3): a usage
    error (exit 2) before anything runs."""
    path = tmp_path / "net.yaml"
    path.write_text("models:\n  a: {simulator: 'python:m:f', inputs: {x: {lower: 0, upper: 1}},"
                    " outputs: {y: {}}}\n")
    (tmp_path / "afile").write_text("")
    result = runner.invoke(app, ["run", str(path), "--out", str(tmp_path / "afile")],
                           terminal_width=400)
    assert result.exit_code == 2, result.output
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and "internal error" not in lines[0], result.output
    assert "is a file, not a folder" in lines[0], lines


def test_cli_surrogates_checks_out_before_fitting(tmp_path):
    """A bad ``--out`` fails before any fit (no campaign has run here: a fit would fail
    with another message), so no work is lost."""
    path = tmp_path / "net.yaml"
    path.write_text("models:\n  a: {simulator: 'python:m:f', inputs: {x: {lower: 0, upper: 1}},"
                    " outputs: {y: {measurable: true}}}\n"
                    "data:\n  d: {path: d.csv, observes: a.y, columns: {x: x, y: y}}\n")
    (tmp_path / "d.csv").write_text("x,y\n0.5,1.0\n")
    (tmp_path / "afile").write_text("")
    result = runner.invoke(app, ["surrogates", str(path), "--out", str(tmp_path / "afile")],
                           terminal_width=400)
    assert result.exit_code == 2 and "is a file, not a folder" in result.output, result.output


def test_spec_error_attributes():
    err = SpecError("fix it", file="f.yaml", field="models.a")
    assert str(err) == "f.yaml: models.a: fix it" and err.reason == "fix it"



def _check_warnings(folder, sims) -> list[str]:
    """``calnet check`` on one-input models with these simulators: its warning lines."""
    models = {m: {"simulator": sim, "inputs": {"x": {"lower": 0, "upper": 1}},
                  "outputs": {"y": {}}} for m, sim in sims.items()}
    spec = {"models": models, "settings": {"predict": [f"{m}.y" for m in sims]}}
    (folder / "network.yaml").write_text(yaml.safe_dump(spec))
    res = runner.invoke(app, ["check", str(folder)], terminal_width=400)
    assert res.exit_code == 0, res.output
    return [" ".join(line.split()) for line in res.output.splitlines()
            if line.startswith("warning:")]


def test_check_warns_of_a_simulator_that_cannot_run_here(tmp_path):
    """``calnet check``: a Python target that does not import, or a command that is not
    found, would fail every run; check says so (a warning: remote workers may differ)."""
    (tmp_path / "here.py").write_text("def f(inputs):\n    return {'y': 1.0}\n")
    warned = _check_warnings(tmp_path, {
        "a": "python:nomodule_xyz:f", "b": "python:here:nofunc", "c": "python:here:f",
        "d": {"kind": "command", "argv": ["./no_such_prog", "{x}"]}})
    assert len(warned) == 3, warned  # c imports and has f
    assert "a: simulator 'python:nomodule_xyz:f' cannot be imported here" in warned[0]
    assert "b: module 'here' has no 'nofunc'" in warned[1]
    assert "d: command './no_such_prog' is not found" in warned[2]


def test_check_warns_of_a_umbridge_server_that_cannot_run_the_model(tmp_path):
    """``calnet check``: a UM-Bridge URL where nothing listens, a server that is not a
    UM-Bridge server, or one that does not serve the model would fail every run."""
    import json
    import socket
    import threading
    from http.server import BaseHTTPRequestHandler, HTTPServer

    class Handler(BaseHTTPRequestHandler):
        def do_GET(self):  # noqa: N802 - http.server's name
            ok = self.path == "/Info" and self.server.umbridge
            body = json.dumps({"protocolVersion": 1.0, "models": ["forward"]}).encode()
            self.send_response(200 if ok else 404)
            self.end_headers()
            self.wfile.write(body if ok else b"not found")

        def log_message(self, *args):
            pass

    servers = []
    for umbridge in (True, False):
        server = HTTPServer(("127.0.0.1", 0), Handler)
        server.umbridge = umbridge
        threading.Thread(target=server.serve_forever, daemon=True).start()
        servers.append(f"http://127.0.0.1:{server.server_port}")
    with socket.socket() as s:  # a port where nothing listens
        s.bind(("127.0.0.1", 0))
        closed = f"http://127.0.0.1:{s.getsockname()[1]}"
    warned = _check_warnings(tmp_path, {
        "a": f"umbridge:{closed}/forward", "b": f"umbridge:{servers[1]}/forward",
        "c": f"umbridge:{servers[0]}/other", "d": f"umbridge:{servers[0]}/forward"})
    assert len(warned) == 3, warned  # d is served
    assert f"a: UM-Bridge server '{closed}' cannot be reached (ConnectionError)" in warned[0]
    assert "b: UM-Bridge server" in warned[1] and "(HTTP 404)" in warned[1]
    assert "c: UM-Bridge server" in warned[2] and "serves ['forward'], not 'other'" in warned[2]


def test_simulator_forms_in_campaigns_doc_parse():
    """Every ``simulator:`` example of docs/campaigns.md is a valid SimulatorRef."""
    import re
    from pathlib import Path

    doc = (Path(__file__).resolve().parents[2] / "docs" / "campaigns.md").read_text()
    entries = []
    for block in re.findall(r"```yaml\n(.*?)```", doc, re.S):
        chunks = re.split(r"^(?=simulator:)", block, flags=re.M)
        entries += [yaml.safe_load(c)["simulator"] for c in chunks if c.startswith("simulator:")]
    refs = [SimulatorRef.model_validate(e) for e in entries]
    assert {r.kind for r in refs} == {"builtin", "python", "command", "umbridge"}
    assert len(refs) >= 7


def test_a_unit_written_as_a_number_is_its_text():
    """``unit: 1`` (YAML reads a number) means the dimensionless "1"."""
    from calnet.spec.variables import Bounded, Output

    assert Bounded(name="a", unit=1, lower=0.0, upper=1.0).unit == "1"
    assert Output(name="y", unit=1e-3).unit == "0.001"
    assert Output(name="y", unit="mm").unit == "mm"
