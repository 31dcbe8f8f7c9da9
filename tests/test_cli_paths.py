"""Options that name paths or go together: a usage error (exit 2, one line) before
anything is read or written, and ``calnet run --fresh`` never deletes the stores beside
the spec."""

from __future__ import annotations

import pytest
import yaml
from typer.testing import CliRunner

from calnet.cli import app


def _two_models(folder, module: str):
    """A chain of two analytic models (``a: x -> y``, ``b: y -> z``) whose Python
    simulators live in ``module`` beside the spec; the spec's path."""
    (folder / f"{module}.py").write_text(
        "def a(inputs):\n    return {'y': 2 * inputs['x']}\n\n\n"
        "def b(inputs):\n    return {'z': inputs['y'] ** 2}\n")
    spec = {"name": "pair", "models": {
        "a": {"simulator": f"python:{module}:a", "inputs": {"x": {"lower": 0, "upper": 1}},
              "outputs": {"y": {}}, "campaign": {"runs": 5}},
        "b": {"simulator": f"python:{module}:b", "inputs": {"y": {"lower": 0, "upper": 2}},
              "outputs": {"z": {}}, "campaign": {"runs": 5}}},
        "links": [{"from": "a.y", "to": "b.y"}],
        "settings": {"seed": 0, "predict": ["b.z"]}}
    (folder / "network.yaml").write_text(yaml.safe_dump(spec, sort_keys=False))
    return folder / "network.yaml"


def _one_line_usage_error(result, message: str) -> None:
    assert result.exit_code == 2, result.output
    assert result.output.startswith(f"error: {message}"), result.output
    assert len(result.output.strip().splitlines()) == 1, result.output


@pytest.mark.parametrize("out", ["spec", "."])
def test_run_fresh_into_the_spec_folder_is_refused_and_keeps_its_stores(tmp_path, monkeypatch,
                                                                        out):
    spec = tmp_path / "spec"
    spec.mkdir()
    _two_models(spec, f"fresh_sims_{out == '.'}")
    made = CliRunner().invoke(app, ["campaign", str(spec), "--executor", "in-process",
                                    "--no-progress"])
    assert made.exit_code == 0, made.output
    stores = sorted((spec / "campaigns").glob("*.sqlite"))
    assert [p.name for p in stores] == ["a.sqlite", "b.sqlite"]
    before = [p.read_bytes() for p in stores]
    monkeypatch.chdir(spec if out == "." else tmp_path)
    result = CliRunner().invoke(app, ["run", "." if out == "." else "spec", "--out", out,
                                      "--fresh"], terminal_width=400)
    _one_line_usage_error(result, f"--fresh simulates every model again into "
                                  f"OUT/campaigns, but with --out '{out}' that is the "
                                  "campaigns folder beside the spec")
    assert "give another --out" in result.output
    assert [p.read_bytes() for p in stores] == before
    assert not (spec / "figures").exists()  # refused before anything was written


@pytest.mark.parametrize(("argv", "message"), [
    (["--import", "x.csv"], "--import reads one model's runs; give --model NAME too"),
    (["--store", "x.sqlite"], "--store and --export name one file; give --model NAME too"),
    (["--workers", "2", "--executor", "in-process"],
     "the in-process executor runs one run at a time, not --workers 2"),
    (["--model", "a", "--fresh", "--import", "x.csv"], "--import only adds runs to a store"),
    (["--model", "a", "--export", "x.txt"], "cannot export to 'x.txt'; name the file *.csv"),
    (["--model", "a", "--export-only", "--export", "x.txt"], "cannot export to 'x.txt'"),
])
def test_campaign_options_that_do_not_go_together_are_usage_errors(tmp_path, argv, message):
    spec = _two_models(tmp_path, "combo_sims")
    result = CliRunner().invoke(app, ["campaign", str(spec), *argv, "--no-progress"],
                                terminal_width=400)
    _one_line_usage_error(result, message)
    assert not (tmp_path / "campaigns").exists()  # nothing was simulated


def test_simulate_with_an_option_it_does_not_take_is_a_usage_error():
    result = CliRunner().invoke(app, ["simulate", "solidification", "--option", "foo=1"],
                                terminal_width=400)
    _one_line_usage_error(result, "'solidification' has no option ['foo']; it takes "
                                  "['variant']")
    bad = CliRunner().invoke(app, ["simulate", "solidification", "--option", "variant=Q",
                                   "--set", "S=0.3", "--set", "G=1e7"], terminal_width=400)
    _one_line_usage_error(bad, "solidification: variant must be one of ('A', 'B'), got 'Q' "
                               "(--option variant='Q'); fix the option names or values")
    typed = CliRunner().invoke(app, ["simulate", "phase_field", "--option", "nx=10.5",
                                     "--set", "S=0.3", "--set", "G=1e7"], terminal_width=400)
    _one_line_usage_error(typed, "phase_field option nx: expected an integer, got 10.5 "
                                 "(--option nx=10.5)")


@pytest.mark.parametrize(("argv", "message"), [
    (["--model", "a", "--store", ""],
     "--store '.' is a folder, not a file; give a file, e.g. --store a.sqlite"),
    (["--model", "a", "--store", "{tmp}/emptydir"],
     "--store '{tmp}/emptydir' is a folder, not a file; give a file, e.g. --store "
     "{tmp}/emptydir/a.sqlite"),
    (["--model", "a", "--store", "{tmp}/afile/x.sqlite"],
     "--store '{tmp}/afile/x.sqlite': '{tmp}/afile' is a file, not a folder"),
    (["--model", "a", "--export", "{tmp}/afile/x.csv"],
     "--export '{tmp}/afile/x.csv': '{tmp}/afile' is a file, not a folder"),
])
def test_campaign_paths_no_file_can_have_are_usage_errors(tmp_path, monkeypatch, argv,
                                                          message):
    spec = _two_models(tmp_path, "path_sims")
    (tmp_path / "emptydir").mkdir()
    (tmp_path / "afile").write_text("")
    monkeypatch.chdir(tmp_path)
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    result = CliRunner().invoke(app, ["campaign", str(spec), *argv, "--no-progress"],
                                terminal_width=400)
    _one_line_usage_error(result, message.replace("{tmp}", str(tmp_path)))
    assert not (tmp_path / "campaigns").exists()


@pytest.mark.parametrize(("argv", "message"), [
    (["run", "spec", "--out", ""], "--out is empty; give a folder"),
    (["run", "spec", "--out", "afile"], "--out 'afile' is a file, not a folder"),
    (["run", "spec", "--out", "afile/sub"],
     "--out 'afile/sub': 'afile' is a file, not a folder"),
    (["surrogates", "spec", "--out", "afile"], "--out 'afile' is a file, not a folder"),
    (["calibrate", "spec", "--out", "afile"], "--out 'afile' is a file, not a folder"),
    (["predict", "spec", "--at", "x=0.5", "--output", "afile/p.csv"],
     "--output 'afile/p.csv': 'afile' is a file, not a folder"),
])
def test_output_paths_that_cannot_be_folders_are_usage_errors(tmp_path, monkeypatch, argv,
                                                              message):
    (tmp_path / "spec").mkdir()
    _two_models(tmp_path / "spec", "out_sims")
    (tmp_path / "afile").write_text("")
    monkeypatch.chdir(tmp_path)
    result = CliRunner().invoke(app, argv, terminal_width=400)
    _one_line_usage_error(result, message)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile", "spec"]  # nothing written
    assert sorted(p.name for p in (tmp_path / "spec").iterdir()) == ["network.yaml",
                                                                    "out_sims.py"]
