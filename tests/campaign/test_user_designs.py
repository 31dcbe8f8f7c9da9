"""Designs chosen in the spec: quasi-random, a file of points, chain-aware."""

from __future__ import annotations

import sqlite3

import numpy as np
import pandas as pd
import pytest
import yaml
from campaign_helpers import campaign_app, chain_spec, store_rows, toy_spec
from typer.testing import CliRunner

from calnet.campaign import default_store, load_runs, run_campaign, runs_frame
from calnet.campaign.store import RunStore
from calnet.errors import CampaignError, CampaignWarning, SpecError
from calnet.spec import load_spec


def run(network, model: str = "toy", **kw):
    """Run (or resume) a campaign of the toy simulators in this process."""
    return run_campaign(network, model, executor="in-process", progress=False, **kw)


def with_campaign(spec, model: str = "toy", **campaign):
    doc = yaml.safe_load(spec.read_text())
    doc["models"][model]["campaign"] = {**doc["models"][model].get("campaign", {}), **campaign}
    spec.write_text(yaml.safe_dump(doc, sort_keys=False))
    return load_spec(spec)


@pytest.mark.parametrize("kind", ["sobol", "halton"])
def test_quasi_random_designs_are_fixed_by_the_seed(tmp_path, kind):
    stores = {}
    for name, seed in (("a", 3), ("b", 3), ("c", 4)):
        net = with_campaign(toy_spec(tmp_path / name, runs=6, seed=seed), design=kind)
        summary = run(net, "toy")
        assert (summary.planned, summary.design) == (6, kind)
        stores[name] = store_rows(summary.store_path, drop=("wall_time", "started_at",
                                                             "finished_at", "diagnostics"))
    assert stores["a"] == stores["b"]
    assert stores["a"] != stores["c"]
    X = load_runs(load_spec(tmp_path / "a" / "network.yaml"), "toy").X
    assert ((X >= [0, 0, -1]) & (X <= [1, 1, 1])).all()


def test_a_sobol_design_is_the_scrambled_sequence(tmp_path):
    """Cross-check with SciPy: the design is the scrambled Sobol sequence, mapped to the box."""
    from scipy.stats import qmc

    from calnet.campaign.design import design_rng

    net = with_campaign(toy_spec(tmp_path, runs=5, seed=2), design="sobol")
    X = load_runs(net, "toy", store=run(net, "toy").store_path).X
    unit = qmc.Sobol(d=3, rng=design_rng(2, "toy", 5)).random_base2(3)[:5]
    np.testing.assert_allclose(X, unit * [1, 1, 2] + [0, 0, -1], rtol=0, atol=1e-15)


def test_a_design_file_is_run_as_given_and_grows_at_its_end(tmp_path):
    spec = toy_spec(tmp_path, runs=50)
    points = pd.DataFrame({"x": [0.1, 0.2, 0.3], "a": [0.5, 0.5, 0.5],
                           "b": [0.0, 0.1, -0.3]})
    points.to_csv(tmp_path / "points.csv", index=False)
    net = with_campaign(spec, design="points.csv")
    summary = run(net, "toy")
    assert (summary.planned, summary.ran, summary.design) == (3, 3, "file:points.csv")
    np.testing.assert_array_equal(load_runs(net, "toy").X, points.to_numpy())  # exact
    assert runs_frame(summary.store_path).source.tolist() == ["file:points.csv"] * 3
    more = pd.concat([points, pd.DataFrame({"x": [0.9], "a": [0.1], "b": [0.9]})])
    more.to_csv(tmp_path / "points.csv", index=False)
    again = run(net, "toy")
    assert (again.planned, again.skipped, again.ran) == (4, 3, 1)
    grown = run(net, "toy", runs=6)  # maximin points after the file's
    assert (grown.planned, grown.ran) == (6, 2)
    assert run(net, "toy").ran == 0
    assert runs_frame(summary.store_path).source.tolist()[4:] == ["maximin"] * 2
    more = pd.concat([more, pd.DataFrame({"x": [0.4], "a": [0.7], "b": [0.2]})])
    more.to_csv(tmp_path / "points.csv", index=False)  # a row at the file's end again
    after = run(net, "toy")
    assert (after.planned, after.ran) == (7, 1)
    assert runs_frame(summary.store_path).source.tolist()[-1] == "file:points.csv"
    more.iloc[[1, 0, 2, 3]].to_csv(tmp_path / "points.csv", index=False)
    with pytest.raises(CampaignError, match=r"design file '.*points.csv' changed: row 1"):
        run(net, "toy")


def test_a_bad_design_file_is_one_line(tmp_path):
    spec = toy_spec(tmp_path)
    pd.DataFrame({"x": [0.1, 0.2], "b": [0.0, 0.1]}).to_csv(tmp_path / "p.csv", index=False)
    with_campaign(spec, design="p.csv")
    app = campaign_app()
    out = CliRunner().invoke(app, ["campaign", str(spec), "--no-progress"])
    assert out.exit_code == 1
    assert "has no column 'a'; a design file of 'toy' needs columns x, a, b" in " ".join(
        out.output.split())
    with_campaign(spec, design="missing.csv")
    out = CliRunner().invoke(app, ["campaign", str(spec), "--no-progress"])
    assert out.exit_code == 2
    assert "models.toy.campaign.design: no design file" in " ".join(out.output.split())
    assert not (tmp_path / "campaigns").exists()


def test_a_store_keeps_its_design_and_an_explicit_other_one_is_refused(tmp_path):
    spec = toy_spec(tmp_path, runs=4)
    run(with_campaign(spec, design="halton"), "toy")
    doc = yaml.safe_load(spec.read_text())
    del doc["models"]["toy"]["campaign"]["design"]
    spec.write_text(yaml.safe_dump(doc))
    grown = run(load_spec(spec), "toy", runs=6)
    assert (grown.ran, grown.design) == (2, "halton")
    with pytest.raises(CampaignError, match="holds a 'halton' design, but the spec asks for "
                                            "'sobol'; set campaign.design: halton"):
        run(with_campaign(spec, design="sobol"), "toy")


def test_a_store_from_before_designs_resumes_as_a_latin_hypercube(tmp_path):
    """A store without the provenance columns and the design_kind key (as the shipped ones)
    is read as it is and, augmented, gets the columns and stays a Latin hypercube."""
    net = load_spec(chain_spec(tmp_path, runs=(6, 6, 6)))
    run(net, "M1")
    path = run(net, "M2", seed=0).store_path
    with sqlite3.connect(path) as db:
        db.execute("DELETE FROM runs")
        db.execute("UPDATE meta SET value = ? WHERE key = 'design'",
                   ("scipy.stats.qmc.LatinHypercube(optimization='random-cd')",))
        db.execute("DELETE FROM meta WHERE key = 'design_kind'")
        db.execute("ALTER TABLE runs DROP COLUMN origin")
        db.execute("ALTER TABLE runs DROP COLUMN source")
        db.execute("INSERT INTO runs (idx, input_hash, inputs, seed) VALUES (0, 'h', ?, 0)",
                   ('{"w1": -1.5, "c": 0.05}',))
    db.close()
    with RunStore(path, readonly=True) as ro:
        assert (ro.planned(), ro.imported()) == (1, 0)
    summary = run(net, "M2", runs=4)
    assert (summary.design, summary.ran) == ("lhs", 4)
    assert runs_frame(path).origin.tolist() == ["simulated"] * 4


def test_chain_design_lands_where_the_parent_outputs_land(tmp_path):
    net = load_spec(chain_spec(tmp_path, runs=(8, 10, 10)))
    for name in net.order:
        summary = run(net, name)
        assert summary.design == ("lhs" if name == "M1" else "chain")
    # M1: w1 = 0.5 + 0.4 sin(2x), x in [0, 1]: w1 in [0.5, 0.9]; the 10 % margin of
    # that 0.4 range adds 0.04 on each side (GP error aside: 0.01 allowed)
    w1 = load_runs(net, "M2").X[:, 0]
    assert w1.min() >= 0.5 - 0.05 and w1.max() <= 0.9 + 0.05
    assert w1.max() - w1.min() > 0.35  # spread over the envelope, not bunched
    # M3 along w2 = w1^2 + c, c in [0, 0.1], in a w2 box 10 wide: the margin moves w2 by
    # up to 0.07 (10 % of its 0.66 range), and w1 by 0.04, which moves w1^2 by 0.07
    m3 = load_runs(net, "M3").X
    gap = m3[:, 1] - m3[:, 0] ** 2
    assert gap.min() >= -0.15 and gap.max() <= 0.25
    # a per-box Latin hypercube of M2 spreads over the whole w1 box [-2, 3] instead
    lhs = load_spec(chain_spec(tmp_path / "lhs", runs=(8, 10, 10), design="lhs"))
    run(lhs, "M2")
    assert np.ptp(load_runs(lhs, "M2").X[:, 0]) > 3.0


def test_chain_design_is_resumed_not_replanned(tmp_path):
    net = load_spec(chain_spec(tmp_path, runs=(6, 8, 8)))
    run(net, "M1")
    path = run(net, "M2").store_path
    before = store_rows(path)
    run(net, "M1", runs=12)  # the parent changes...
    with sqlite3.connect(path) as db:  # ... and runs 1 and 4 were in flight when M2 died
        db.execute("UPDATE runs SET status = NULL, outputs = NULL WHERE idx IN (1, 4)")
    db.close()
    summary = run(net, "M2")
    assert (summary.ran, summary.skipped) == (2, 6)
    assert [r[:3] for r in store_rows(path)] == [r[:3] for r in before]  # same points


def test_chain_design_without_parent_runs_falls_back_to_lhs(tmp_path):
    net = load_spec(chain_spec(tmp_path, runs=(6, 8, 8)))
    with pytest.warns(CampaignWarning, match=r"M2: no runs of its parent 'M1'.*Latin "
                                             "hypercube instead.*parents first"):
        summary = run(net, "M2")
    assert summary.n_ok == 8
    assert not default_store(net, "M1").exists()
    assert runs_frame(summary.store_path).source.tolist() == ["lhs"] * 8  # what they are


def test_a_points_file_or_import_under_settings_is_refused(tmp_path):
    spec = toy_spec(tmp_path)
    doc = yaml.safe_load(spec.read_text())
    doc["settings"]["campaign"] = {"import": "runs.csv"}
    spec.write_text(yaml.safe_dump(doc))
    with pytest.raises(SpecError, match=r"settings.campaign.import: 'runs.csv' holds one "
                                        r"model's points or runs; move it under models"):
        run(load_spec(spec))
    doc["settings"]["campaign"] = {"design": "oops"}
    spec.write_text(yaml.safe_dump(doc))
    with pytest.raises(SpecError, match=r"unknown design 'oops'; use one of lhs, sobol, "
                                        "halton, chain or a .csv/.parquet file"):
        load_spec(spec)


def test_chain_design_warns_when_the_chain_leaves_the_bounds(tmp_path):
    """w1 lands in [0.5, 0.9]; M2 declares w1 in [0, 0.6], so about 85 % of the cloud
    (w1 > 0.6) lies outside and is clipped to the bound."""
    net = load_spec(chain_spec(tmp_path, runs=(8, 6, 6), w1_box=(0.0, 0.6)))
    run(net, "M1")
    with pytest.warns(CampaignWarning, match=r"M2: \d+% of the values its input 'w1' takes "
                                             r"from upstream lie outside its bounds \[0, 0.6\]"):
        run(net, "M2")
    w1 = load_runs(net, "M2").X[:, 0]
    assert (w1 >= 0.0).all() and (w1 <= 0.6).all()
