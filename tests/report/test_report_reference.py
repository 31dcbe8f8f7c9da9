"""A reference study's published values beside a run's, from reference.json in the
spec's folder; no file, no comparison."""

import json
from types import SimpleNamespace

import numpy as np
import pytest
from report_inputs import calibration, summary

from calnet.errors import SpecError
from calnet.report.reference import read_reference, reference_rows
from calnet.results import DatasetValidation, RunResults

REFERENCE = {"dataset": "pdas", "label": "PDAS", "test": {"mape": 5.7, "rmse": 0.023},
             "baselines_test_mape": {"training_mean": 6.9, "power_law": 6.6},
             "dominant_input": "v (scan speed)", "modes": {"micro": {"b": 0.75, "zz": 1.0}}}


def _results(reference):
    pdas = DatasetValidation(
        train={"n": 8}, pit=np.zeros(0), loo={}, variance_shares={},
        test={"n": 3, "mape": 4.2, "rmse": 0.031},
        baselines_test={"training_mean": {"mape": 7.1}, "direct_gp": {"error": "few"}})
    indices = SimpleNamespace(names=("P", "v"), ST=np.array([0.2, 0.7]))
    return RunResults("t", False, {}, None, calibration(summary()), validation={"pdas": pdas},
                      sensitivity={"pdas": SimpleNamespace(indices=indices)},
                      reference=reference)


def test_rows_set_the_published_values_beside_the_run(tmp_path):
    (tmp_path / "reference.json").write_text(json.dumps(REFERENCE))
    rows = reference_rows(_results(read_reference(tmp_path)), {"pdas": "um"})
    assert rows == [["PDAS test MAPE %", "5.7", "4.2"],
                    ["PDAS test SE_pred = RMSE (um)", "0.023", "0.031"],
                    ["PDAS test MAPE %, training-mean baseline", "6.9", "7.1"],
                    ["dominant input (total effect)", "v (scan speed)", "v"],
                    ["mode micro.b", "0.75", "0.8"]]  # no power law run, no parameter zz


def test_no_file_no_rows_and_a_broken_file_is_named(tmp_path):
    assert read_reference(tmp_path) is None
    assert reference_rows(_results(None), {}) == []
    (tmp_path / "reference.json").write_text("{not json")
    with pytest.raises(SpecError, match="reference.json: not valid JSON"):
        read_reference(tmp_path)
    (tmp_path / "reference.json").write_text("[1, 2]")
    with pytest.raises(SpecError, match="expected a JSON object"):
        read_reference(tmp_path)


def test_the_case_study_reference_names_what_the_spec_declares():
    from pathlib import Path

    from calnet.spec import load_spec

    network = load_spec(Path(__file__).resolve().parents[2] / "examples" / "ninb")
    ref = read_reference(network.path("."))
    assert ref is not None and network.dataset(ref["dataset"]).observes == (
        "solidification.lambda")
    for model, modes in ref["modes"].items():
        assert set(modes) <= {p.name for p in network.model(model).parameters}, model
