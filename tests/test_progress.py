"""Plain progress lines: a line at every 10 % or after a quiet spell, never carriage
returns (the campaign's and the sampler's lines are tested beside them)."""

from __future__ import annotations

import time

from calnet.progress import Lines


def _clock(times):
    it = iter(times)
    return lambda: next(it)


def test_a_line_at_the_start_at_every_tenth_and_at_the_end():
    out = []
    lines = Lines("m", out.append, clock=_clock([0.0] + [1.0] * 100))
    for done in range(1, 101):
        lines.update(done / 100, f"{done}/100")
    assert out == [f"m: {k}/100 (1 s)" for k in (1, *range(10, 101, 10))]


def test_a_line_after_a_quiet_spell_between_tenths():
    out = []
    lines = Lines("m", out.append, every_s=5.0, clock=_clock([0.0, 1.0, 2.0, 7.5, 8.0]))
    for done in (10, 11, 12, 13):  # 10 % at 1 s, quiet until 7.5 s, then again quiet
        lines.update(done / 100, f"{done}")
    assert out == ["m: 10 (1 s)", "m: 12 (8 s)"]


def test_heartbeat_speaks_while_nothing_reports():
    out = []
    lines = Lines("stage", out.append, every_s=0.05)
    with lines.heartbeat(lambda: "warm-up"):
        time.sleep(0.4)
    assert out and all(line.startswith("stage: warm-up (") for line in out)
    n = len(out)
    time.sleep(0.2)
    assert len(out) == n  # stopped with the block

