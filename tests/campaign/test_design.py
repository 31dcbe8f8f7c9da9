"""Latin hypercube designs: stratified, seeded, augmentable."""

import numpy as np
import pytest

from calnet.campaign.design import augment, latin_hypercube
from calnet.errors import CampaignError
from calnet.spec import Input, Model, Output, Parameter, SimulatorRef


def _model(name="m"):
    return Model(name=name, simulator=SimulatorRef(kind="python", target="a:f"),
                 inputs=[Input(name="P", lower=80, upper=250), Input(name="v", lower=0.05,
                                                                     upper=2.0)],
                 parameters=[Parameter(name="k", lower=60, upper=100)],
                 outputs=[Output(name="W")])


def test_every_column_is_stratified_and_inside_the_box():
    d = latin_hypercube(_model(), 50, seed=0)
    assert d.columns == ("P", "v", "k")
    assert d.points.shape == (50, 3)
    bins = np.floor(d.unit * 50).astype(int)
    for j in range(3):  # one point per stratum in each column: a Latin hypercube
        assert sorted(bins[:, j]) == list(range(50))
    assert (d.points >= d.lower).all() and (d.points <= d.upper).all()


def test_design_depends_only_on_seed_model_and_runs():
    a = latin_hypercube(_model(), 20, seed=0)
    np.testing.assert_array_equal(a.unit, latin_hypercube(_model(), 20, seed=0).unit)
    assert not np.allclose(a.unit, latin_hypercube(_model(), 20, seed=1).unit)
    assert not np.allclose(a.unit, latin_hypercube(_model("other"), 20, seed=0).unit)
    assert a.row(3) == {c: float(v) for c, v in zip(a.columns, a.points[3], strict=True)}


def test_space_filling_beats_a_plain_hypercube():
    from scipy.stats import qmc

    ours = qmc.discrepancy(latin_hypercube(_model(), 40, seed=3).unit)
    plain = np.mean([qmc.discrepancy(qmc.LatinHypercube(d=3, rng=s).random(40))
                     for s in range(10)])
    assert ours < plain


def test_augment_keeps_old_points_and_fills_gaps():
    d = latin_hypercube(_model(), 20, seed=0)
    more = augment(d, 10, seed=0, model_name="m")
    assert len(more) == 30
    np.testing.assert_array_equal(more.unit[:20], d.unit)
    new = more.unit[20:]
    assert ((new >= 0) & (new <= 1)).all()
    gap = np.min(np.linalg.norm(new[:, None] - d.unit[None], axis=-1), axis=1)
    rand = np.random.default_rng(0).random((10, 3))
    gap_rand = np.min(np.linalg.norm(rand[:, None] - d.unit[None], axis=-1), axis=1)
    assert gap.mean() > gap_rand.mean()
    np.testing.assert_array_equal(more.unit, augment(d, 10, seed=0, model_name="m").unit)


def test_bad_sizes_say_what_to_do():
    with pytest.raises(CampaignError, match="at least 1 run"):
        latin_hypercube(_model(), 0, seed=0)
    with pytest.raises(CampaignError, match="seed must be >= 0"):
        latin_hypercube(_model(), 5, seed=-1)


def test_log_scale_inputs_are_stratified_in_log_x():
    m = Model(name="m", simulator=SimulatorRef(kind="python", target="a:f"),
              inputs=[Input(name="G", lower=1e4, upper=1e8, scale="log")],
              parameters=[Parameter(name="k", lower=0, upper=1)], outputs=[Output(name="y")])
    d = latin_hypercube(m, 40, seed=0)
    g = d.points[:, 0]
    assert (g >= 1e4).all() and (g <= 1e8).all()
    bins = np.floor((np.log10(g) - 4) / 4 * 40).astype(int)
    assert sorted(bins) == list(range(40))  # one point per decade-quarter stratum
    more = augment(d, 5, seed=0, model_name="m")
    np.testing.assert_allclose(more.points[:40], d.points)
    assert (more.points[40:, 0] >= 1e4).all() and (more.points[40:, 0] <= 1e8).all()
