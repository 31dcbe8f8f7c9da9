"""What each output is for (observed, linked, predicted, unused) and ``settings.predict``."""

from __future__ import annotations

import pytest
import yaml
from typer.testing import CliRunner

from calnet.cli import app

runner = CliRunner()


def _chain(predict=None, data=False) -> dict:
    """a: x -> (u, spare); b: u -> (y, z); b.y observed when ``data``."""
    raw = {"models": {
        "a": {"simulator": "python:m:f", "inputs": {"x": {"lower": 0, "upper": 1}},
              "outputs": {"u": {}, "spare": {}}},
        "b": {"simulator": "python:m:g", "inputs": {"u": {"lower": 0, "upper": 1}},
              "outputs": {"y": {"measurable": True}, "z": {}}}},
        "links": [{"from": "a.u", "to": "b.u"}]}
    if predict is not None:
        raw["settings"] = {"predict": predict}
    if data:
        raw["data"] = {"d": {"path": "d.csv", "observes": "b.y", "columns": {"x": "x", "y": "y"}}}
    return raw


def _check(tmp_path, raw):
    (tmp_path / "d.csv").write_text("x,y\n0.5,1.0\n")
    (tmp_path / "m.py").write_text("def f(i):\n    return {}\n\n\ndef g(i):\n    return {}\n")
    (tmp_path / "network.yaml").write_text(yaml.safe_dump(raw))
    return runner.invoke(app, ["check", str(tmp_path)], terminal_width=400)


def test_output_uses_and_needed_outputs():
    from calnet.spec import parse_spec

    net = parse_spec({**_chain(["b.z", "b.y"], data=True)}, root=".", source="t")
    assert net.output_uses("a") == {"u": ("linked",), "spare": ()}
    assert net.output_uses("b") == {"y": ("observed", "predicted"), "z": ("predicted",)}
    assert [o.name for o in net.needed_outputs("a")] == ["u"]
    assert [o.name for o in net.needed_outputs("b")] == ["y", "z"]
    bare = parse_spec(_chain(), root=".", source="t")  # no data, nothing requested
    assert [o.name for o in bare.needed_outputs("b")] == []
    one = parse_spec(_chain("b.z"), root=".", source="t")  # one output without a list
    assert one.settings.predict == ("b.z",)


def test_check_says_what_each_output_is_for_and_warns_of_unused(tmp_path):
    res = _check(tmp_path, _chain(["b.z"], data=True))
    assert res.exit_code == 0, res.output
    rows = {line.split()[0]: " ".join(line.split()) for line in res.output.splitlines()
            if "│ output" in line}
    assert "linked;" in rows["u"] and "unused" in rows["spare"]
    assert "observed;" in rows["y"] and "predicted;" in rows["z"]
    warned = [" ".join(line.split()) for line in res.output.splitlines()
              if line.startswith("warning:")]
    assert len(warned) == 1, res.output
    assert warned[0].startswith("warning: a: output spare is used by nothing (no data set "
                                "observes it")
    assert "list it in settings.predict" in warned[0]


def test_check_of_an_emulation_only_network(tmp_path):
    res = _check(tmp_path, {**_chain(["b.y", "b.z", "a.spare"])})
    assert res.exit_code == 0, res.output
    assert "warning:" not in res.output
    assert "no data sets: emulation only" in res.output and "predicts b.y, b.z, a.spare" \
        in " ".join(res.output.split())


@pytest.mark.parametrize(("predict", "message"), [
    (["c.y"], "settings.predict[0]: no model named 'c'; known models: ['a', 'b']"),
    (["b.y", "b.w"], "settings.predict[1]: model 'b' has no output 'w'; known outputs: "
                     "['y', 'z']"),
    (["y"], "'y' must be written 'model.variable'"),
    (["b.y", "b.y"], "names an output twice"),
    (["a.x"], "model 'a' has no output 'x'"),
])
def test_settings_predict_errors_are_one_line_exit_2(tmp_path, predict, message):
    res = _check(tmp_path, _chain(predict))
    assert res.exit_code == 2, res.output
    lines = [line for line in res.output.splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in res.output, res.output
    assert message in " ".join(lines[0].split()), lines[0]
    assert "settings.predict" in lines[0]


def test_check_warnings_show_the_simulator_verbatim(tmp_path):
    """``python:x:f`` in a warning is text, not console markup (``:x:`` is an emoji code)."""
    raw = {"models": {"a": {"simulator": "python:x:f", "inputs": {"x": {"lower": 0, "upper": 1}},
                            "outputs": {"y": {}}}}, "settings": {"predict": ["a.y"]}}
    (tmp_path / "network.yaml").write_text(yaml.safe_dump(raw))
    res = runner.invoke(app, ["check", str(tmp_path)], terminal_width=400)
    assert res.exit_code == 0, res.output
    assert "simulator 'python:x:f' cannot be imported here" in res.output, res.output


def test_check_says_what_the_run_compares(tmp_path):
    """calnet check names settings.compare, warns of a variant that changes nothing here
    (no discrepancy: no_discrepancy and non_orthogonal), and counts one point as one."""
    raw = _chain(data=True)
    raw["data"]["d"]["discrepancy"] = "none"
    raw["settings"] = {"compare": ["no_discrepancy", "non_orthogonal", "reference"]}
    res = _check(tmp_path, raw)
    assert res.exit_code == 0, res.output
    said = " ".join(res.output.split())
    assert "d.csv observes b.y; 1 point (1 train, 0 test)" in said
    assert ("compared by leave-one-out with the variants no_discrepancy, non_orthogonal, "
            "reference; warning: no_discrepancy and non_orthogonal change nothing in this "
            "spec, so they are not run") in said


def test_a_variant_named_twice_is_a_one_line_error(tmp_path):
    raw = _chain(data=True)
    raw["settings"] = {"compare": ["no_discrepancy", "no_discrepancy"]}
    res = _check(tmp_path, raw)
    assert res.exit_code == 2, res.output
    assert "names a variant twice; list each once" in " ".join(res.output.split())
