"""Markdown tables from ``results/*.json`` (written by run_benchmarks.py)."""

from __future__ import annotations

import json
import statistics
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"


def _load(name: str) -> list[dict]:
    path = RESULTS / f"{name}.json"
    return json.loads(path.read_text()) if path.exists() else []


def convergence_table() -> str:
    recs = _load("convergence")
    by = {(r["inputs"]["P"], r["inputs"]["v"], r["tag"]): r for r in recs}
    lines = ["| P (W) | v (m/s) | cells h / h/2 | W (um) h / h/2 | dW | D (um) h / h/2 | dD "
             "| G0 (K/m) h / h/2 | dG0 | pass |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for (P, v, tag), a in by.items():
        b = by.get((P, v, "res2"))
        if tag != "res1" or b is None:
            continue
        if a["status"] != "ok" or b["status"] != "ok":
            lines.append(f"| {P:g} | {v:g} | {a['status']} / {b['status']} | | | | | | | no |")
            continue
        if a.get("version") != b.get("version"):  # a stale res2 record: say so
            lines.append(f"| {P:g} | {v:g} | res1 from {a.get('version', '?')}, res2 from "
                         f"{b.get('version', '< 0.5.0')} | | | | | | | not compared |")
            continue
        oa, ob = a["outputs"], b["outputs"]
        rel = {k: oa[k] / ob[k] - 1 for k in ("W", "D", "G0")}
        ok = abs(rel["W"]) <= 0.03 and abs(rel["D"]) <= 0.03 and abs(rel["G0"]) <= 0.10
        lines.append(
            f"| {P:g} | {v:g} | {a['n_cells']} / {b['n_cells']} | {oa['W']:.1f} / {ob['W']:.1f} "
            f"| {rel['W']:+.1%} | {oa['D']:.1f} / {ob['D']:.1f} | {rel['D']:+.1%} "
            f"| {oa['G0']:.3g} / {ob['G0']:.3g} | {rel['G0']:+.1%} | {'yes' if ok else 'no'} |")
    return "\n".join(lines)


def speed_table() -> str:
    recs = [r for r in _load("convergence") if r["tag"] == "res1"]
    recs += [r for r in _load("sanity")]
    if not recs:
        return "(no runs)"
    ok = [r for r in recs if r["status"] == "ok"]
    wall = [r["wall_s"] for r in recs if "wall_s" in r]
    five = [r["wall_s"] for r in _load("convergence") if r["tag"] == "res1"]
    rss = [r["peak_rss_mib"] for r in recs if "peak_rss_mib" in r]
    cpu = [r["cpu_s"] for r in recs if "cpu_s" in r]
    cells = [r["n_cells"] for r in recs if r.get("n_cells")]
    its = [r["iterations"] for r in recs if r.get("iterations")]
    return "\n".join([
        "| runs | converged | wall median (s) | wall max (s) | CPU median (s) "
        "| 5-setting wall median / max (s) | peak RSS max (MiB) | cells median "
        "| Newton its median |",
        "|---|---|---|---|---|---|---|---|---|",
        f"| {len(recs)} | {len(ok)} | {statistics.median(wall):.1f} | {max(wall):.1f} "
        f"| {statistics.median(cpu):.1f} "
        f"| {statistics.median(five) if five else float('nan'):.1f} / "
        f"{max(five) if five else float('nan'):.1f} | {max(rss):.0f} "
        f"| {statistics.median(cells):.0f} | {statistics.median(its):.0f} |"])


def sanity_table() -> str:
    recs = _load("sanity")
    lines = ["| sample | split | P (W) | v (m/s) | W measured (um) | W simulated (um) | ratio "
             "| G0 (K/m) | T0 (K) | status |", "|---|---|---|---|---|---|---|---|---|---|"]
    inside = 0
    for r in recs:
        o = r.get("outputs", {})
        w = o.get("W", float("nan"))
        ratio = w / r["measured_W"]
        inside += 0.6 <= ratio <= 1.4
        lines.append(f"| {r['tag'].removeprefix('sample')} | {r['split']} | {r['inputs']['P']:g} "
                     f"| {r['inputs']['v']:g} | {r['measured_W']:.1f} | {w:.1f} | {ratio:.2f} "
                     f"| {o.get('G0', float('nan')):.3g} | {o.get('T0', float('nan')):.0f} "
                     f"| {r['status']} |")
    lines.append(f"\n{inside} of {len(recs)} simulated widths within +-40 % of measured.")
    return "\n".join(lines)


def corners_table() -> str:
    recs = _load("corners")
    lines = ["| P (W) | v (m/s) | parameters | status | W (um) | D (um) | G0 (K/m) "
             "| T peak (K) | wall (s) | message |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in recs:
        o = r.get("outputs", {})
        lines.append(f"| {r['inputs']['P']:g} | {r['inputs']['v']:g} | {r['tag']} "
                     f"| {r['status']} | {o.get('W', float('nan')):.1f} "
                     f"| {o.get('D', float('nan')):.1f} | {o.get('G0', float('nan')):.3g} "
                     f"| {r.get('peak_temperature_K') or float('nan'):.0f} "
                     f"| {r.get('wall_s', float('nan')):.1f} | {r.get('message', '')[:80]} |")
    return "\n".join(lines)


if __name__ == "__main__":
    for title, fn in (("Mesh convergence", convergence_table), ("Speed", speed_table),
                      ("Physical sanity", sanity_table), ("Robustness corners", corners_table)):
        print(f"### {title}\n\n{fn()}\n")
