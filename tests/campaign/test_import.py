"""Importing finished runs: validation of the table, provenance, idempotence, round trip."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
import yaml
from campaign_helpers import campaign_app, toy_network, toy_spec
from typer.testing import CliRunner

from calnet.campaign import export_runs, import_runs, load_runs, run_campaign, runs_frame
from calnet.errors import CampaignError, CampaignWarning, SpecError
from calnet.spec import load_spec
from calnet.surrogates import fit_gp


def toy_runs(n: int = 6, seed: int = 3) -> pd.DataFrame:
    """A run table of the toy model (x in [0, 1], a in [0, 1], b in [-1, 1]), outputs
    from the toy simulator's formulas."""
    rng = np.random.default_rng(seed)
    x, a, b = rng.uniform(0, 1, n), rng.uniform(0, 1, n), rng.uniform(-1, 1, n)
    return pd.DataFrame({"x": x, "a": a, "b": b, "y": x * x + a * x + b, "z": x - b})


def write(frame: pd.DataFrame, path):
    frame.to_csv(path, index=False, float_format="%.17g")
    return path


def test_imported_runs_are_first_class_and_carry_their_provenance(tmp_path):
    net = toy_network(tmp_path, runs=4)
    table = write(toy_runs(), tmp_path / "old_runs.csv")
    summary = import_runs(net, "toy", table)
    assert (summary.imported, summary.planned, summary.n_ok) == (6, 0, 6)
    runs = load_runs(net, "toy")
    np.testing.assert_array_equal(runs.X, toy_runs()[["x", "a", "b"]].to_numpy())  # exact
    # a campaign then adds its design beside them: the spec sets runs (4)
    summary = run_campaign(net, "toy", executor="in-process", progress=False)
    assert (summary.planned, summary.ran, summary.n_ok) == (4, 4, 10)
    frame = runs_frame(summary.store_path)
    assert frame.origin.tolist() == ["imported"] * 6 + ["simulated"] * 4
    assert frame.source.tolist() == ["old_runs.csv"] * 6 + ["lhs"] * 4
    assert load_runs(net, "toy").n_ok == 10


def test_importing_the_same_file_again_adds_nothing(tmp_path):
    net = toy_network(tmp_path)
    table = write(toy_runs(), tmp_path / "runs.csv")
    assert import_runs(net, "toy", table).imported == 6
    more = pd.concat([toy_runs(), toy_runs(2, seed=9)], ignore_index=True)
    assert import_runs(net, "toy", write(more, tmp_path / "more.csv")).imported == 2
    assert load_runs(net, "toy").n_ok == 8
    other = toy_runs()
    other.loc[2, "y"] += 1.0
    with pytest.raises(CampaignError, match=r"other.csv: row 3 has the inputs of run 2 .* "
                                            "another result"):
        import_runs(net, "toy", write(other, tmp_path / "other.csv"))


def test_spec_import_key_simulates_nothing_without_runs(tmp_path):
    spec = toy_spec(tmp_path)
    doc = yaml.safe_load(spec.read_text())
    doc["models"]["toy"]["campaign"] = {"import": "data/runs.parquet"}
    spec.write_text(yaml.safe_dump(doc))
    (tmp_path / "data").mkdir()
    toy_runs().to_parquet(tmp_path / "data" / "runs.parquet", index=False)
    net = load_spec(spec)
    first = run_campaign(net, "toy", executor="in-process", progress=False)
    assert (first.imported, first.planned, first.ran, first.n_ok) == (6, 0, 0, 6)
    again = run_campaign(net, "toy", executor="in-process", progress=False)
    assert (again.imported, again.n_ok) == (0, 6)
    (tmp_path / "data" / "runs.parquet").unlink()
    with pytest.raises(SpecError, match=r"models.toy.campaign.import: no run table"):
        run_campaign(net, "toy", executor="in-process", progress=False)


def test_a_planned_point_an_imported_run_holds_is_that_run(tmp_path):
    # the export of a campaign, imported into a new store of the same spec and seed:
    # the design then plans the very same points, which are the imported runs
    net = toy_network(tmp_path, "python:toy_sims:counted", runs=5)
    count = tmp_path / "count.txt"  # one line per simulator call
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("TOY_COUNT_FILE", str(count))
        made = run_campaign(net, "toy", executor="in-process", progress=False,
                            store=tmp_path / "first.sqlite")
        exported = export_runs(made.store_path, tmp_path / "runs.csv")
        store = tmp_path / "second.sqlite"
        assert import_runs(net, "toy", exported, store=store).imported == 5
        again = run_campaign(net, "toy", executor="in-process", progress=False, store=store)
        once_more = run_campaign(net, "toy", executor="in-process", progress=False,
                                 store=store)
    assert len(count.read_text().splitlines()) == 5  # the first campaign's, no more
    assert (again.planned, again.ran, again.status_counts) == (5, 0, {"ok": 5})
    assert once_more.complete and once_more.status_counts == {"ok": 5}
    runs = load_runs(net, "toy", store=store)
    assert (runs.n_total, runs.n_ok, runs.n_excluded) == (5, 5, 0)
    np.testing.assert_array_equal(runs.X, load_runs(net, "toy", store=made.store_path).X)
    # export -> import round-trips: each run once
    frame = runs_frame(store)
    assert len(frame) == 5 and frame.input_hash.is_unique
    assert frame.origin.tolist() == ["imported"] * 5
    back = export_runs(store, tmp_path / "again.csv")
    third = import_runs(net, "toy", back, store=tmp_path / "third.sqlite")
    assert third.imported == 5 and third.status_counts == {"ok": 5}


def test_a_planned_point_within_round_off_of_an_imported_run_is_that_run(tmp_path):
    net = toy_network(tmp_path, "python:toy_sims:counted", runs=6)
    count = tmp_path / "count.txt"
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("TOY_COUNT_FILE", str(count))
        made = run_campaign(net, "toy", executor="in-process", progress=False,
                            store=tmp_path / "first.sqlite")
        frame = runs_frame(made.store_path)
        frame.iloc[:4].to_csv(tmp_path / "short.csv", index=False, float_format="%.15g")
        store = tmp_path / "second.sqlite"
        import_runs(net, "toy", tmp_path / "short.csv", store=store)
        again = run_campaign(net, "toy", executor="in-process", progress=False, store=store)
    assert len(count.read_text().splitlines()) == 6 + 2  # only the 2 points not imported
    assert again.status_counts == {"ok": 6} and again.ran == 2
    assert runs_frame(store).origin.tolist() == ["imported"] * 4 + ["simulated"] * 2


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_export_then_import_gives_the_same_surrogate(tmp_path, suffix):
    net = toy_network(tmp_path, "python:toy_sims:crashy", runs=12)
    made = run_campaign(net, "toy", executor="in-process", progress=False)
    exported = export_runs(made.store_path, tmp_path / f"runs{suffix}")
    copy = import_runs(net, "toy", exported, store=tmp_path / "copy.sqlite")
    assert copy.status_counts == made.status_counts  # failed runs come along, not ok
    a, b = load_runs(net, "toy"), load_runs(net, "toy", store=tmp_path / "copy.sqlite")
    np.testing.assert_array_equal(a.X, b.X)
    np.testing.assert_array_equal(a.Y["y"], b.Y["y"])
    lower, upper = np.array([0.0, 0.0, -1.0]), np.array([1.0, 1.0, 1.0])
    gp_a = fit_gp(a.X, a.Y["y"], lower=lower, upper=upper, n_restarts=1, seed=0)
    gp_b = fit_gp(b.X, b.Y["y"], lower=lower, upper=upper, n_restarts=1, seed=0)
    z = np.random.default_rng(0).uniform(size=(20, 3)) * (upper - lower) + lower
    np.testing.assert_array_equal(np.asarray(gp_a.predict(z)[0]),
                                  np.asarray(gp_b.predict(z)[0]))


def test_status_column_and_unfinished_rows(tmp_path):
    net = toy_network(tmp_path)
    frame = toy_runs(4)
    frame["status"] = ["ok", "failed", "unfinished", None]
    frame.loc[1, "y"] = np.nan  # a failed run may lack its outputs
    summary = import_runs(net, "toy", write(frame, tmp_path / "runs.csv"))
    assert summary.status_counts == {"ok": 2, "failed": 1}
    # --retry-failed runs the design's failures again, never an imported one
    again = run_campaign(net, "toy", executor="in-process", progress=False, retry_failed=True)
    assert (again.ran, again.status_counts) == (12, {"ok": 14, "failed": 1})


def _fails(tmp_path, frame, match, *, name="runs.csv", strict=False):
    net = toy_network(tmp_path, seed=0)
    if strict:
        net = net.model_copy(update={"settings": net.settings.model_copy(
            update={"strict": True})})
    with pytest.raises(CampaignError, match=match):
        import_runs(net, "toy", write(frame, tmp_path / name))
    assert not (tmp_path / "campaigns").exists()  # a bad table writes nothing


def test_a_missing_column_is_named(tmp_path):
    _fails(tmp_path, toy_runs().drop(columns="a"),
           r"'.*runs.csv' has no column 'a'; a run table of 'toy' needs columns x, a, b, y, z")


def test_another_models_table_is_recognised(tmp_path):
    other = pd.DataFrame({"P": [100.0, 200.0], "v": [0.5, 1.0], "W": [80.0, 60.0]})
    _fails(tmp_path, other, r"does not match model 'toy': it lacks x, a, b, y, z .*its "
                            r"columns: P, v, W.*another model")
    frame = toy_runs()
    write(frame, tmp_path / "m.csv")
    (tmp_path / "m.meta.json").write_text(json.dumps({"model": "thermal"}))
    _fails(tmp_path, frame, r"holds runs of model 'thermal' .*--model thermal", name="m.csv")


@pytest.mark.parametrize(("column", "value", "match"), [
    ("b", "abc", r"column 'b', row 3: 'abc' is not a number"),
    ("x", np.nan, r"column 'x', row 3: empty or NaN; every input and parameter needs a finite"),
    ("a", np.inf, r"column 'a', row 3: inf; every input"),
    ("y", np.nan, r"column 'y', row 3: nan in a run with status ok"),
])
def test_bad_values_name_the_column_and_row(tmp_path, column, value, match):
    frame = toy_runs().astype(object)
    frame.loc[2, column] = value
    _fails(tmp_path, frame, match)


def test_duplicate_rows_are_refused(tmp_path):
    frame = toy_runs()
    frame.loc[4] = frame.loc[1]
    _fails(tmp_path, frame, r"rows 2 and 5 have the same x, a, b; remove one")


def test_out_of_bounds_is_a_warning_or_with_strict_an_error(tmp_path):
    frame = toy_runs()
    frame.loc[3, "x"] = 1.5
    _fails(tmp_path / "strict", frame, r"column 'x': 1 row\(s\) outside its bounds \[0, 1\] "
                                       r"\(first: row 4, 1.5\); fix .*strict", strict=True)
    net = toy_network(tmp_path / "lax")
    with pytest.warns(CampaignWarning, match=r"row 4, 1.5\); used as they are"):
        assert import_runs(net, "toy", write(frame, tmp_path / "r.csv")).imported == 6


def test_bad_status_and_not_a_table(tmp_path):
    frame = toy_runs()
    frame["status"] = "ok"
    frame.loc[1, "status"] = "done"
    _fails(tmp_path, frame, r"column 'status', row 2: 'done'; write one of ok, failed")
    net = toy_network(tmp_path)
    (tmp_path / "runs.xlsx").write_text("x")
    with pytest.raises(CampaignError, match="give a .csv or .parquet file"):
        import_runs(net, "toy", tmp_path / "runs.xlsx")
    with pytest.raises(CampaignError, match="no file"):
        import_runs(net, "toy", tmp_path / "none.csv")


def test_cli_import(tmp_path):
    spec = toy_spec(tmp_path)
    table = write(toy_runs(), tmp_path / "runs.csv")
    app = campaign_app()
    ok = CliRunner().invoke(app, ["campaign", str(spec), "--model", "toy", "--import",
                                  str(table)])
    assert ok.exit_code == 0, ok.output
    text = " ".join(ok.output.split())
    assert "toy: imported 6 runs" in text and "toy.sqlite: ok 6" in text
    bad = toy_runs().astype(object)
    bad.loc[0, "a"] = "?"
    out = CliRunner().invoke(app, ["campaign", str(spec), "--model", "toy", "--import",
                                   str(write(bad, tmp_path / "bad.csv"))])
    assert out.exit_code == 1
    assert "column 'a', row 1: '?' is not a number" in " ".join(out.output.split())
    assert "Traceback" not in out.output
    both = CliRunner().invoke(app, ["campaign", str(spec), "--import", str(table),
                                    "--runs", "20"])
    assert both.exit_code == 2 and "--import only adds runs" in both.output  # usage


def test_retry_failed_keeps_imported_runs_and_says_so(tmp_path):
    spec = toy_spec(tmp_path, runs=3)
    frame = toy_runs(4)
    frame["status"] = ["ok", "failed", "ok", "timeout"]
    table = write(frame, tmp_path / "runs.csv")
    app = campaign_app()
    assert CliRunner().invoke(app, ["campaign", str(spec), "--model", "toy", "--import",
                                    str(table)]).exit_code == 0
    out = CliRunner().invoke(app, ["campaign", str(spec), "--retry-failed", "--no-progress"])
    assert out.exit_code == 0, out.output
    assert ("note: --retry-failed runs again the simulated runs only: 2 imported runs not ok "
            "(failed 1, timeout 1) are kept as imported; to simulate those points, give "
            "them as a design file (campaign.design) to a new --store"
            ) in " ".join(out.output.split())
    counts = runs_frame(tmp_path / "campaigns" / "toy.sqlite").status.value_counts()
    assert counts.to_dict() == {"ok": 5, "failed": 1, "timeout": 1}
    summary = run_campaign(load_spec(spec), "toy", progress=False, retry_failed=True,
                           executor="in-process")
    assert summary.ran == 0 and len(summary.notes) == 1
    assert run_campaign(load_spec(spec), "toy", progress=False).notes == ()


def test_importing_runs_the_store_holds_within_round_off_adds_nothing(tmp_path):
    net = toy_network(tmp_path, runs=6)
    made = run_campaign(net, "toy", executor="in-process", progress=False)
    frame = runs_frame(made.store_path)
    frame.to_csv(tmp_path / "short.csv", index=False, float_format="%.15g")
    assert not (pd.read_csv(tmp_path / "short.csv").x == frame.x).all()  # not bit for bit
    again = import_runs(net, "toy", tmp_path / "short.csv")
    assert again.imported == 0 and again.status_counts == {"ok": 6}
    frame.loc[2, "y"] += 1e-6  # another result at the same point
    frame.to_csv(tmp_path / "other.csv", index=False, float_format="%.15g")
    with pytest.raises(CampaignError, match=r"other.csv: row 3 has the inputs of run 2 .* "
                                            "another result"):
        import_runs(net, "toy", tmp_path / "other.csv")
