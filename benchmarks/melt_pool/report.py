"""Markdown tables from ``results/*.json`` (written by run_benchmarks.py).

Usage: ``report.py [RESULTS_DIR]`` (default ``benchmarks/melt_pool/results``).
"""

from __future__ import annotations

import json
import statistics
import sys
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"


def _load(name: str) -> list[dict]:
    path = RESULTS / f"{name}.json"
    return json.loads(path.read_text()) if path.exists() else []


def convergence_table(name: str = "convergence", tag: str = "res1") -> str:
    """``resolution`` 1 (or the records tagged ``tag``) against 2 (records of phase
    ``name``)."""
    recs = _load(name)
    by = {(r["inputs"]["P"], r["inputs"]["v"], r["tag"]): r for r in recs}
    lines = ["| P (W) | v (m/s) | cells h / h/2 | W (um) h / h/2 | dW | D (um) h / h/2 | dD "
             "| G0 (K/m) h / h/2 | dG0 | pass |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for (P, v, t), a in by.items():
        b = by.get((P, v, "res2"))
        if t != tag or b is None:
            continue
        if a["status"] != "ok" or b["status"] != "ok":
            verdict = "not measured" if "stopped" in (a["status"], b["status"]) else "no"
            lines.append(f"| {P:g} | {v:g} | {a['status']} / {b['status']} | | | | | | "
                         f"| {verdict} |")
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


def _default_runs() -> tuple[list[dict], list[dict]]:
    """Default-option, default-resolution runs at mid parameters, one per (P, v):
    the 40 sanity settings and the 5 benchmark settings (from ``start``, ``powder`` and
    ``convergence`` records). Returns (all, the 5 settings)."""
    recs: dict[tuple, dict] = {}
    five: dict[tuple, dict] = {}
    candidates = ([r for r in _load("convergence") if r["tag"] == "res1"]
                  + [r for r in _load("start") if r["tag"] == "rosenthal"]
                  + [r for r in _load("powder") if r["tag"] == "powder"])
    for r in candidates:
        if set(r["inputs"]) == {"P", "v"}:
            key = (r["inputs"]["P"], r["inputs"]["v"])
            five.setdefault(key, r)
            recs.setdefault(key, r)
    for r in _sanity():
        recs.setdefault((r["inputs"]["P"], r["inputs"]["v"]), r)
    return list(recs.values()), list(five.values())


def speed_table() -> str:
    recs, five_recs = _default_runs()
    if not recs:
        return "(no runs)"
    ok = [r for r in recs if r["status"] == "ok"]
    wall = [r["wall_s"] for r in recs if "wall_s" in r]
    five = [r["cpu_s"] for r in five_recs if "cpu_s" in r]
    rss = [r["peak_rss_mib"] for r in recs if "peak_rss_mib" in r]
    cpu = [r["cpu_s"] for r in recs if "cpu_s" in r]
    sim = [r["sim_cpu_s"] for r in recs if "sim_cpu_s" in r]
    cells = [r["n_cells"] for r in recs if r.get("n_cells")]
    its = [r["iterations"] for r in recs if r.get("iterations")]
    nan = float("nan")
    return "\n".join([
        "| runs | converged | CPU median / max (s) | simulation CPU median / max (s) "
        "| 5-setting CPU median / max (s) "
        "| wall median / max (s) | peak RSS max (MiB) | cells median | Newton its median / max |",
        "|---|---|---|---|---|---|---|---|---|",
        f"| {len(recs)} | {len(ok)} | {statistics.median(cpu):.1f} / {max(cpu):.1f} "
        f"| {statistics.median(sim) if sim else nan:.1f} / {max(sim) if sim else nan:.1f} "
        f"| {statistics.median(five) if five else nan:.1f} / {max(five) if five else nan:.1f} "
        f"| {statistics.median(wall):.0f} / {max(wall):.0f} | {max(rss):.0f} "
        f"| {statistics.median(cells):.0f} | {statistics.median(its):.0f} / {max(its)} |"])


def coarse_table(resolution: float) -> str:
    """Speed and mesh error of the default options at a coarser ``resolution`` (phase
    ``coarse``): its runs at the 40 sanity settings and the 5 benchmark settings, and
    the 5 settings against the halved mesh (``resolution=2``)."""
    tag = f"res{resolution:g}"
    recs = [r for r in _load("convergence") if r["tag"] == tag] + _load(f"sanity_{tag}")
    if not recs:
        return "(no runs)"
    cpu = sorted(r["cpu_s"] for r in recs if r["status"] == "ok")
    if not cpu:
        return f"{len(recs)} runs at `resolution={resolution:g}`, none converged."
    summary = (f"{len(recs)} runs at `resolution={resolution:g}`, {len(cpu)} converged; CPU over "
               f"the converged ones median {statistics.median(cpu):.1f} s, max {max(cpu):.1f} "
               f"s, {sum(c <= 5 for c in cpu)} within 5 s, {sum(c <= 2 for c in cpu)} within "
               f"2 s; cells median {statistics.median(r['n_cells'] for r in recs):.0f}.")
    return convergence_table(tag=tag) + "\n\n" + summary


def sanity_table() -> str:
    recs = _sanity()
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
    ok = sum(r["status"] == "ok" for r in recs)
    lines.append(f"\n{len(recs)} settings run, {ok} converged; {inside} of {len(recs)} "
                 "simulated widths within +-40 % of measured.")
    return "\n".join(lines)


def _sanity() -> list[dict]:
    """The sanity records of both halves, one per sample, in sample order."""
    by = {r["tag"]: r for r in _load("sanity_reverse") + _load("sanity")}
    return sorted(by.values(), key=lambda r: int(r["tag"].removeprefix("sample")))


def path_table() -> str:
    """Phase ``path``: one setting, the continuation step varied, per consolidation."""
    lines = ["| consolidation | continuation ratio | status | W (um) | D (um) | L (um) | G0 (K/m) "
             "| Newton its | CPU (s) |", "|---|---|---|---|---|---|---|---|---|"]
    for r in _load("path"):
        o = r.get("options", {})
        lines.append(f"| {o.get('consolidation')} | {o.get('continuation_ratio'):g} "
                     f"| {r['status']} | {_fmt(r, 'W', '.3f')} | {_fmt(r, 'D', '.3f')} "
                     f"| {_fmt(r, 'L', '.2f')} | {_fmt(r, 'G0', '.5g')} | {r.get('iterations')} "
                     f"| {r.get('cpu_s', float('nan')):.1f} |")
    return "\n".join(lines)


def _fmt(r: dict, key: str, spec: str) -> str:
    x = r.get("outputs", {}).get(key, float("nan"))
    return format(x, spec)


def start_table(name: str = "start") -> str:
    """Rosenthal vs ambient initial field of the first continuation stage (records of
    phase ``name``)."""
    recs = _load(name)
    pairs: dict[tuple, dict] = {}
    for r in recs:
        pairs.setdefault(tuple(sorted(r["inputs"].items())), {})[r["tag"]] = r
    lines = ["| P (W) | v (m/s) | parameters | status R / A | W (um) R / A | D (um) R / A "
             "| G0 (K/m) R / A | max rel. diff | Newton its R / A | CPU (s) R / A |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for key, pair in pairs.items():
        a, b = pair.get("rosenthal"), pair.get("ambient")
        if a is None or b is None:
            continue
        inputs = dict(key)
        theta = "run 104" if "K_S" in inputs else "mid"
        diff = float("nan")
        if a["status"] == b["status"] == "ok":
            diff = max(abs(a["outputs"][k] / b["outputs"][k] - 1) for k in ("W", "D", "G0"))
        lines.append(
            f"| {inputs['P']:g} | {inputs['v']:g} | {theta} | {a['status']} / {b['status']} "
            f"| {_fmt(a, 'W', '.2f')} / {_fmt(b, 'W', '.2f')} "
            f"| {_fmt(a, 'D', '.2f')} / {_fmt(b, 'D', '.2f')} "
            f"| {_fmt(a, 'G0', '.4g')} / {_fmt(b, 'G0', '.4g')} | {diff:.1e} "
            f"| {a.get('iterations')} / {b.get('iterations')} "
            f"| {a.get('cpu_s', float('nan')):.1f} / {b.get('cpu_s', float('nan')):.1f} |")
    return "\n".join(lines)


def powder_table() -> str:
    """W with (the default runs) and without the powder layer."""
    _, five = _default_runs()
    with_layer = {(r["inputs"]["P"], r["inputs"]["v"]): r for r in five}
    lines = ["| P (W) | v (m/s) | status with / without | W (um) with / without "
             "| D (um) with / without | T0 (K) with / without |", "|---|---|---|---|---|---|"]
    for b in _load("powder"):
        key = (b["inputs"]["P"], b["inputs"]["v"])
        a = with_layer.get(key)
        if b["tag"] != "no_powder" or a is None:
            continue
        lines.append(f"| {key[0]:g} | {key[1]:g} | {a['status']} / {b['status']} "
                     f"| {_fmt(a, 'W', '.1f')} / {_fmt(b, 'W', '.1f')} "
                     f"| {_fmt(a, 'D', '.1f')} / {_fmt(b, 'D', '.1f')} "
                     f"| {_fmt(a, 'T0', '.0f')} / {_fmt(b, 'T0', '.0f')} |")
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
    if len(sys.argv) > 1:
        RESULTS = Path(sys.argv[1])
    for title, fn in (("Mesh convergence", convergence_table), ("Speed", speed_table),
                      ("Start independence", start_table),
                      ("The solver's path (152 W / 0.32 m/s)", path_table),
                      ("Powder layer", powder_table), ("Physical sanity", sanity_table),
                      ("Robustness corners", corners_table),
                      ("Coarser default mesh (resolution 0.7)", lambda: coarse_table(0.7))):
        print(f"### {title}\n\n{fn()}\n")
