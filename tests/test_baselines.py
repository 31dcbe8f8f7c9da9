"""Naive baselines beside calnet's validation metrics (method.md section 7)."""

from __future__ import annotations

import numpy as np
import pytest

from calnet.spec import ExperimentalData
from calnet.validation import _power_law


def _data(x, y, name="d"):
    return ExperimentalData(name, "m.y", ("m.P", "m.v"), np.asarray(x, float),
                            np.asarray(y, float), np.zeros(len(y), bool),
                            tuple(str(i) for i in range(len(y))))


def test_power_law_baseline_recovers_an_exact_power_law():
    rng = np.random.default_rng(0)
    x = np.column_stack([rng.uniform(80, 250, 12), rng.uniform(0.05, 2.0, 12)])
    y = 0.7 * x[:, 0] ** 0.25 * x[:, 1] ** -0.4
    res = _power_law(_data(x[:8], y[:8]), _data(x[8:], y[8:]))
    np.testing.assert_allclose(res["exponents"], [0.25, -0.4], rtol=1e-10)
    assert res["mape"] < 1e-8 and res["n"] == 4


def test_power_law_baseline_is_skipped_for_non_positive_or_too_few_points():
    x = np.array([[1.0, 2.0], [2.0, 1.0], [3.0, 3.0]])
    assert _power_law(_data(x, [1.0, -1.0, 2.0]), _data(x, [1.0, 1.0, 1.0])) is None
    assert _power_law(_data(x, [1.0, 2.0, 3.0]), _data(x, [1.0, 1.0, 1.0])) is None  # 3 <= 3


def test_metrics_scores_against_closed_forms():
    """CRPS of a Gaussian predictive (closed form), the interval score, NRMSE, and MAPE
    left out where observations come near zero."""
    from scipy import stats

    from calnet.predict import metrics

    rng = np.random.default_rng(0)
    y = np.array([1.0, 2.0, 4.0])
    samples = rng.normal(y[None] + 0.5, 1.0, size=(200000, 3))
    z = -0.5
    crps = z * (2 * stats.norm.cdf(z) - 1) + 2 * stats.norm.pdf(z) - 1 / np.sqrt(np.pi)
    m = metrics(y, y + 0.5, y - 1.0, y + 0.2, samples=samples,
                pit=np.array([0.3, 0.95, 0.99]))
    assert abs(m["crps"] - crps) < 5e-3
    assert m["rmse"] == pytest.approx(0.5) and m["nrmse"] == pytest.approx(0.5 / 3)
    assert m["interval_score95"] == pytest.approx(1.2)  # every y inside its band
    assert m["mape"] == pytest.approx(100 * np.mean(0.5 / y))
    assert (m["pit_coverage50"], m["pit_coverage80"], m["pit_coverage95"]) == \
        pytest.approx((1 / 3, 1 / 3, 2 / 3))
    missed = metrics(np.array([0.0, 1.0]), np.array([0.0, 1.0]), np.array([0.5, 0.5]),
                     np.array([1.0, 1.0]))
    assert missed["interval_score95"] == pytest.approx(0.5 + (2 / 0.05) * 0.5 / 2)
    assert missed["mape"] is None  # a zero observation: percentages are meaningless
    assert metrics(np.array([-0.2, 1.0]), np.array([0.0, 1.0]))["mape"] is None
    # positive data over two decades: near zero on their own range, but modelled on the
    # log scale their errors are relative, and the MAPE is what a user reads
    wide, off = np.array([0.5, 5.0, 50.0]), np.array([0.55, 4.5, 55.0])
    assert metrics(wide, off)["mape"] is None
    assert metrics(wide, off, relative=True)["mape"] == pytest.approx(10.0)
    assert metrics(np.array([-0.2, 1.0]), np.array([0.0, 1.0]), relative=True)["mape"] is None
    # a split's MAPE follows the whole data set's: three positive test points of a data
    # set that crosses zero get none
    pos, near = np.array([2.0, 3.0]), np.array([2.2, 3.0])
    assert metrics(pos, near)["mape"] == pytest.approx(5.0)
    assert metrics(pos, near, mape_y=np.r_[pos, -1.0, 0.5])["mape"] is None
    # the NRMSE of a split on the whole data set's range: one point has one too
    assert metrics(np.array([2.0]), np.array([2.5]), y_range=4.0)["nrmse"] == 0.125
    assert metrics(np.array([2.0]), np.array([2.5]))["nrmse"] is None


def test_the_baselines_score_the_test_points_on_the_data_sets_range():
    """The test rows' NRMSE divides by the range of all the data set's measurements, as
    calnet's rows do, not by the range of the few test values."""
    from calnet.validation import baselines

    x = np.array([[100.0, 0.5], [150.0, 1.0], [200.0, 1.5], [250.0, 2.0]])
    train, test = _data(x[:3], [1.0, 5.0, 9.0]), _data(x[3:], [4.0])
    from types import SimpleNamespace

    box = {"P": (50.0, 300.0), "v": (0.1, 2.5)}
    model = SimpleNamespace(variable=lambda n: SimpleNamespace(lower=box[n][0],
                                                               upper=box[n][1]))
    def network(transform=None):
        return SimpleNamespace(model=lambda m: model, dataset=lambda name: name,
                               observed=lambda ds: SimpleNamespace(transform=transform))

    got = baselines(network(), train, test)["training_mean"]
    assert got["rmse"] == pytest.approx(1.0) and got["nrmse"] == pytest.approx(1.0 / 8.0)
    # measurements over two decades: no MAPE on the linear scale, a MAPE where the data
    # set is modelled on the log scale (its errors are relative)
    train, test = _data(x[:2], [0.5, 50.0]), _data(x[2:], [0.4, 40.0])
    assert baselines(network(), train, test)["training_mean"]["mape"] is None
    rel = baselines(network("log"), train, test)["training_mean"]["mape"]
    assert rel == pytest.approx(50 * (abs(0.4 - 25.25) / 0.4 + abs(40.0 - 25.25) / 40.0))


def test_a_naive_predictor_far_better_than_the_network_is_warned_of():
    from calnet.validation import baseline_check

    test = {"n": 4, "rmse": 0.125}
    naive = {"training_mean": {"rmse": 0.4}, "direct_gp": {"rmse": 0.0303},
             "power_law": {"error": "no positive data"}}
    said = baseline_check("d", test, naive)
    assert said.startswith("d: a GP fitted directly to the training points predicts the 4 "
                           "test point(s) 4.1 times better than the calibrated network "
                           "(RMSE 0.0303 against 0.125)"), said
    assert baseline_check("d", test, {"direct_gp": {"rmse": 0.07}}) is None  # within 2x
    assert baseline_check("d", None, naive) is None and baseline_check("d", test, {}) is None
