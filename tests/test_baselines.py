"""Naive baselines beside calnet's validation metrics (method.md section 7)."""

from __future__ import annotations

import numpy as np

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
