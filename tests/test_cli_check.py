"""``calnet check``'s rendering of a network: each output's role once, and tables at
their full width in a pipe (Rich cuts them to 80 columns off a terminal)."""

from __future__ import annotations

import textwrap

import pytest
from typer.testing import CliRunner

from calnet.cli import app

SPEC = """
name: roles
models:
  M:
    simulator: python:roles_sims:f
    inputs: {x: {lower: 0.5, upper: 2, description: "the one process input"}}
    parameters: {a: {lower: 0.5, upper: 2.0}}
    outputs:
      y: {measurable: true, transform: log}
      z: {transform: log}
      w: {}
    campaign: {runs: 10}
data:
  a_data_set_with_a_rather_long_name_that_fills_the_role_column:
    {path: y.csv, observes: M.y, columns: {x: x, y: y}}
settings:
  predict: [M.w]
"""


@pytest.fixture
def spec(tmp_path):
    (tmp_path / "network.yaml").write_text(textwrap.dedent(SPEC))
    (tmp_path / "roles_sims.py").write_text(
        "def f(inputs):\n    x, a = inputs['x'], inputs['a']\n"
        "    return {'y': a * x, 'z': x, 'w': x + a}\n")
    (tmp_path / "y.csv").write_text("x,y\n0.6,0.7\n1.0,1.2\n1.5,1.7\n")
    return tmp_path


def _roles(output: str) -> dict[str, str]:
    """``{output name: its range / role cell}`` of the model table (one line per row)."""
    rows = [[c.strip() for c in line.split("│")] for line in output.splitlines()
            if "│ output" in line]
    return {r[0]: r[3] for r in rows}


def test_each_output_says_surrogate_once_with_its_scale(spec):
    result = CliRunner().invoke(app, ["check", str(spec)], env={"COLUMNS": None})
    assert result.exit_code == 0, result.output
    roles = _roles(result.output)
    assert roles["y"].endswith("; surrogate on log scale"), roles
    assert roles["y"].count("surrogate") == 1, roles
    assert "surrogate" not in roles["z"], roles  # unused: no surrogate, on any scale
    assert roles["w"].endswith("; surrogate"), roles  # settings.predict, linear scale


def test_tables_keep_their_full_width_in_a_pipe(spec):
    result = CliRunner().invoke(app, ["check", str(spec)], env={"COLUMNS": None})
    assert result.exit_code == 0, result.output
    table = [line for line in result.output.splitlines() if "│" in line]
    # one line per variable (5), none wrapped onto a second line
    assert len(table) == 5, table
    assert max(len(line) for line in table) > 80
    assert "a_data_set_with_a_rather_long_name_that_fills_the_role_column; surrogate" \
        in result.output


def test_tables_respect_columns_when_set(spec):
    result = CliRunner().invoke(app, ["check", str(spec)], env={"COLUMNS": "70"})
    assert result.exit_code == 0, result.output
    table = [line for line in result.output.splitlines() if "│" in line]
    assert len(table) > 5 and max(len(line) for line in table) <= 70


def test_check_says_which_models_share_a_parameter(tmp_path):
    (tmp_path / "network.yaml").write_text(textwrap.dedent("""
        name: sharing
        models:
          A:
            simulator: python:share_sims:a
            inputs: {x: {lower: 0, upper: 1}}
            parameters: {k: {lower: 0, upper: 2, shared: true}, c: {lower: 0, upper: 1}}
            outputs: {y: {measurable: true}}
          B:
            simulator: python:share_sims:b
            inputs: {y: {lower: 0, upper: 3}}
            parameters: {k: {lower: 0, upper: 2, shared: true}}
            outputs: {z: {measurable: true}}
        links: [{from: A.y, to: B.y}]
        settings: {predict: [B.z]}
        """))
    (tmp_path / "share_sims.py").write_text(
        "def a(i):\n    return {'y': i['k'] * i['x'] + i['c']}\n\n\n"
        "def b(i):\n    return {'z': i['k'] * i['y']}\n")
    res = CliRunner().invoke(app, ["check", str(tmp_path)], terminal_width=200)
    assert res.exit_code == 0, res.output
    rows = {line.split("│")[0].strip() + "/" + str(i): line
            for i, line in enumerate(res.output.splitlines()) if "parameter" in line}
    shared = [line for line in rows.values() if line.startswith("k ")]
    assert len(shared) == 2 and "shared with B" in shared[0] and "shared with A" in shared[1]
    assert not any("shared" in line for line in rows.values() if line.startswith("c "))


@pytest.mark.parametrize(("prior", "said"), [
    ("{dist: normal, mu: 10, sigma: 0.5}", "prior normal(mu=10, sigma=0.5) puts 6.4e-56 % of "
     "its mass within [0.5, 2] and most of it above 2"),
    ("{dist: gamma, a: 2, b: 100}", "most of it below 0.5"),
    ("{dist: lognormal, mu: 0, sigma: 0.5}", None),
    ("{dist: normal, mu: 2.5, sigma: 0.5}", None),  # 16 % within: truncated, not refuted
])
def test_check_warns_of_a_prior_whose_mass_lies_beyond_the_bounds(spec, prior, said):
    text = (spec / "network.yaml").read_text()
    (spec / "network.yaml").write_text(text.replace(
        "{a: {lower: 0.5, upper: 2.0}}", f"{{a: {{lower: 0.5, upper: 2.0, prior: {prior}}}}}"))
    result = CliRunner().invoke(app, ["check", str(spec)])
    assert result.exit_code == 0, result.output
    warned = [line for line in result.output.splitlines() if "models.M.parameters.a" in line]
    if said is None:
        assert not warned, result.output
    else:
        assert len(warned) == 1 and said in warned[0], result.output
        assert "move the prior into the bounds" in warned[0]


RUNS = "x,a,y,z,w\n0.6,1.0,0.6,0.6,1.6\n1.0,1.5,1.5,1.0,2.5\n1.5,0.7,1.05,1.5,2.2\n"


@pytest.mark.parametrize(("table", "strict", "said"), [
    (None, False, "runs.csv'; check the path"),
    (RUNS.replace("1.5,1.0,2.5", "nan,1.0,2.5"), False,
     "runs.csv: column 'y', row 2: nan in a run with status ok"),
    (RUNS.replace("1.5,0.7", "2.5,0.7"), True, "runs.csv: column 'x': 1 row(s) outside its "
     "bounds [0.5, 2] (first: row 3, 2.5)"),
    (RUNS, False, None),
])
def test_check_reads_the_campaign_import_tables(spec, table, strict, said):
    text = (spec / "network.yaml").read_text().replace(
        "campaign: {runs: 10}", "campaign: {import: runs.csv}")
    if strict:
        text = text.replace("settings:\n", "settings:\n  strict: true\n")
    (spec / "network.yaml").write_text(text)
    if table is not None:
        (spec / "runs.csv").write_text(table)
    result = CliRunner().invoke(app, ["check", str(spec)])
    if said is None:
        assert result.exit_code == 0, result.output
        return
    errors = [line for line in result.output.splitlines() if line.startswith("error:")]
    assert result.exit_code == 2 and len(errors) == 1, result.output
    assert "models.M.campaign.import: " in errors[0] and said in errors[0], errors


@pytest.mark.parametrize("data, settings, said", [
    ("", "", ["noise sd sampled, prior half-normal (scale: the observations' sd); "
              "discrepancy orthogonal to the model's parameters, sd prior half-normal",
              "calibration: segmented (plug: posterior; stages: M with "
              "a_data_set_with_a_rather_long_name_that_fills_the_role_column), surrogate "
              "variance in the likelihood; sampler: 4 chains x (1000 warm-up + 1000 "
              "draws), target_accept 0.9, diagonal mass matrix"]),
    (", noise: {sd: 0.05}, discrepancy: none",
     "  sampler: {chains: 2, warmup: 300, draws: 200, thin: 2, dense_mass: true}\n"
     "  calibration: {mode: joint, emulator_variance: false}\n",
     ["noise sd 0.05 (known; taken to the log scale as sd / y); no discrepancy",
      "calibration: joint, surrogate variance left out of the likelihood; sampler: 2 chains "
      "x (300 warm-up + 200 draws, thin 2), target_accept 0.9, dense mass matrix"]),
    (", noise: {prior: {dist: halfnormal, sigma: 0.2}}, "
     "discrepancy: {orthogonal: false, sd_prior: {dist: halfnormal, sigma: 0.3}}", "",
     ["noise sd sampled, prior halfnormal(sigma=0.2); discrepancy free to mimic the "
      "model's parameters, sd prior halfnormal(sigma=0.3)"]),
    (", noise: {prior: {dist: invgamma, a: 2, b: 0.01}}", "",
     ["noise variance sampled, prior invgamma(a=2, b=0.01)"]),
])
def test_check_says_how_each_data_set_and_the_sampler_enter(spec, data, settings, said):
    """Known noise, no discrepancy and the sampler's settings are visible before a run."""
    text = (spec / "network.yaml").read_text()
    text = text.replace("columns: {x: x, y: y}}", "columns: {x: x, y: y}" + data + "}")
    (spec / "network.yaml").write_text(text + settings)
    result = CliRunner().invoke(app, ["check", str(spec)])
    assert result.exit_code == 0, result.output
    flat = " ".join(result.output.split())
    for line in said:
        assert line in flat, (line, result.output)


def test_check_refuses_a_command_template_field_the_campaign_would(tmp_path):
    """A ``{name}`` in a command's arguments that is no input, parameter or option: the
    campaign refuses it, and check says so the same way."""
    (tmp_path / "network.yaml").write_text(textwrap.dedent("""
        models:
          M:
            simulator: {kind: command, argv: [python3, x.py, "{xx}", "{x}"]}
            inputs: {x: {lower: 0, upper: 1}}
            outputs: {y: {}}
        settings: {predict: [M.y]}
        """))
    result = CliRunner().invoke(app, ["check", str(tmp_path)], terminal_width=400)
    errors = [line for line in result.output.splitlines() if line.startswith("error:")]
    assert result.exit_code == 2 and len(errors) == 1, result.output
    assert ("models.M.simulator.argv: command argument '{xx}' names {xx}, which is not an "
            "input, parameter or option") in errors[0]
    fixed = (tmp_path / "network.yaml").read_text().replace('"{xx}", ', "")
    (tmp_path / "network.yaml").write_text(fixed)
    assert CliRunner().invoke(app, ["check", str(tmp_path)]).exit_code == 0


def test_check_gives_up_on_a_module_that_does_not_finish_importing(tmp_path, monkeypatch):
    """A Python simulator whose module waits at import: check says so after the time
    limit, and never imports it in its own process (which would wait as long)."""
    import sys
    import time

    import calnet.cli

    monkeypatch.setattr(calnet.cli, "IMPORT_LIMIT_S", 1.0)
    (tmp_path / "waits_at_import.py").write_text(
        "import time\ntime.sleep(60)\n\n\ndef f(inputs):\n    return {'y': 1.0}\n")
    (tmp_path / "network.yaml").write_text(textwrap.dedent("""
        models:
          Slow:
            simulator: python:waits_at_import:f
            inputs: {x: {lower: 0, upper: 1}}
            outputs: {y: {}}
        settings: {predict: [Slow.y]}
        """))
    t0 = time.monotonic()
    result = CliRunner().invoke(app, ["check", str(tmp_path)], terminal_width=400)
    assert time.monotonic() - t0 < 20
    assert result.exit_code == 1, result.output
    assert result.output.startswith(
        "error: Slow: importing module 'waits_at_import' (python:waits_at_import:f) did not "
        "finish within 1 s, so check stopped before importing it here"), result.output
    assert "waits_at_import" not in sys.modules


def _solidification_spec(folder, outputs: str, rest: str) -> None:
    """A one-model spec of the built-in solidification simulator in ``folder``."""
    (folder / "network.yaml").write_text(textwrap.dedent("""
        models:
          M:
            simulator: builtin:solidification
            inputs: {S: {unit: m/s, lower: 0.1, upper: 1},
                     G: {unit: K/m, lower: 1.0e+6, upper: 1.0e+7}}
            parameters: {sigma: {unit: J/cm^2, lower: 1.0e-6, upper: 3.0e-6}}
            outputs: OUTPUTS
        """).replace("OUTPUTS", outputs) + textwrap.dedent(rest))


def test_plug_mode_in_a_joint_spec_is_said_to_be_ignored(tmp_path):
    """settings.calibration.plug applies to segmented mode: check says a joint spec's
    plug: mode does nothing, and calibrate refuses --plug for a joint calibration."""
    _solidification_spec(tmp_path, "{lambda: {unit: um, measurable: true}}", """
        data:
          d: {path: d.csv, observes: M.lambda}
        settings: {calibration: {mode: joint, plug: mode}}
        """)
    (tmp_path / "d.csv").write_text("S,G,lambda\n0.3,5.0e+6,0.5\n")
    result = CliRunner().invoke(app, ["check", str(tmp_path)], terminal_width=400)
    assert result.exit_code == 0, result.output
    assert "calibration: joint (plug: mode applies to segmented mode only: ignored)" \
        in result.output, result.output
    result = CliRunner().invoke(app, ["calibrate", str(tmp_path), "--plug", "posterior",
                                      "--surrogates", str(tmp_path / "nowhere")])
    assert result.exit_code == 2, result.output
    assert ("--plug applies to segmented calibration only; this calibration is joint (the "
            "spec's settings.calibration.mode): add --mode segmented, or leave --plug out"
            ) in result.output, result.output


def test_outputs_nothing_uses_are_named_in_one_line_per_model(tmp_path):
    _solidification_spec(tmp_path, '{lambda: {unit: um}, k_V: {unit: "1"}}', """
        settings: {predict: []}
        """)
    result = CliRunner().invoke(app, ["check", str(tmp_path)], terminal_width=400)
    warned = [line for line in result.output.splitlines() if line.startswith("warning: M:")]
    assert warned == ["warning: M: outputs lambda, k_V are used by nothing (no data set "
                      "observes them, no link reads them, settings.predict does not list "
                      "them), so they get no surrogate and are never predicted; list them in "
                      "settings.predict to emulate them, or remove them from the spec"], \
        result.output
