"""KOH calibration sampler benchmark: calnet vs PyMC (C and numba backends), side by side.

usage (from the repository root):
    python3 -m venv benchmarks/.venv-peers
    benchmarks/.venv-peers/bin/pip install pymc numba arviz
    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/calibration/run.py --reps 3

Each side runs in its own process (fresh interpreter, own working directory for the CPU
meter), interleaved rep by rep so that they see the same load. 4 chains x (1000 warm-up +
1000 draws). Metric: min bulk ESS over the 11 parameters / sampling wall time, and / total
wall time including compilation; ESS per CPU-second beside it because the box is shared.
Results: benchmarks/calibration/results.jsonl (appended) and a markdown table on stdout.
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
PEERS = os.path.join(ROOT, "benchmarks", ".venv-peers", "bin", "python")
SIDES = {
    "calnet": (sys.executable, ["side_calnet.py"]),
    "calnet-dense": (sys.executable, ["side_calnet.py", None, "dense"]),
    # calnet at another commit: --before DIR (a worktree of it), its own side_calnet.py
    "calnet-before": (sys.executable, ["side_calnet.py"]),
    "pymc-default": (PEERS, ["side_pymc.py", None, "default"]),
    "pymc-numba": (PEERS, ["side_pymc.py", None, "numba"]),
    "numpyro": (sys.executable, ["side_numpyro.py"]),
}


def run_side(name, rep, timeout, before=None):
    exe, args = SIDES[name]
    root = before if name == "calnet-before" else ROOT
    here = os.path.join(root, "benchmarks", "calibration")
    args = [os.path.join(here, args[0]), str(rep)] + [a for a in args[2:]]
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1",
               PYTHONPATH=os.pathsep.join([here, os.path.join(root, "src")]))
    with tempfile.TemporaryDirectory(prefix=f"koh-{name}-") as cwd:
        t0 = time.perf_counter()
        proc = subprocess.run([exe] + args, cwd=cwd, env=env, capture_output=True, text=True,
                              timeout=timeout)
    recs = [json.loads(line[7:]) for line in proc.stdout.splitlines()
            if line.startswith("RESULT ")]
    print(f"  {name} rep {rep}: rc={proc.returncode} {time.perf_counter() - t0:.0f}s "
          f"{[round(r['min_ess_bulk'] / r['t_sample']) for r in recs if r['t_sample']]} ESS/s",
          file=sys.stderr, flush=True)
    if proc.returncode:
        print(proc.stderr[-3000:], file=sys.stderr)
    return recs


def _med(xs):
    xs = [x for x in xs if x is not None]
    return statistics.median(xs) if xs else float("nan")


def table(records):
    rows, groups = [], {}
    for r in records:
        groups.setdefault((r["side"], r["run"]), []).append(r)
    head = ("| sampler | run | reps | compile s | sampling s | min bulk ESS | ESS/s sampling "
            "| ESS/s incl. compile | ESS per CPU-s | max R-hat | divergences |")
    rows += [head, "|" + "---|" * 11]
    med = {}
    for (side, run), rs in sorted(groups.items()):
        ess_s = _med([r["min_ess_bulk"] / r["t_sample"] for r in rs if r["t_sample"]])
        ess_t = _med([r["min_ess_bulk"] / r["t_total"] for r in rs])
        med[(side, run)] = (ess_s, ess_t)
        t_comp, t_samp = _med([r["t_compile"] for r in rs]), _med([r["t_sample"] for r in rs])
        ess = _med([r["min_ess_bulk"] for r in rs])
        ess_cpu = _med([r["min_ess_bulk"] / r["cpu_s"] for r in rs])
        rows.append(
            f"| {side} | {run} | {len(rs)} | {t_comp:.1f} | {t_samp:.2f} | {ess:.0f} | "
            f"{ess_s:.0f} | {ess_t:.0f} | {ess_cpu:.0f} | "
            f"{max(r['max_rhat'] for r in rs):.3f} | {sum(r['divergences'] for r in rs)} |")
    c = med.get(("calnet", 1))
    for peer in ("pymc-default", "pymc-numba"):
        if c and (peer, 1) in med:
            p = med[(peer, 1)]
            rows.append(f"\ncalnet / {peer}: {c[0] / p[0]:.1f}x (sampling), "
                        f"{c[1] / p[1]:.1f}x (incl. compile)")
    return "\n".join(rows)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--sides", default="calnet,pymc-default,pymc-numba,numpyro",
                    help=f"comma-separated, from {','.join(SIDES)}")
    ap.add_argument("--timeout", type=int, default=900)
    ap.add_argument("--before", help="worktree of another calnet commit (side calnet-before)")
    ap.add_argument("--out", default=os.path.join(HERE, "results.jsonl"))
    a = ap.parse_args()
    sides = a.sides.split(",")
    if any(s.startswith("pymc") for s in sides) and not os.path.exists(PEERS):
        sys.exit("PyMC venv missing: python3 -m venv benchmarks/.venv-peers && "
                 "benchmarks/.venv-peers/bin/pip install pymc numba arviz")
    records = []
    stamp = time.strftime("%Y-%m-%dT%H:%M:%S")
    for rep in range(a.reps):
        for side in sides:
            for r in run_side(side, rep, a.timeout, a.before):
                r["stamp"] = stamp
                if side == "calnet-before":
                    r["side"] = "calnet-before"
                records.append(r)
                with open(a.out, "a") as fh:
                    fh.write(json.dumps(r) + "\n")
    print(table(records))


if __name__ == "__main__":
    main()
