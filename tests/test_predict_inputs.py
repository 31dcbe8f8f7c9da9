"""``calnet predict``'s inputs as calnet.predict resolves them: points from a CSV file, the
run's files, the targets, and the ranking of the variance shares."""

from types import SimpleNamespace

import numpy as np
import pytest

from calnet.errors import CalnetError, UsageError
from calnet.predict import (
    Prediction,
    largest_shares,
    load_run,
    prediction_targets,
    read_points,
    shares_per_point,
)


def test_points_from_a_csv_file(tmp_path):
    path = tmp_path / "points.csv"
    path.write_text("P,melt_pool.v\n200,0.5\n150,1.25\n")
    assert read_points(path) == [{"P": 200.0, "melt_pool.v": 0.5},
                                 {"P": 150.0, "melt_pool.v": 1.25}]


def test_text_cells_stay_text(tmp_path):
    """An ID column, or a typo in an input column: the targets' inputs decide."""
    path = tmp_path / "points.csv"
    path.write_text("P,label\n200,a\nfast,b\n")
    assert read_points(path) == [{"P": 200.0, "label": "a"}, {"P": "fast", "label": "b"}]


@pytest.mark.parametrize(("text", "message"), [
    (None, "no file"),
    ("P,v\n", "no rows"),
])
def test_a_bad_points_file_says_what_is_wrong(tmp_path, text, message):
    path = tmp_path / "points.csv"
    if text is not None:
        path.write_text(text)
    with pytest.raises(UsageError, match=message):
        read_points(path)


def test_the_largest_variance_shares_per_point_come_first():
    # budget (variance by source) at two points: shares are the fractions of the sum
    budget = {"parameters": np.array([1.0, 6.0]), "noise": np.array([3.0, 2.0]),
              "discrepancy": np.array([4.0, 0.0]), "emulator M.y": np.array([2.0, 2.0])}
    pred = Prediction("d", "M.y", ("M.x",), np.zeros((2, 1)), np.zeros(2), np.zeros(2),
                      np.zeros(2), budget)
    shares = shares_per_point(pred)
    assert shares[0] == pytest.approx({"parameters": 0.1, "noise": 0.3, "discrepancy": 0.4,
                                       "emulator M.y": 0.2})
    assert sum(shares[1].values()) == pytest.approx(1.0)
    top = largest_shares(pred, n=2)
    assert [k for k, _ in top[0]] == ["discrepancy", "noise"]
    assert [k for k, _ in top[1]] == ["parameters", "noise"]  # a tie keeps budget order
    assert top[1][0][1] == pytest.approx(0.6)


def test_a_run_folder_without_surrogates_is_named(tmp_path):
    with pytest.raises(CalnetError, match="no fitted surrogates in .*run 'calnet run SPEC"):
        load_run(None, tmp_path)


def test_targets_default_to_the_data_sets_and_predicted_outputs():
    network = SimpleNamespace(settings=SimpleNamespace(predict=("M2.z",)))
    sur = SimpleNamespace(items={"M1.y": None, "M2.z": None})
    post = SimpleNamespace(hyper={"width": {}})
    assert prediction_targets(network, sur, post) == ["width", "M2.z"]
    assert prediction_targets(network, sur, post, ["M1.y"]) == ["M1.y"]
    with pytest.raises(CalnetError, match=r"nothing to predict for \['depth', 'M3.q'\]"):
        prediction_targets(network, sur, post, ["depth", "M3.q"])
    empty = SimpleNamespace(settings=SimpleNamespace(predict=()))
    with pytest.raises(CalnetError, match="settings.predict is empty; pass -d"):
        prediction_targets(empty, sur, SimpleNamespace(hyper={}))
