"""Newton iterations and CPU per continuation stage of the M1 melt-pool simulator.

Runs the 5 benchmark settings (``run_benchmarks.SETTINGS``, mid-range parameters,
default options; ``--case P v`` names other settings, ``--run N ...`` rows of a campaign
table with their parameters: by default the ninb melt_pool store, e.g. the runs that did
not converge there), each in a fresh process, one at
a time, and prints per run one row per Newton solve (the continuation stages on the
sizing mesh, then the fine solve): mesh, power, cells, Newton iterations, CPU seconds;
then the run's outputs. With ``--starts`` it also runs RUN_104 and both first-stage
fields (``start="rosenthal"`` and ``"ambient"``) and prints their largest relative
difference in W, D and G0.

Experiments without editing the package: ``--options`` passes simulator options,
``--patch module.NAME=value`` sets a module (or class) constant of the melt_pool package in the
worker (e.g. ``--patch model.COARSE_RTOL=1e-3``). ``--save`` writes the records as
JSON, ``--compare`` prints the relative change of W, D, G0 against such a file.

Usage (repository root)::

    OPENBLAS_NUM_THREADS=1 nice -n 5 python benchmarks/melt_pool/iterations.py \\
        --starts --save /tmp/base.json
"""

from __future__ import annotations

import argparse
import csv
import importlib
import json
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from run_benchmarks import RUN_104, SETTINGS  # noqa: E402

KEYS = ("W", "D", "G0")
STORE_TABLE = Path(__file__).resolve().parents[2] / "examples/ninb/campaigns/melt_pool.csv"


def _worker(spec: str) -> None:
    """Run one simulation described by a JSON spec; print one JSON line."""
    job = json.loads(spec)
    for item in job["patch"]:
        name, value = item.split("=", 1)
        module, *path, attr = name.split(".")
        obj = importlib.import_module(f"calnet.simulators.melt_pool.{module}")
        for part in path:  # a class attribute: solver.LinearSolver.MAX_AGE
            obj = getattr(obj, part)
        setattr(obj, attr, type(getattr(obj, attr))(json.loads(value)))
    from calnet.simulators import melt_pool

    cpu = time.process_time()
    res = melt_pool.simulate(job["inputs"], **job["options"])
    d = res.diagnostics
    print(json.dumps({**job, "status": res.status, "message": res.message,
                      "outputs": res.outputs, "cpu_s": time.process_time() - cpu,
                      "iterations": d.get("iterations"), "stages": d.get("stages", [])}))


def run_one(inputs: dict, options: dict, patch: list[str]) -> dict:
    spec = json.dumps({"inputs": inputs, "options": options, "patch": patch})
    out = subprocess.run([sys.executable, __file__, "--worker", spec], capture_output=True,
                         text=True, check=False)
    if out.returncode != 0:
        return {"inputs": inputs, "options": options, "status": "crashed",
                "message": out.stderr[-2000:], "outputs": {}, "stages": []}
    return json.loads(out.stdout.strip().splitlines()[-1])


def _label(rec: dict) -> str:
    i = rec["inputs"]
    tag = " run104" if i == RUN_104 else (" own parameters" if "K_S" in i else "")
    return f"{i['P']:g} W / {i['v']:g} m/s{tag} {rec['options'].get('start', 'rosenthal')}"


def _print(rec: dict) -> None:
    print(f"\n{_label(rec)}: {rec['status']} {rec['message']}")
    print("  mesh    P (W)   cells  its  CPU (s)")
    for s in rec["stages"]:
        print(f"  {s['mesh']:<6} {s['P']:7.1f} {s['n_cells']:7d} {s['iterations']:4d}"
              f" {s['cpu_s']:8.2f}")
    o = rec["outputs"]
    print(f"  total its {rec.get('iterations')}  CPU {rec.get('cpu_s', float('nan')):.2f} s"
          + "".join(f"  {k} {o.get(k, float('nan')):.6g}" for k in KEYS), flush=True)


def _table_inputs(table: Path, runs: list[int]) -> list[dict]:
    """Inputs (P, v and the parameters) of the rows ``runs`` of a campaign CSV table."""
    from calnet.simulators.melt_pool import INPUTS, PARAMETERS

    with table.open() as fh:
        rows = {int(r["run"]): r for r in csv.DictReader(fh)}
    missing = [n for n in runs if n not in rows]
    if missing:
        sys.exit(f"{table}: no run {', '.join(map(str, missing))}")
    return [{k: float(rows[n][k]) for k in (*INPUTS, *PARAMETERS)} for n in runs]


def _rel(a: dict, b: dict) -> float:
    return max(abs(a["outputs"][k] / b["outputs"][k] - 1) for k in KEYS)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--options", default="{}", help="simulator options as JSON")
    ap.add_argument("--patch", action="append", default=[], help="module.NAME=json")
    ap.add_argument("--starts", action="store_true", help="RUN_104, both starts too")
    ap.add_argument("--only", type=int, nargs="*", help="indices into SETTINGS")
    ap.add_argument("--case", type=float, nargs=2, action="append", metavar=("P", "V"),
                    help="a setting (W, m/s) at mid parameters instead of SETTINGS")
    ap.add_argument("--run", type=int, nargs="+", metavar="N",
                    help="rows of a campaign table (run numbers) instead of SETTINGS")
    ap.add_argument("--table", type=Path, default=STORE_TABLE,
                    help="the campaign table --run reads (default: the ninb melt_pool store)")
    ap.add_argument("--save", type=Path)
    ap.add_argument("--compare", type=Path)
    args = ap.parse_args()
    base = json.loads(args.options)
    picked = [SETTINGS[i] for i in (args.only if args.only else range(len(SETTINGS)))]
    picked = [tuple(c) for c in args.case] if args.case else picked
    if args.run:
        cases = _table_inputs(args.table, args.run)
    else:
        cases = [{"P": P, "v": v} for P, v in picked] + ([RUN_104] if args.starts else [])
    starts = ("rosenthal", "ambient") if args.starts else ("rosenthal",)
    records = []
    for inputs in cases:
        for start in starts:
            opts = base if start == "rosenthal" else {**base, "start": start}
            records.append(run_one(inputs, opts, args.patch))
            _print(records[-1])
    ok = [r for r in records if r["status"] == "ok"]
    main_runs = [r for r in records if r["options"].get("start", "rosenthal") == "rosenthal"
                 and r["inputs"] != RUN_104]
    print(f"\ntotals: its {sum(r.get('iterations') or 0 for r in main_runs)}"
          f"  CPU {sum(r.get('cpu_s', 0) for r in main_runs):.1f} s"
          f"  ok {len(ok)} of {len(records)}")
    if args.starts:
        for a, b in zip(records[::2], records[1::2], strict=True):
            diff = _rel(a, b) if a["status"] == b["status"] == "ok" else float("nan")
            print(f"start independence {_label(a)[:-10]}: max rel diff {diff:.2e}")
    if args.compare:
        ref = {json.dumps([r["inputs"], r["options"].get("start")]): r
               for r in json.loads(args.compare.read_text())}
        for r in records:
            old = ref.get(json.dumps([r["inputs"], r["options"].get("start")]))
            if old and old["status"] == r["status"] == "ok":
                ch = "  ".join(f"{k} {r['outputs'][k] / old['outputs'][k] - 1:+.2e}"
                               for k in KEYS)
                print(f"vs reference {_label(r)}: {ch}  its {old['iterations']} -> "
                      f"{r['iterations']}  CPU {old['cpu_s']:.1f} -> {r['cpu_s']:.1f} s")
    if args.save:
        args.save.write_text(json.dumps(records, indent=1))


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "--worker":
        _worker(sys.argv[2])
    else:
        main()
