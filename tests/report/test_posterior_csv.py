"""The posterior draws and summary as CSV files beside the netCDFs."""

import csv

import numpy as np
import pytest
from report_inputs import summary as _summary

from calnet.report.posterior_csv import write_posterior_csv


def test_posterior_csv_files(tmp_path):
    """The draws read back exactly (shortest float repr) and the summary has one row per
    calibrated parameter; prior-only models are in neither; nothing else is left."""
    rng = np.random.default_rng(0)
    theta = {"thermal": rng.normal(size=(5, 2)) * [1.0, 1e-7], "micro": rng.normal(size=(5, 2)),
             "extra": rng.normal(size=(5, 1))}
    draws, table = write_posterior_csv(tmp_path / "posterior", theta, _summary())
    assert sorted(p.name for p in (tmp_path / "posterior").iterdir()) == [
        "posterior_draws.csv", "posterior_summary.csv"]
    with open(draws, newline="") as fh:
        rows = list(csv.reader(fh))
    assert rows[0] == ["draw", "thermal.a", "thermal.s", "micro.b", "micro.s"]
    got = np.array([[float(x) for x in r] for r in rows[1:]])
    np.testing.assert_array_equal(got[:, 0], np.arange(5))
    np.testing.assert_array_equal(got[:, 1:], np.hstack([theta["thermal"], theta["micro"]]))
    with open(table, newline="") as fh:
        summary = list(csv.DictReader(fh))
    assert [(r["model"], r["parameter"]) for r in summary] == [
        ("thermal", "a"), ("thermal", "s"), ("micro", "b"), ("micro", "s")]
    assert float(summary[2]["mean"]) == 0.8 and summary[2]["unit"] == "um"
    assert float(summary[2]["q97.5"]) == 0.9 and summary[1]["shared"] == "True"
    assert summary[0]["shared"] == "" and float(summary[0]["rhat"]) == 1.0


def test_a_folder_that_cannot_be_made_is_one_error(tmp_path):
    from calnet.errors import CalnetError

    (tmp_path / "posterior").write_text("a file where the folder should be")
    with pytest.raises(CalnetError, match="cannot write"):
        write_posterior_csv(tmp_path / "posterior", {}, {})
