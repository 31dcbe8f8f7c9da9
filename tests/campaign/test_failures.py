"""The warning about a campaign with many runs not ok: the threshold and the ranges."""

from __future__ import annotations

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
    assert note == ("M: 3 of 5 runs (60 %) did not finish ok (timeout 3); no single input "
                    "or parameter range separates them from the ok runs")
    assert failure_note("M", _rows([0.1, 0.2], []), ["x"]) == (
        "M: 2 of 2 runs (100 %) did not finish ok (failed 2)")
