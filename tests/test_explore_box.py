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


def test_sobol_indices_are_uniform_in_each_inputs_own_scale(tmp_path, monkeypatch):
    """An input of scale: log is uniform in ln x over the box: for y = ln P + b q the
    indices are the variance shares of ln P and b q, (ln span)^2 / 12 and b^2 span^2 / 12
    (the shares under P uniform in P itself differ by far more than the tolerance)."""
    from types import SimpleNamespace

    import calnet.explore as explore

    test_the_box_widens_on_the_log_scale_and_keeps_to_the_bounds(tmp_path)  # writes it
    network = load_spec(tmp_path)
    data = read_all(network)["d"]
    box = process_box(data, network)
    b = 3.0

    def truth(network, surrogates, posterior, name, idx, per_draw=False):
        def f(x):
            y = np.log(x[:, 0]) + b * x[:, 1]
            return np.tile(y, (len(idx), 1)) if per_draw else y
        return f

    monkeypatch.setattr(explore, "mean_function", truth)
    monkeypatch.setattr(explore, "predict", lambda *a, **k: SimpleNamespace(  # the map
        mean=np.zeros(explore.GRID**2), prob=None))
    res = explore.explore_dataset(network, None, SimpleNamespace(n_draws=50), data, seed=1)
    v_p = np.log(box[0, 1] / box[0, 0]) ** 2 / 12
    v_q = (b * (box[1, 1] - box[1, 0])) ** 2 / 12
    expect = np.array([v_p, v_q]) / (v_p + v_q)
    np.testing.assert_allclose(res.indices.ST, expect, atol=0.03)
    np.testing.assert_allclose(res.indices.S1, expect, atol=0.03)
    p = np.random.default_rng(0).uniform(*box[0], 200_000)  # P uniform in P instead
    linear = np.var(np.log(p)) / (np.var(np.log(p)) + v_q)
    assert abs(linear - expect[0]) > 0.1
    # the map's grid is even in each input's own scale too, and says which axes are log
    grid = res.map
    assert grid.log == (True, False)
    np.testing.assert_allclose(np.diff(np.log(grid.axis0)), np.log(box[0, 1] / box[0, 0])
                               / (explore.GRID - 1))
    np.testing.assert_allclose(np.diff(grid.axis1), (box[1, 1] - box[1, 0]) / (explore.GRID - 1))
