"""End to end on the shipped case study: ``calnet run --quick examples/ninb`` from the
shipped campaign stores (nothing is re-simulated), then ``calnet predict`` on its output."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from calnet.cli import app

NINB = Path(__file__).resolve().parents[2] / "examples" / "ninb"


@pytest.mark.integration
def test_quick_run_on_the_case_study(tmp_path):
    work = tmp_path / "ninb"
    shutil.copytree(NINB, work, ignore=shutil.ignore_patterns("*.sqlite-wal", "*.sqlite-shm",
                                                              "__pycache__"))
    out = tmp_path / "out"
    result = CliRunner().invoke(app, ["run", str(work), "--out", str(out), "--quick"])
    assert result.exit_code == 0, result.output
    # one ArviZ netCDF per calibration stage: the shipped spec calibrates jointly
    stages = {c["stage"] for c in json.loads((out / "metrics.json").read_text())
              ["calibration"]["models"].values()}
    assert stages == {"melt_pool+solidification"}
    for rel in ("report.html", "metrics.json", *(f"posterior/{s}.nc" for s in stages),
                "posterior/network_posterior.json",
                "figures/data.png", "figures/cv_melt_pool.W.png",
                "figures/cv_solidification.lambda.png", "figures/posterior_melt_pool.png",
                "figures/posterior_solidification.png", "surrogates/surrogates.json"):
        assert (out / rel).is_file(), rel
    m = json.loads((out / "metrics.json").read_text())
    # nothing was simulated: the shipped stores are complete
    for name, c in m["campaigns"].items():
        assert c["n_total"] == {"melt_pool": 238, "solidification": 100}[name]
    assert set(m["surrogates"]) == {"melt_pool.W", "melt_pool.G0", "solidification.lambda"}
    for key in ("mape", "rmse", "coverage95", "n"):
        assert key in m["surrogates"]["melt_pool.W"]["cv"], key
    assert set(m["calibration"]["models"]) == {"melt_pool", "solidification"}
    assert set(m["calibration"]["models"]["melt_pool"]["parameters"]) == {
        "K_S", "K_L", "K_Lz", "K_V", "K_Vz", "A_0", "A_max"}
    for ds, n_test in (("width", 10), ("pdas", 3)):
        v = m["validation"][ds]
        assert v["test"]["n"] == n_test
        assert {"mape", "rmse", "nrmse", "crps", "coverage95"} <= set(v["test"])
        assert {"training_mean", "direct_gp"} <= set(v["baselines_test"])
    for ds in ("width", "pdas"):  # PSIS-LOO for every data set, with its checks
        loo = m["validation"][ds]["loo"]
        assert loo["method"] == "psis" and len(loo["pareto_k"]) == loo["calnet"]["n"]
        assert {"elpd_loo", "elpd_se", "pit", "pit_check"} <= set(loo)
    for ds in ("width", "pdas"):  # the shipped spec compares with no discrepancy
        rows = m["comparison"][ds]
        assert set(rows) == {"spec", "no_discrepancy"}
        assert sum(r["weight"] for r in rows.values()) == pytest.approx(1.0)
        assert min(r["elpd_diff"] for r in rows.values()) == 0.0
    assert "discrepancy against variants, by leave-one-out" in (out / "report.html").read_text()
    assert set(m["sensitivity"]["pdas"]["indices"]["names"]) == {"P", "v"}
    res = CliRunner().invoke(app, ["predict", str(work), "--run", str(out), "--at",
                                   "P=200,v=0.5", "--json"])
    assert res.exit_code == 0, res.output
    preds = {p["dataset"]: p for p in json.loads(res.output)["predictions"]}
    assert set(preds) == {"width", "pdas"}
    assert 0 < preds["pdas"]["lower95"][0] < preds["pdas"]["upper95"][0]


def test_shipped_ninb_pf_stores_match_the_spec():
    """examples/ninb-pf's stores are its spec's, complete, with enough phase-field runs
    that gave a spacing for the lambda surrogate and its cross-validation folds, so that
    ``calnet run examples/ninb-pf`` simulates nothing and does not stop at the surrogates."""
    import math

    from calnet.campaign import load_runs
    from calnet.spec import load_spec

    network = load_spec(NINB.parent / "ninb-pf")
    model = network.model("phase_field")
    for name in ("melt_pool", "phase_field"):
        table = load_runs(network, name)
        assert table.n_total == network.model(name).campaign.runs, name
        assert "unfinished" not in table.status_counts, name
    n_ok = load_runs(network, "phase_field").n_ok
    d = len(model.inputs) + len(model.parameters)
    folds = min(model.surrogate.cv_folds, n_ok)
    assert n_ok - math.ceil(n_ok / folds) >= d + 2, n_ok
