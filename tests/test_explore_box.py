"""The box the Sobol indices and process maps are computed over: the data's range,
widened a little, never past an input's declared bounds."""

from __future__ import annotations

import textwrap

import numpy as np
from network_helpers import write_csv

from calnet.explore import process_box
from calnet.spec import load_spec, read_all


def test_the_box_widens_on_the_log_scale_and_keeps_to_the_bounds(tmp_path):
    (tmp_path / "network.yaml").write_text(textwrap.dedent("""
        name: box
        models:
          A:
            simulator: python:box_sims:a
            inputs: {P: {lower: 1, upper: 100, scale: log}, q: {lower: 0, upper: 1}}
            parameters: {a: {lower: 0.5, upper: 2}}
            outputs: {T: {measurable: true, transform: log}}
        data:
          d: {path: d.csv, observes: A.T, columns: {P: P, q: q, T: T}}
        """))
    P = np.array([1.1353, 3.0, 20.0, 83.8136])
    q = np.array([0.0, 0.4, 0.7, 0.99])
    write_csv(tmp_path / "d.csv", P=P, q=q, T=1.2 * np.sqrt(P) * (1 + q))
    network = load_spec(tmp_path)
    box = process_box(read_all(network)["d"], network)
    # ln P widened by 2 % of its span on both sides, inside [1, 100]
    span = np.log(83.8136 / 1.1353)
    np.testing.assert_allclose(box[0], [1.1353 * np.exp(-0.02 * span),
                                        83.8136 * np.exp(0.02 * span)], rtol=1e-12)
    assert 1.0 <= box[0, 0] and box[0, 1] <= 100.0
    # q on its linear scale: the lower end stops at the bound 0, the upper at 1
    np.testing.assert_allclose(box[1], [0.0, 1.0])
    # without the network: the data's range widened linearly (no bounds known)
    assert process_box(read_all(network)["d"])[0, 0] < 0


def test_an_input_the_data_never_vary_is_warned_of_and_spans_its_bounds(tmp_path):
    import pytest

    from calnet.errors import SpecWarning

    (tmp_path / "network.yaml").write_text(textwrap.dedent("""
        name: same
        models:
          A:
            simulator: python:box_sims:a
            inputs: {x: {lower: 0, upper: 1}, z: {lower: 2, upper: 4}}
            parameters: {a: {lower: 0.5, upper: 2}}
            outputs: {y: {measurable: true}}
        data:
          d: {path: d.csv, observes: A.y}
        """))
    write_csv(tmp_path / "d.csv", x=np.full(5, 0.5), z=np.linspace(2.5, 3.5, 5),
              y=np.arange(5.0))
    with pytest.warns(SpecWarning, match=r"d.csv: data.d: all 5 points have A.x = 0.5: the "
                                         r"data inform the model at that setting only"):
        network = load_spec(tmp_path)  # which reads the data to check them
        data = read_all(network)["d"]
    box = process_box(data, network)
    np.testing.assert_allclose(box[0], [0.0, 1.0])  # the declared bounds, not [0.5, 0.5]
    assert 2.5 > box[1, 0] > 2.45 and 3.5 < box[1, 1] < 3.55  # z varies: its own range
