"""A new measurement's noise in a prediction: a known sd in the data's units, on an
output modelled on the log scale, is the relative sd / y of the value predicted there."""

from __future__ import annotations

import numpy as np
import pytest
from network_helpers import fitted_network, on_path, write_csv

SD = 0.5  # known noise sd, data units


@pytest.fixture(scope="module")
def log_output(tmp_path_factory):
    root = tmp_path_factory.mktemp("log_known_noise")
    (root / "expsim.py").write_text(
        "import math\n\ndef f(inputs):\n    return {'y': math.exp(inputs['a'] + inputs['x'])}\n")
    (root / "network.yaml").write_text(
        "models:\n"
        "  m:\n"
        "    simulator: python:expsim:f\n"
        "    inputs: {x: {lower: 0, upper: 3}}\n"
        "    parameters: {a: {lower: 0, upper: 2}}\n"
        "    outputs: {y: {measurable: true, transform: log}}\n"
        "    campaign: {runs: 30}\n"
        "data:\n"
        f"  d: {{path: d.csv, observes: m.y, noise: {{sd: {SD}}}, discrepancy: none}}\n"
        "settings: {seed: 3, sampler: {chains: 2, warmup: 300, draws: 300},\n"
        "           calibration: {emulator_variance: false}}\n")
    x = np.linspace(0.2, 2.8, 25)
    y = np.exp(1.0 + x) + SD * np.random.default_rng(0).standard_normal(x.size)
    write_csv(root / "d.csv", x=x, y=y)
    with on_path(root):
        network, sur = fitted_network(root)
        from calnet.calibration import calibrate

        post = calibrate(network, sur, seed=2, warn=False)
    return network, sur, post


def test_a_known_sd_on_a_log_output_is_relative_to_the_value_predicted(log_output):
    from calnet.predict import predict

    network, sur, post = log_output
    x = np.array([[0.3], [2.7]])  # y about 3.7 and 40: the same 0.5 is 13 % and 1.2 %
    pred = predict(network, sur, post, "d", x, n_samples=200)
    half = (pred.upper - pred.lower) / 2
    # the posterior of a is tight (25 points): the band is nearly the noise's alone
    np.testing.assert_allclose(half, 1.96 * SD, rtol=0.12)
    # the noise share of the predictive variance dominates at both ends
    assert np.all(pred.point_shares()["noise"] > 0.8)
