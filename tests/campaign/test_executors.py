"""Backend equivalence: the same campaign on every executor gives the same store."""

from __future__ import annotations

import pytest
from campaign_helpers import store_rows, toy_network

from calnet.campaign import run_campaign
from calnet.campaign.executors import (
    THREAD_VARIABLES,
    ProcessExecutor,
    WorkerDied,
    make_executor,
)
from calnet.errors import CampaignError
from calnet.parallel import usable_cores


@pytest.mark.slow
def test_in_process_processes_and_dask_give_identical_stores(tmp_path):
    net = toy_network(tmp_path, "python:toy_sims:crashy", runs=16)
    stores = {}
    for kind, workers in (("in-process", None), ("processes", 2), ("dask", 2)):
        summary = run_campaign(net, "toy", executor=kind, workers=workers, progress=False,
                               store=tmp_path / f"{kind}.sqlite")
        assert summary.executor == kind and summary.complete
        stores[kind] = store_rows(summary.store_path)
    assert stores["in-process"] == stores["processes"] == stores["dask"]
    assert {r[4] for r in stores["dask"]} == {"ok", "failed"}  # status column, both kinds


@pytest.mark.slow
def test_dask_at_a_scheduler_address(tmp_path):
    from distributed import LocalCluster

    net = toy_network(tmp_path, runs=6)
    reference = run_campaign(net, "toy", progress=False, store=tmp_path / "ref.sqlite")
    with LocalCluster(n_workers=1, threads_per_worker=1, dashboard_address=None,
                      processes=True) as cluster:
        summary = run_campaign(net, "toy", scheduler=cluster.scheduler_address,
                               progress=False, store=tmp_path / "remote.sqlite")
    assert summary.executor == "dask" and summary.workers == 1
    assert store_rows(summary.store_path) == store_rows(reference.store_path)


def test_executor_choice_is_validated():
    assert make_executor().name == "in-process"
    with pytest.raises(CampaignError, match="--workers or --scheduler, not both"):
        make_executor(workers=2, scheduler="tcp://127.0.0.1:1")
    with pytest.raises(CampaignError, match="--workers must be >= 1"):
        make_executor(workers=0)
    with pytest.raises(CampaignError, match="unknown executor 'threads'"):
        make_executor("threads")
    assert make_executor("in-process", workers=1).name == "in-process"
    with pytest.raises(CampaignError, match="one run at a time, not --workers 2; use "
                                            "--executor processes"):
        make_executor("in-process", workers=2)


def test_bad_executor_options_fail_before_anything_runs(tmp_path):
    net = toy_network(tmp_path, runs=3)
    store = run_campaign(net, "toy", progress=False).store_path
    before = store.read_bytes()
    for fresh in (False, True):  # a complete store (nothing to run), and --fresh
        with pytest.raises(CampaignError, match="unknown executor 'foo'; choose auto"):
            run_campaign(net, "toy", executor="foo", fresh=fresh, progress=False)
        with pytest.raises(CampaignError, match="in-process executor runs one run at a time"):
            run_campaign(net, "toy", executor="in-process", workers=2, fresh=fresh,
                         progress=False)
    assert store.read_bytes() == before  # neither deleted nor written


def test_unreachable_scheduler_says_so(monkeypatch):
    monkeypatch.setattr("calnet.campaign.executors.CONNECT_TIMEOUT", "1s")
    with pytest.raises(CampaignError, match="cannot reach the Dask scheduler"):
        make_executor(scheduler="tcp://127.0.0.1:9")


@pytest.mark.timeout(120)
def test_a_worker_deaf_to_sigterm_is_killed_when_another_dies(tmp_path):
    """One worker dies while the other runs a simulator that ignores SIGTERM: the broken
    pool's SIGTERM does not end it, so it is killed after the grace period (not waited
    for), and both runs are run again, one at a time."""
    import time

    from toy_sims import deaf_sleeper_or_dies

    deaf, dies = ("deaf", str(tmp_path / "marker")), ("dies", str(tmp_path / "marker"))
    t0 = time.monotonic()
    with ProcessExecutor(2) as executor:
        out = dict(executor.run(deaf_sleeper_or_dies, [deaf, dies]))
    assert time.monotonic() - t0 < 40  # the deaf run's first attempt sleeps for 60 s
    assert out[deaf] == "deaf done"
    assert isinstance(out[dies], WorkerDied) and "exit code 7" in str(out[dies])


def test_a_run_that_ends_its_worker_runs_twice_and_the_queued_ones_once(tmp_path):
    """One worker, two runs in flight (one running, one queued): a run that ends its
    worker is executed twice, then recorded failed; the run queued behind it is not
    blamed, and runs once."""
    from collections import Counter

    log = tmp_path / "calls.log"
    net = toy_network(tmp_path, {"kind": "python", "target": "toy_sims:dies_logged",
                                 "options": {"log": str(log)}}, runs=12)
    summary = run_campaign(net, "toy", workers=1, progress=False)
    calls = Counter(float(x) for x in log.read_text().split())
    rows = {r[0]: r for r in store_rows(summary.store_path)}
    failed = sorted(i for i, r in rows.items() if "failed" in r)
    assert failed and summary.n_failed == len(failed) and len(calls) == 12
    assert sorted(calls.values()) == [1] * (12 - len(failed)) + [2] * len(failed)
    assert summary.notes[:len(failed)] == tuple(
        f"a worker process died (exit code 7) with run {i} running; it is run again alone "
        "(a run that ends its process again is recorded failed)" for i in failed)


def test_a_memory_error_gets_the_next_runs_a_fresh_worker(tmp_path):
    """A simulator that leaks: from its third run in a process on, memory runs out. The
    worker is replaced after a MemoryError, so the next runs succeed; the message says
    what happened, and the campaign's warning points at --retry-failed."""
    from calnet.campaign.failures import store_failure_note

    net = toy_network(tmp_path, "python:toy_sims:leaks", runs=6)
    summary = run_campaign(net, "toy", workers=1, progress=False)
    assert summary.n_failed == 2  # the third and the sixth, each in its own worker
    for message in summary.failures.values():
        assert message.startswith("failed: MemoryError (out of memory) at toy_sims.py:"), message
    note = store_failure_note(summary.store_path, net.model("toy"))
    assert "2 of them ran out of memory (MemoryError" in note and "--retry-failed" in note


def test_runs_whose_process_died_leave_no_empty_folders(tmp_path):
    """A run that ended its worker had no time to remove its empty logs: the campaign
    removes them, and the run's folder, as for a run that finished."""
    net = toy_network(tmp_path, "python:toy_sims:dies", runs=12)
    summary = run_campaign(net, "toy", workers=1, progress=False)
    assert summary.n_failed > 0
    work = summary.store_path.with_suffix(".work")
    assert not work.exists() or not any(work.iterdir()), sorted(work.rglob("*"))


@pytest.mark.parametrize("address", ["tcp://10.0.0.5:8786", "localhost:8786",
                                     "tls://[::1]:8786", "tcp://node-17.cluster:8786"])
def test_a_dask_scheduler_address_is_accepted_as_dask_takes_it(address):
    from calnet.campaign.executors import executor_kind

    assert executor_kind("auto", scheduler=address) == "dask"


@pytest.mark.parametrize("address", ["localhost", "tcp://:8786", "tcp://host:8786x",
                                     "http://host:8786", "host:0", ""])
def test_a_string_that_is_no_scheduler_address_is_a_usage_error(address):
    from calnet.campaign.executors import executor_kind
    from calnet.errors import UsageError

    with pytest.raises(UsageError, match="give tcp://HOST:PORT"):
        executor_kind("auto", scheduler=address)


def test_worker_processes_share_the_cores_among_their_blas_threads(monkeypatch):
    """Without a thread count in the environment each of 2 workers runs BLAS on half
    the cores (at least one thread), also SciPy's OpenBLAS, loaded after the start."""
    from toy_sims import blas_threads

    for name in THREAD_VARIABLES:
        monkeypatch.delenv(name, raising=False)
    share = max(1, usable_cores() // 2)
    with ProcessExecutor(2) as executor:
        out = dict(executor.run(blas_threads, [(i,) for i in range(4)]))
    assert sorted(out.values()) == [(str(share), share)] * 4


def test_a_thread_count_in_the_environment_is_left_to_the_user(monkeypatch):
    from toy_sims import blas_threads

    for name in THREAD_VARIABLES:
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "3")
    with ProcessExecutor(2) as executor:
        out = dict(executor.run(blas_threads, [(0,)]))
    assert out[(0,)][0] == "3"
