"""Data files that would mislead the calibration: a column name given twice in a header
(pandas would rename the second one ``P.1``) and a measurement given twice (it would
count twice in the likelihood)."""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

from calnet.cli import app
from calnet.errors import SpecError
from calnet.spec import load_spec

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
    assert result.exit_code == 1, result.output
    assert result.output.strip() == (f"error: --csv {points}: column 'P' appears twice in the "
                                     "header; give each column its own name")
