"""Campaign scaling: the built-in thermal simulator on 1 vs 2 Dask workers.

Runs the first ``--runs`` points of the ninb melt_pool design (seed from the spec) on a
Dask LocalCluster of 1 and then 2 single-threaded workers, each into a fresh temporary
store, and reports the makespan (first run handed out -> last run committed, read from
the store, so cluster start-up is excluded) and the speed-up. Usage, from the repository
root::

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/campaign/scaling.py --runs 12

Prints one Markdown table row per worker count, and the machine's load average, because
on a shared machine other processes compete for the cores.
"""

from __future__ import annotations

import argparse
import os
import sqlite3
import tempfile
import time
from pathlib import Path

from calnet.campaign import run_campaign
from calnet.spec import load_spec

ROOT = Path(__file__).resolve().parents[2]


def makespan(store: Path) -> tuple[float, float, int]:
    """(makespan s, mean wall time per run s, runs ok) of a finished store."""
    with sqlite3.connect(store) as db:
        t0, t1, mean, ok = db.execute(
            "SELECT MIN(started_at), MAX(finished_at), AVG(wall_time), "
            "SUM(status = 'ok') FROM runs").fetchone()
    db.close()
    return t1 - t0, mean, int(ok)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=12)
    parser.add_argument("--spec", default=str(ROOT / "examples" / "ninb"))
    args = parser.parse_args()
    network = load_spec(args.spec, read_data=False)
    print(f"cpus {os.cpu_count()}, load average before {os.getloadavg()}")
    print("| workers | runs | makespan (s) | mean run wall time (s) | runs/min | ok |")
    print("|---:|---:|---:|---:|---:|---:|")
    spans = {}
    with tempfile.TemporaryDirectory() as tmp:
        for workers in (1, 2):
            store = Path(tmp) / f"w{workers}.sqlite"
            run_campaign(network, "melt_pool", runs=args.runs, executor="dask",
                         workers=workers, store=store, progress=False)
            span, mean, ok = makespan(store)
            spans[workers] = span
            print(f"| {workers} | {args.runs} | {span:.1f} | {mean:.2f} | "
                  f"{60 * args.runs / span:.1f} | {ok} |", flush=True)
    print(f"speed-up 2 vs 1 workers: {spans[1] / spans[2]:.2f}x; load average after "
          f"{os.getloadavg()} ({time.strftime('%Y-%m-%d %H:%M')})")


if __name__ == "__main__":
    main()
