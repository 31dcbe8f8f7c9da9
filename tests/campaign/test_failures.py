"""The warning about a campaign with many runs not ok: the threshold and the ranges."""

from __future__ import annotations

import numpy as np

from calnet.campaign.failures import FAILED_SHARE_LIMIT, failure_note


def _rows(bad: list[float], ok: list[float], status: str = "failed") -> list[dict]:
    return ([{"status": status, "inputs": {"x": x, "a": 0.5}} for x in bad]
            + [{"status": "ok", "inputs": {"x": x, "a": 0.5}} for x in ok]
            + [{"status": None, "inputs": {"x": 2.0, "a": 0.5}}])  # unfinished: not counted


def test_only_a_share_above_the_limit_is_warned_about():
    assert FAILED_SHARE_LIMIT == 0.10
    ok = [i / 30 for i in range(27)]
    assert failure_note("M", _rows([0.95, 0.96, 0.97], ok), ["x", "a"]) is None  # 3 of 30
    note = failure_note("M", _rows([0.94, 0.95, 0.96, 0.97], ok), ["x", "a"])
    assert note == ("M: 4 of 31 runs (13 %) did not finish ok (failed 4); they lie at x in "
                    "[0.94, 0.97], the ok runs at x in [0, 0.867] (the surrogate "
                    "extrapolates there)")


def test_failures_among_the_ok_runs_name_no_range():
    note = failure_note("M", _rows([0.1, 0.5, 0.9], [0.2, 0.6], status="timeout"), ["x", "a"])
    assert note == ("M: 3 of 5 runs (60 %) did not finish ok (timeout 3); no input "
                    "or parameter range separates them from the ok runs")
    assert failure_note("M", _rows([0.1, 0.2], []), ["x"]) == (
        "M: 2 of 2 runs (100 %) did not finish ok (failed 2)")


def test_failures_of_two_causes_name_both_ranges():
    # the simulator fails for P > 200 (any v) and for v < 0.1 (any P): no single column
    # separates the failures from the ok runs, two one-sided ranges do
    rng = np.random.default_rng(0)
    rows = []
    for P, v in zip(rng.uniform(50, 250, 80), rng.uniform(0.04, 2.0, 80), strict=True):
        bad = P > 200 or v < 0.1
        rows.append({"status": "failed" if bad else "ok", "inputs": {"P": P, "v": v, "a": 1.0}})
    n_p = sum(r["inputs"]["P"] > 200 for r in rows)
    n_v = sum(r["inputs"]["v"] < 0.1 and r["inputs"]["P"] <= 200 for r in rows)
    note = failure_note("M1", rows, ["P", "v", "a"])
    edge_p = max(r["inputs"]["P"] for r in rows if r["status"] == "ok")
    edge_v = min(r["inputs"]["v"] for r in rows if r["status"] == "ok")
    assert 195 < edge_p <= 200 and 0.1 <= edge_v < 0.15
    assert (f"they lie where P > {edge_p:.3g} ({n_p} runs) or v < {edge_v:.3g} ({n_v} runs), "
            "beyond every ok run (the surrogate extrapolates there)") in note, note
    assert "among the ok runs" not in note
    # one more failure among the ok runs is counted as left out, not hidden
    rows.append({"status": "timeout", "inputs": {"P": 120.0, "v": 1.0, "a": 1.0}})
    assert failure_note("M1", rows, ["P", "v"]).endswith("; the other 1 lies among the ok runs")
    # scattered failures with an extreme run or two beyond the ok runs name no range
    scattered = [{"status": "failed" if i % 3 == 0 else "ok", "inputs": {"x": float(i)}}
                 for i in range(30)]
    assert failure_note("M", scattered, ["x"]).endswith("separates them from the ok runs")


def test_the_commonest_outcome_counts_messages_that_differ_in_numbers():
    """Runs that did not converge after different iteration counts are one outcome: the
    commonest is the status with most runs, shown with its commonest message."""
    from calnet.campaign.failures import commonest_outcome

    rows = [{"status": status, "message": message} for status, message in [
        ("failed", "no output"), ("failed", "no output"),
        ("nonconverged", "stopped after 500 its (residual 1e-2)"),
        ("nonconverged", "stopped after 500 its (residual 3e-3)"),
        ("nonconverged", "stopped after 500 its (residual 3e-3)"),
        ("ok", ""), ("pending", None)]]
    assert commonest_outcome(rows) == ("nonconverged (3 runs), e.g. stopped after 500 its "
                                       "(residual 1e-2)")
    assert commonest_outcome(rows[-2:]) is None
    # a simulator that names the value at which it failed: those messages are one kind
    rows = ([{"status": "failed", "message": f"diverged at x={x}"} for x in (0.61, 0.7, 0.93)]
            + [{"status": "failed", "message": "mesh too coarse"}] * 2)
    assert commonest_outcome(rows) == "failed (5 runs), e.g. diverged at x=0.61"
