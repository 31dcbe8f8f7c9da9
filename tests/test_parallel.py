"""map_threads: order, errors, and real overlap of calls that release the GIL."""

import threading
import time

import pytest

from calnet.parallel import map_threads, usable_cores


def test_results_keep_the_order_of_the_items():
    def slow_first(i):
        time.sleep(0.05 if i == 0 else 0.0)
        return i * 10

    assert map_threads(slow_first, range(5)) == [0, 10, 20, 30, 40]
    assert map_threads(slow_first, []) == []


def test_the_first_failing_item_raises_after_the_running_calls_finish():
    started, done = set(), []

    def work(i):
        started.add(i)
        if i in (1, 3):
            raise ValueError(f"item {i}")
        time.sleep(0.05)
        done.append(i)
        return i

    for _ in range(20):
        started.clear()
        done.clear()
        with pytest.raises(ValueError, match="item 1"):
            map_threads(work, range(4))
        assert 0 in done and set(done) == started - {1, 3}  # no call left running


@pytest.mark.skipif(usable_cores() < 2, reason="one usable core: calls run one by one")
def test_calls_overlap_on_several_cores():
    barrier = threading.Barrier(2, timeout=5)  # both calls must be running at once
    assert map_threads(lambda i: barrier.wait() >= 0, [0, 1]) == [True, True]
