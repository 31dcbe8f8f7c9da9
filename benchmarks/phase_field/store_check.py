"""Re-simulate the runs of a phase_field campaign store with the installed simulator.

    PYTHONPATH=src python benchmarks/phase_field/store_check.py STORE OUT_JSONL
        [--deadline S]

For every run of the SQLite store ``STORE`` (a ``calnet campaign`` store of a
``builtin:phase_field`` model), runs :func:`calnet.simulators.phase_field.simulate` on
the run's inputs with the options the run recorded in its diagnostics, and appends one
JSON line per run to ``OUT_JSONL``: the index, the stored and the new status and outputs,
the largest relative difference of the outputs and the wall time. Prints a line per run
and, at the end, how many runs gave the same status and outputs. Runs not started before
``--deadline`` seconds (from the start) are left out, and the summary says how many. A
check that a new simulator version leaves a store's runs as they are.
"""

from __future__ import annotations

import argparse
import json
import math
import sqlite3
import sys
import time
from pathlib import Path

from calnet.simulators import phase_field


def _rel(a: float, b: float) -> float:
    if math.isnan(a) and math.isnan(b):
        return 0.0
    return abs(a - b) / max(abs(a), abs(b), 1e-300)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("store", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--deadline", type=float, default=math.inf)
    args = ap.parse_args()
    start = time.perf_counter()
    db = sqlite3.connect(f"file:{args.store}?mode=ro", uri=True)
    rows = db.execute("SELECT idx, inputs, status, outputs, diagnostics, simulator_version "
                      "FROM runs WHERE status IS NOT NULL ORDER BY idx").fetchall()
    same, done = 0, 0
    for idx, inputs, status, outputs, diagnostics, version in rows:
        if time.perf_counter() - start > args.deadline:
            break
        options = dict(json.loads(diagnostics or "{}").get("options") or {"resolution": "default"})
        t0 = time.perf_counter()
        res = phase_field.simulate(json.loads(inputs), **options)
        wall = time.perf_counter() - t0
        old = json.loads(outputs or "{}")
        diff = max((_rel(float(old[k]), float(res.outputs[k])) for k in old), default=0.0)
        agree = status == res.status and diff == 0.0
        same += agree
        done += 1
        row = {"idx": idx, "status": [status, res.status], "max_rel_diff": diff,
               "outputs": [old, res.outputs], "version": [version, phase_field.VERSION],
               "wall": wall}
        with args.out.open("a") as f:
            f.write(json.dumps(row) + "\n")
        print(f"run {idx}: {status} -> {res.status}, max rel. diff {diff:.1e}, {wall:.1f} s",
              flush=True)
    print(f"{same} of {done} runs the same ({len(rows) - done} not run before the deadline); "
          f"store made by {sorted({r[5] for r in rows})}, installed {phase_field.VERSION}",
          flush=True)


if __name__ == "__main__":
    sys.exit(main())
