"""Each malformed spec is rejected with a one-line error naming file, field and fix."""

from __future__ import annotations

import warnings

import pytest

from calnet.errors import SpecError, SpecWarning
from calnet.spec import load_spec, read_all


def _error(path) -> SpecError:
    with pytest.raises(SpecError) as info:
        load_spec(path)
    message = str(info.value)
    assert "\n" not in message
    assert str(path.parent) in message  # the spec or the data file at fault
    return info.value


def test_valid_spec_loads(base_spec, write_spec):
    network = load_spec(write_spec(base_spec))
    assert network.order == ("heat", "micro")
    assert network.process_inputs("micro") == (("heat", "P"), ("heat", "v"))
    assert [o.name for o in network.needed_outputs("heat")] == ["W", "G"]


def test_folder_accepted(base_spec, write_spec):
    path = write_spec(base_spec)
    assert load_spec(path.parent).name == "toy"


def test_unknown_key(base_spec, write_spec):
    base_spec["models"]["heat"]["parameters"]["k"]["lowr"] = 1
    err = _error(write_spec(base_spec))
    assert "unknown key 'lowr'" in str(err) and "lower" in str(err)
    assert err.field == "models.heat.parameters.k"


def test_unknown_top_level_key(base_spec, write_spec):
    base_spec["modles"] = {}
    assert "unknown key 'modles'" in str(_error(write_spec(base_spec)))


def test_duplicate_model_name_in_yaml(base_spec, write_spec):
    text = ("models:\n  a: {simulator: 'python:m:f', inputs: {x: {lower: 0, upper: 1}}, "
            "outputs: {y: {}}}\n  a: {simulator: 'python:m:f', inputs: {x: {lower: 0, "
            "upper: 1}}, outputs: {y: {}}}\n")
    err = _error(write_spec(base_spec, text=text))
    assert "duplicate key 'a'" in str(err)


def test_duplicate_model_name_in_list(base_spec, write_spec):
    heat = base_spec["models"]["heat"]
    base_spec["models"] = [{"name": "heat", **heat}, {"name": "heat", **heat}]
    base_spec["links"], base_spec["data"] = [], {}
    assert "duplicate model name" in str(_error(write_spec(base_spec)))


def test_duplicate_variable_across_groups(base_spec, write_spec):
    base_spec["models"]["heat"]["parameters"]["P"] = {"lower": 0, "upper": 1}
    assert "duplicate variable name 'P'" in str(_error(write_spec(base_spec)))


def test_cycle(base_spec, write_spec):
    base_spec["models"]["heat"]["inputs"]["lam"] = {"unit": "um", "lower": 0, "upper": 1}
    base_spec["links"].append({"from": "micro.lam", "to": "heat.lam"})
    err = _error(write_spec(base_spec))
    assert "cycle" in str(err) and "heat" in str(err) and "micro" in str(err)


def test_link_to_missing_model(base_spec, write_spec):
    base_spec["links"][0]["to"] = "mikro.G"
    err = _error(write_spec(base_spec))
    assert "no model named 'mikro'" in str(err) and err.field is None or "links" in str(err)


def test_link_to_missing_variable(base_spec, write_spec):
    base_spec["links"][0]["from"] = "heat.G0"
    err = _error(write_spec(base_spec))
    assert "no output or input 'G0'" in str(err) and "links[0].from" in str(err)


def test_link_into_parameter_rejected(base_spec, write_spec):
    base_spec["links"][0]["to"] = "micro.s"
    assert "no control input 's'" in str(_error(write_spec(base_spec)))


def test_unit_mismatch_across_link(base_spec, write_spec):
    base_spec["models"]["micro"]["inputs"]["G"]["unit"] = "K/mm"
    err = _error(write_spec(base_spec))
    assert "unit mismatch" in str(err) and "K/mm" in str(err)


@pytest.mark.parametrize("lower,upper", [(30, 10), (10, 10)])
def test_bounds_order(base_spec, write_spec, lower, upper):
    base_spec["models"]["heat"]["parameters"]["k"].update(lower=lower, upper=upper)
    err = _error(write_spec(base_spec))
    assert "must be smaller than upper" in str(err)
    assert err.field == "models.heat.parameters.k"


def test_missing_data_file(base_spec, write_spec):
    base_spec["data"]["width"]["path"] = "nowhere.csv"
    err = _error(write_spec(base_spec))
    assert "not found" in str(err) and err.field == "data.width.path"


def test_missing_column(base_spec, write_spec):
    base_spec["data"]["width"]["columns"]["W"] = "wdth"
    err = _error(write_spec(base_spec))
    assert "column 'wdth' is not in the CSV" in str(err)


def test_unmapped_variable(base_spec, write_spec):
    del base_spec["data"]["spacing"]["columns"]["v"]
    assert "no column given for ['heat.v']" in str(_error(write_spec(base_spec)))


def test_non_numeric_column(base_spec, write_spec):
    bad = "id,power,speed,width,split\n1,100,fast,90,train\n2,150,1.0,80,test\n"
    err = _error(write_spec(base_spec, width=bad))
    assert "not numeric ('fast' on line 2)" in str(err)


def test_nan_in_data(base_spec, write_spec):
    bad = "id,power,speed,width,split\n1,100,0.5,,train\n2,150,1.0,nan,test\n3,1,1,1,train\n"
    err = _error(write_spec(base_spec, width=bad))
    assert "2 missing/NaN" in str(err) and "[2, 3]" in str(err)


def test_every_bad_column_is_reported(base_spec, write_spec):
    bad = "id,power,speed,width,split\n1,100,0.5,nan,train\n2,150,,80,test\n3,1,1,1,train\n"
    err = _error(write_spec(base_spec, width=bad))
    said = [str(err), *err.more]
    assert any("column 'speed' has 1 missing/NaN" in s and "[3]" in s for s in said), said
    assert any("column 'width' has 1 missing/NaN" in s and "[2]" in s for s in said), said


def test_csv_without_data_rows(base_spec, write_spec):
    err = _error(write_spec(base_spec, width="id,power,speed,width,split\n"))
    assert "no data rows" in str(err) and err.field == "data.width"


def test_non_positive_data_of_a_log_output(base_spec, write_spec):
    base_spec["models"]["micro"]["outputs"]["lam"]["transform"] = "log"
    bad = "id,power,speed,pdas\n1,100,0.5,0.3\n2,150,1.0,0\n3,120,1.0,-0.1\n"
    err = _error(write_spec(base_spec, spacing=bad))
    assert "2 value(s) <= 0 on line(s) [3, 4]" in str(err) and "transform: log" in str(err)


def test_non_positive_data_of_a_log_scale_input(base_spec, write_spec):
    base_spec["models"]["heat"]["inputs"]["v"]["scale"] = "log"
    bad = "id,power,speed,width,split\n1,100,0.5,90,train\n2,150,0,80,test\n"
    err = _error(write_spec(base_spec, width=bad))  # not just out of bounds: log(0)
    assert "heat.v has 1 value(s) <= 0 on line(s) [3]" in str(err) and "scale is log" in str(err)


def test_out_of_bounds_warns_with_count(base_spec, write_spec):
    wide = "id,power,speed,width,split\n1,300,0.5,90,train\n2,20,3.0,80,train\n3,100,1,80,test\n"
    with pytest.warns(SpecWarning, match="2 of 3 point"):
        load_spec(write_spec(base_spec, width=wide))


def test_out_of_bounds_strict_errors(base_spec, write_spec):
    base_spec["settings"] = {"strict": True}
    wide = "id,power,speed,width,split\n1,300,0.5,90,train\n2,150,1.0,80,test\n"
    assert "1 of 2 point(s) lie outside" in str(_error(write_spec(base_spec, width=wide)))


def test_observing_unmeasurable_output(base_spec, write_spec):
    base_spec["data"]["width"]["observes"] = "heat.G"
    base_spec["data"]["width"]["columns"] = {"P": "power", "v": "speed", "G": "width"}
    assert "is not measurable" in str(_error(write_spec(base_spec)))


def test_bad_split_value(base_spec, write_spec):
    bad = "id,power,speed,width,split\n1,100,0.5,90,train\n2,150,1.0,80,holdout\n"
    assert "'holdout'" in str(_error(write_spec(base_spec, width=bad)))


def test_invalid_yaml(base_spec, write_spec):
    err = _error(write_spec(base_spec, text="models: [unclosed\n"))
    assert "invalid YAML" in str(err)


def test_not_a_number(base_spec, write_spec):
    base_spec["models"]["heat"]["inputs"]["P"]["lower"] = "low"
    assert "expected a number" in str(_error(write_spec(base_spec)))


def test_bad_simulator_shorthand(base_spec, write_spec):
    base_spec["models"]["heat"]["simulator"] = "fortran:heat"
    assert "cannot read simulator" in str(_error(write_spec(base_spec)))


def test_unknown_builtin(base_spec, write_spec):
    base_spec["models"]["heat"]["simulator"] = "builtin:nosuch"
    assert "unknown built-in simulator 'nosuch'" in str(_error(write_spec(base_spec)))


def test_missing_spec_path(tmp_path):
    with pytest.raises(SpecError, match="no such file"):
        load_spec(tmp_path / "absent.yaml")
    with pytest.raises(SpecError, match="no network.yaml"):
        load_spec(tmp_path)


def test_predict_settings_refuse_non_positive_log_scale_input(base_spec, write_spec):
    from calnet.errors import CalnetError
    from calnet.predict import settings_matrix

    base_spec["models"]["heat"]["inputs"]["v"]["scale"] = "log"
    net = load_spec(write_spec(base_spec))
    x, notes = settings_matrix(net, "width", [{"P": 100, "v": 3.0}])
    assert x.tolist() == [[100, 3.0]] and "outside its bounds" in notes[0]
    with pytest.raises(CalnetError, match=r"point 2: heat.v = 0 must be > 0 \(its scale is log"):
        settings_matrix(net, "width", [{"P": 100, "v": 1.0}, {"P": 100, "v": 0.0}])


def test_normal_prior_without_mass_inside_the_bounds(base_spec, write_spec):
    k = base_spec["models"]["heat"]["parameters"]["k"]  # bounds [10, 30]
    k["prior"] = {"dist": "normal", "mu": 35, "sigma": 1}  # 5 sigma out: usable, named
    with pytest.warns(SpecWarning, match="models.heat.parameters.k: prior normal"):
        load_spec(write_spec(base_spec))
    k["prior"] = {"dist": "normal", "mu": 100, "sigma": 0.5}
    err = _error(write_spec(base_spec))
    assert err.field == "models.heat.parameters.k" and "has no mass there" in str(err)


def test_predict_settings_skip_inputs_of_other_data_sets(base_spec, write_spec):
    """``calnet predict`` without ``-d``: a point may carry inputs that only some data
    sets take; those are skipped for the others, an unknown name is still an error."""
    from calnet.errors import CalnetError
    from calnet.predict import settings_matrix, shared_inputs

    net = load_spec(write_spec(base_spec))
    row = [{"P": 100, "v": 1.0, "other": 3.0}]
    with pytest.raises(CalnetError, match="'other' is not a process input"):
        settings_matrix(net, "width", row)
    x, _ = settings_matrix(net, "width", row, skip={"other"})
    assert x.tolist() == [[100, 1.0]]
    assert shared_inputs(net, ["width"], [{"P": 1.0, "heat.v": 1.0, "other": 3.0}]) == {
        "P", "heat.v"}


def test_empty_sections_say_so(base_spec, write_spec):
    base_spec["models"]["heat"]["outputs"] = {}
    assert "'outputs' is empty; declare at least one entry" in str(_error(write_spec(base_spec)))


def test_predict_settings_outside_bounds_note_names_the_unit_only_if_any(base_spec, write_spec):
    from calnet.predict import settings_matrix

    del base_spec["models"]["heat"]["inputs"]["P"]["unit"]  # dimensionless: unit "1"
    net = load_spec(write_spec(base_spec))
    _, notes = settings_matrix(net, "width", [{"P": 300, "v": 3.0}])
    assert "heat.P = 300 lies outside its bounds [50, 250]; the surrogates" in notes[0]
    assert "heat.v = 3 lies outside its bounds [0.1, 2] m/s; the surrogates" in notes[1]


@pytest.mark.parametrize("path,field", [
    (("models", "heat", "inputs", "P", "upper"), "upper"),
    (("models", "heat", "parameters", "k", "lower"), "lower"),
    (("data", "width", "noise"), "sd"),
    (("settings", "sampler", "chains"), "chains"),
    (("settings", "seed"), "seed"),
])
def test_boolean_where_a_number_is_expected(base_spec, write_spec, path, field):
    """YAML reads ``true`` as a boolean; pydantic would take it as 1.0 or 1."""
    node = base_spec
    for key in path[:-1]:
        node = node.setdefault(key, {})
    node[path[-1]] = {"sd": True} if field == "sd" else True
    err = _error(write_spec(base_spec))
    assert f"{field} must be a number, got true" in str(err)


def test_spec_file_that_is_not_utf8(base_spec, write_spec):
    path = write_spec(base_spec)
    path.write_bytes(b"# Temp\xe9rature\n" + path.read_bytes())
    err = _error(path)
    assert "not UTF-8 text (byte 0xe9 at line 1)" in str(err) and "save the file" in str(err)


def test_one_output_linked_into_two_inputs_of_one_model(base_spec, write_spec):
    base_spec["links"] = [{"from": "heat.G", "to": "micro.G"}, {"from": "heat.G", "to": "micro.S"}]
    base_spec["models"]["micro"]["inputs"]["S"]["unit"] = "K/m"
    err = _error(write_spec(base_spec))
    assert "'heat.G' feeds both 'micro.G' and 'micro.S'" in str(err)
    assert "links[0]" in str(err)


def test_every_problem_is_listed_one_line_each(base_spec, write_spec):
    """Three independent problems: the error names the first, ``more`` the other two; a
    list that fails only because an item failed is not a problem of its own."""
    base_spec["models"]["heat"]["inputs"]["P"]["upper"] = True
    base_spec["models"]["heat"]["parameters"]["k"]["lower"] = "low"
    base_spec["models"]["micro"]["parameters"]["s"]["prior"] = {
        "dist": "normal", "mu": float("nan"), "sigma": 1.0}
    err = _error(write_spec(base_spec))
    assert len(err.more) == 2 and all("\n" not in line for line in err.more)
    text = " ".join([str(err), *err.more])
    for part in ("models.heat.inputs.P", "models.heat.parameters.k",
                 "models.micro.parameters.s.prior"):
        assert part in text, text
    assert "more problem" not in text


def test_cli_lists_every_problem(base_spec, write_spec):
    from typer.testing import CliRunner

    from calnet.cli import app

    base_spec["models"]["heat"]["inputs"]["P"]["upper"] = True
    base_spec["models"]["micro"]["parameters"]["s"]["lower"] = 5  # above its upper
    result = CliRunner().invoke(app, ["check", str(write_spec(base_spec))],
                                terminal_width=400)
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert result.exit_code == 2 and len(lines) == 2, result.output
    assert all(line.startswith("error: ") for line in lines)


def test_the_network_problems_come_together(base_spec, write_spec):
    """A bad link, data sets observing what is not there and criteria for a missing data
    set: one error, every problem a line of its own, in the spec's order."""
    base_spec["links"][0]["from"] = "heat.G0"
    base_spec["data"]["width"]["observes"] = "heat.W9"
    spacing = next(k for k in base_spec["data"] if k != "width")
    base_spec["data"][spacing]["observes"] = "micro.nothing"
    base_spec.setdefault("settings", {})["criteria"] = {"nosuch": {"upper": 0.2}}
    err = _error(write_spec(base_spec))
    lines = [str(err).split(": ", 1)[1], *err.more]
    assert len(lines) == 4, lines
    assert lines[0].startswith("links[0].from: model 'heat' has no output or input 'G0'")
    assert lines[1].startswith("settings.criteria: no data set named 'nosuch'")
    assert lines[2].startswith("data.width.observes: model 'heat' has no output 'W9'")
    assert lines[3].startswith(f"data.{spacing}.observes: model 'micro' has no output 'nothing'")


def test_columns_default_to_the_variables_own_names(base_spec, write_spec):
    """Without ``columns`` the spacing data (through the links: heat.P, heat.v, and
    micro.lam) is read from the columns P, v and lam."""
    del base_spec["data"]["spacing"]["columns"]
    net = load_spec(write_spec(base_spec, spacing="id,P,v,lam\n1,100,0.5,0.3\n"))
    data = read_all(net)["spacing"]
    assert data.input_keys == ("heat.P", "heat.v") and data.x.tolist() == [[100, 0.5]]
    assert data.y.tolist() == [0.3]
    err = _error(write_spec(base_spec, spacing="id,P,speed,lam\n1,100,0.5,0.3\n"))
    assert err.field == "data.spacing" and err.reason.startswith(
        "no column ['v'] (it has ['id', 'P', 'speed', 'lam']); without 'columns' each input "
        "and the observed output are read from the column of their own name"), err
    assert "add 'columns:" in err.reason


def test_columns_are_needed_where_two_inputs_share_a_name(base_spec, write_spec):
    base_spec["models"]["micro"]["inputs"]["P"] = {"unit": "W", "lower": 50, "upper": 250}
    del base_spec["data"]["spacing"]["columns"]
    err = _error(write_spec(base_spec))
    assert "data.spacing: ['heat.P', 'micro.P'] share a name" in str(err), err


def test_a_single_chain_is_warned_of(base_spec, write_spec):
    base_spec["settings"] = {"sampler": {"chains": 1}}
    with pytest.warns(SpecWarning, match="settings.sampler.chains is 1: R-hat then compares "
                                         "the two halves of one chain"):
        load_spec(write_spec(base_spec))
    base_spec["settings"] = {"sampler": {"chains": 2}}
    with warnings.catch_warnings():
        warnings.simplefilter("error", SpecWarning)
        load_spec(write_spec(base_spec))
