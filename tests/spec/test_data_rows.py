"""Data files that would mislead the calibration: a column name given twice in a header
(pandas would rename the second one ``P.1``) and a measurement given twice (it would
count twice in the likelihood)."""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

from calnet.cli import app
from calnet.errors import SpecError, SpecWarning
from calnet.spec import load_spec, read_all

SPACING_TWICE_P = "id,power,speed,power,pdas\n1,100,0.5,120,0.3\n2,150,1.0,160,0.35\n"


def test_a_column_named_twice_is_a_one_line_error(base_spec, write_spec):
    path = write_spec(base_spec, spacing=SPACING_TWICE_P)
    with pytest.raises(SpecError, match=r"column 'power' appears twice in the header") as err:
        load_spec(path)
    assert err.value.file.endswith("spacing.csv")
    result = CliRunner().invoke(app, ["check", str(path)], terminal_width=400)
    assert result.exit_code == 2, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and "spacing.csv" in lines[0] and "'power'" in lines[0], lines


def test_a_points_file_with_a_column_named_twice_is_refused(tmp_path):
    points = tmp_path / "points.csv"
    points.write_text("P,v,P\n200,0.5,210\n")
    result = CliRunner().invoke(app, ["predict", "examples/ninb", "--csv", str(points)],
                                terminal_width=400)
    assert result.exit_code == 2, result.output
    assert result.output.strip() == (f"error: --csv {points}: column 'P' appears twice in the "
                                     "header; give each column its own name")


WIDTH_REPEATED = ("id,power,speed,width,split\n1,100,0.5,90,train\n2,150,1.0,80,train\n"
                  "3,100,0.5,90,train\n4,200,1.5,85,test\n5,100,0.5,91,train\n")


def test_a_measurement_given_twice_in_a_file_counts_once(base_spec, write_spec):
    path = write_spec(base_spec, width=WIDTH_REPEATED)
    with pytest.warns(SpecWarning, match=r"width.csv: data.width: 1 row\(s\) repeat an earlier "
                      r"measurement .*: P=100, v=0.5, W=90 \(line 4 repeats line 2\)"):
        data = read_all(load_spec(path))["width"]
    # the copy is left out; a second measurement at the same setting (91) is kept
    assert data.y.tolist() == [90, 80, 85, 91]


def test_the_same_file_twice_for_one_output_is_an_error(base_spec, write_spec):
    base_spec["data"]["width_again"] = dict(base_spec["data"]["width"])
    with pytest.raises(SpecError, match="data sets 'width' and 'width_again' both read "
                       "'width.csv' for heat.W, so each measurement would count twice"):
        load_spec(write_spec(base_spec))


def test_rows_of_another_data_set_of_the_same_output_count_once(base_spec, write_spec,
                                                                   tmp_path):
    (tmp_path / "more.csv").write_text("power,speed,width\n150,1.0,80\n180,1.2,83\n")
    base_spec["data"]["more"] = {"path": "more.csv", "observes": "heat.W",
                                 "columns": {"P": "power", "v": "speed", "W": "width"}}
    with pytest.warns(SpecWarning, match=r"more.csv: data.more: 1 row\(s\) .*P=150, v=1, W=80 "
                      r"\(also in data set 'width'\)"):
        data = read_all(load_spec(write_spec(base_spec)))
    assert data["more"].y.tolist() == [83] and len(data["width"].y) == 3


def test_a_data_set_that_only_repeats_another_is_an_error(base_spec, write_spec, tmp_path):
    """A copy of another data set's file would be left with no row (and the run crashed
    in the surrogate check): a one-line error names it."""
    base_spec["data"]["copy"] = {**base_spec["data"]["width"], "path": "copy.csv"}
    path = write_spec(base_spec)
    (path.parent / "copy.csv").write_text((path.parent / "width.csv").read_text())
    with pytest.raises(SpecError, match="every row of data set 'copy' repeats a measurement "
                       "of heat.W in data set 'width', so it adds nothing; remove it"):
        read_all(load_spec(path))


def test_a_repeated_row_outside_the_bounds_is_counted_once(base_spec, write_spec):
    """The bounds warning counts the rows that enter the calibration: a copy left out
    is not a second point outside the bounds."""
    width = ("id,power,speed,width,split\n1,300,0.5,90,train\n2,150,1.0,80,train\n"
             "3,300,0.5,90,train\n4,200,1.5,85,test\n")
    path = write_spec(base_spec, width=width)
    with pytest.warns(SpecWarning) as caught:
        data = read_all(load_spec(path))["width"]
    said = [str(w.message) for w in caught]
    assert any("1 of 3 point(s) lie outside the model's input bounds" in m for m in said), said
    assert len(data.y) == 3


def test_a_column_of_a_linked_input_is_said_to_be_unread(base_spec, write_spec):
    """Read by bare names, a data set's columns named like a linked input (of the observed
    model or one upstream) are not read: the network computes those inputs. Said, so that
    a measured value a user expects to count is not dropped in silence."""
    del base_spec["data"]["spacing"]["columns"]
    path = write_spec(base_spec, spacing="id,P,v,G,S,lam\n1,100,0.5,2e6,0.5,0.3\n"
                                          "2,150,1.0,3e6,1.0,0.35\n")
    with pytest.warns(SpecWarning) as said:
        data = read_all(load_spec(path))["spacing"]
    text = sorted({str(w.message) for w in said if "not read" in str(w.message)})
    assert text == ["spacing.csv: data.spacing: columns 'G' (micro.G is linked from heat.G), "
                    "'S' (micro.S is linked from heat.v) not read: the network computes "
                    "linked inputs from the models upstream; remove the column, or the link "
                    "to set the input from the data"], text
    assert data.input_keys == ("heat.P", "heat.v")


def test_a_value_just_beyond_a_bound_is_shown_with_the_digits_that_say_so(base_spec,
                                                                          write_spec):
    """250.00000000000003 W beside the bound 250 would read '[250, 250] vs bounds
    [50, 250]' at six digits; it is shown in full."""
    width = ("id,power,speed,width,split\n1,250.00000000000003,0.5,90,train\n"
             "2,150,1.0,80,train\n3,200,1.5,85,test\n")
    path = write_spec(base_spec, width=width)
    with pytest.warns(SpecWarning) as caught:
        read_all(load_spec(path))
    said = " ".join(str(w.message) for w in caught)
    assert "heat.P in [250.00000000000003, 250.00000000000003] vs bounds [50, 250]" in said
