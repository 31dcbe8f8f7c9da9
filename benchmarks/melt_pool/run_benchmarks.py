"""Benchmarks of the M1 melt-pool simulator: mesh convergence, speed, sanity, robustness.

Every run is a fresh subprocess (one at a time, one BLAS thread) so that wall time and
peak memory (``ru_maxrss``) are per run. Results go to ``results/<phase>.json``;
``report.py`` turns them into the markdown tables of ``benchmarks/README.md``.

Usage (from the repository root)::

    OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 \\
        .venv/bin/python benchmarks/melt_pool/run_benchmarks.py convergence sanity corners

Phases ``convergence-res1`` and ``convergence-res2`` run one half of ``convergence``;
``start`` (start independence), ``powder`` (W with and without the powder layer) and
``exposure`` (``consolidation="exposure"`` from both starts), ``sanity-exposure`` (and
``sanity-exposure-reverse``, from the last row, to share the work) and
``convergence-exposure`` (its mesh convergence at two settings) are further phases.
``sanity-clip`` and ``sanity-clip-reverse`` run ``sanity-exposure`` with each cell's
update capped alone (``solver.CLIP_CELLS``), and ``exposure-clip`` the starts of
``exposure`` with it; ``sanity-clip6``, ``sanity-clip6-reverse`` and ``exposure-clip6``
the same with the cell cycle test looking for periods up to 6 (``solver.CYCLE_PERIODS``).
``--help`` lists the phases.
"""

from __future__ import annotations

import csv
import importlib
import itertools
import json
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results"
DATA = HERE.parents[1] / "examples" / "ninb" / "data" / "ninb_melt_pool_width.csv"
SETTINGS = [(81.0, 1.5), (152.0, 0.32), (236.0, 0.23), (90.0, 2.3), (243.0, 1.15)]
# ninb campaign run 104: near the keyhole threshold, two steady states
RUN_104 = {"P": 113.1, "v": 0.569, "K_S": 77.4, "K_L": 113.0, "K_Lz": 1.04, "K_V": 12.0,
           "K_Vz": 1989.0, "A_0": 0.266, "A_max": 0.641}


def _worker(spec: str) -> None:
    """Run one simulation described by a JSON spec; print one JSON line."""
    import resource

    from calnet.simulators import melt_pool

    job = json.loads(spec)
    for item in job.get("patch", []):  # "module.NAME=json": a solver constant
        name, value = item.split("=", 1)
        module, attr = name.split(".")
        obj = importlib.import_module(f"calnet.simulators.melt_pool.{module}")
        setattr(obj, attr, type(getattr(obj, attr))(json.loads(value)))
    t0 = time.perf_counter()
    res = melt_pool.simulate(job["inputs"], **job.get("options", {}))
    wall = time.perf_counter() - t0
    cpu = time.process_time()
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # MiB on Linux
    d = res.diagnostics
    print(json.dumps({**job, "version": melt_pool.VERSION, "status": res.status,
                      "message": res.message,
                      "outputs": res.outputs, "wall_s": wall, "cpu_s": cpu,
                      "peak_rss_mib": rss, "n_cells": d.get("n_cells"),
                      "iterations": d.get("iterations"), "residual": d.get("residual"),
                      "peak_temperature_K": d.get("peak_temperature_K"),
                      "absorptivity": d.get("absorptivity")}))


def run_one(inputs: dict, options: dict | None = None, tag: str = "",
            patch: list[str] | None = None) -> dict:
    spec = json.dumps({"inputs": inputs, "options": options or {}, "tag": tag}
                      | ({"patch": patch} if patch else {}))
    out = subprocess.run([sys.executable, __file__, "--worker", spec], capture_output=True,
                         text=True, check=False)
    if out.returncode != 0:
        return {"inputs": inputs, "options": options or {}, "tag": tag, "status": "crashed",
                "message": out.stderr[-2000:]}
    rec = json.loads(out.stdout.strip().splitlines()[-1])
    print(json.dumps({k: rec.get(k) for k in ("tag", "inputs", "status", "wall_s",
                                                 "n_cells", "iterations")}),
          {k: round(v, 3) for k, v in rec.get("outputs", {}).items()}, flush=True)
    return rec


def _save(name: str, records: list[dict]) -> None:
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / f"{name}.json").write_text(json.dumps(records, indent=1))


def convergence(resolutions: tuple[float, ...] = (1.0, 2.0), name: str = "convergence",
                options: dict | None = None) -> None:
    """Default resolution and the mesh spacing halved at the five settings (a 900 s
    ``time_limit``; ``max_iter`` 1500 and 3600 s on the halved mesh, whose continuation
    on a default-resolution sizing mesh can take 500 iterations).

    Converged records of this version already in ``results/convergence.json`` are reused
    (a stopped phase resumes), and those of other resolutions are kept, so the slow
    halved-spacing runs can be made separately (``convergence-res2``, timing irrelevant)
    from the default ones that the speed table uses (``convergence-res1``).
    """
    from calnet.simulators.melt_pool import VERSION

    tags = {f"res{res:g}" for res in resolutions}
    path = RESULTS / f"{name}.json"
    old = json.loads(path.read_text()) if path.exists() else []
    kept = [r for r in old if r.get("tag") not in tags]
    done = {(r["inputs"]["P"], r["inputs"]["v"], r["tag"]): r for r in old
            if r.get("tag") in tags and r.get("version") == VERSION
            and r["status"] == "ok"}  # resume a stopped phase
    recs: list[dict] = []
    for (P, v), res in itertools.product(SETTINGS, resolutions):
        tag = f"res{res:g}"
        rec = done.get((P, v, tag))
        if rec is None:
            opts = (options or {}) | {"resolution": res, "time_limit": 900.0} | (
                {"max_iter": 1500, "time_limit": 3600.0} if res > 1 else {})
            rec = run_one({"P": P, "v": v}, opts, tag=tag)
        recs.append(rec)
        _save(name, kept + recs)


def sanity(reverse: bool = False, options: dict | None = None, name: str | None = None,
           patch: list[str] | None = None) -> None:
    """Mid-range parameters at the 40 experimental settings, default resolution.

    ``reverse`` (phase ``sanity-reverse``): from the last row backwards, into
    ``results/sanity_reverse.json``, so that a second process can share the work;
    ``report.py`` merges the two files (one record per sample). ``options`` and
    ``name`` (phase ``sanity-exposure``: ``consolidation="exposure"`` into
    ``results/sanity_exposure.json``; ``sanity-exposure-reverse`` from the last row) run
    a variant; ``patch`` sets solver constants (``"solver.CLIP_CELLS=true"``). A stopped
    phase resumes: records of this version with the same options are reused.
    """
    from calnet.simulators.melt_pool import VERSION

    path = RESULTS / f"{name or ('sanity_reverse' if reverse else 'sanity')}.json"
    old = {r["tag"]: r for r in (json.loads(path.read_text()) if path.exists() else [])
           if r.get("version") == VERSION and r.get("options") == (options or {})
           and r.get("patch", []) == (patch or [])}
    recs = []
    with DATA.open() as fh:
        rows = list(csv.DictReader(fh))
    for r in rows[::-1] if reverse else rows:
        rec = old.get(f"sample{r['sample']}") or run_one(
            {"P": float(r["power_W"]), "v": float(r["speed_m_per_s"])}, options,
            tag=f"sample{r['sample']}", patch=patch)
        rec["measured_W"] = float(r["width_um"])
        rec["split"] = r["split"]
        recs.append(rec)
        _save(name or ("sanity_reverse" if reverse else "sanity"), recs)


def corners() -> None:
    """Corners of P x v (80-250 W, 0.05-2.3 m/s) with all parameters at lower/upper."""
    from calnet.simulators.melt_pool import BOUNDS, PARAMETERS

    recs = []
    for P, v, side in itertools.product((80.0, 250.0), (0.05, 2.3), (0, 1)):
        theta = {k: BOUNDS[k][side] for k in PARAMETERS}
        recs.append(run_one({"P": P, "v": v, **theta}, {"time_limit": 60.0},
                            tag=f"theta_{'upper' if side else 'lower'}"))
        _save("corners", recs)
    for P, v in itertools.product((80.0, 250.0), (0.05, 2.3)):  # mixed: hot & insulating
        theta = {k: BOUNDS[k][0] for k in PARAMETERS} | {"A_0": 0.4, "A_max": 0.8}
        recs.append(run_one({"P": P, "v": v, **theta}, {"time_limit": 60.0},
                            tag="theta_lowk_highA"))
        _save("corners", recs)


def start() -> None:
    """Both initial fields of the first continuation stage at five settings, default
    resolution: run 104 and four of the convergence settings."""
    cases = [RUN_104] + [{"P": P, "v": v} for P, v in SETTINGS if (P, v) != (90.0, 2.3)]
    recs = []
    for inputs, first in itertools.product(cases, ("rosenthal", "ambient")):
        recs.append(run_one(inputs, {"start": first}, tag=first))
        _save("start", recs)


def powder() -> None:
    """W without the powder layer at the five settings, default resolution; with the
    layer too where ``results/start.json`` holds no default run of the setting."""
    path = RESULTS / "start.json"
    done = {(r["inputs"]["P"], r["inputs"]["v"]) for r in json.loads(path.read_text())
            if r["tag"] == "rosenthal" and set(r["inputs"]) == {"P", "v"}} \
        if path.exists() else set()
    recs = []
    for (P, v), layer in itertools.product(SETTINGS, (True, False)):
        if layer and (P, v) in done:
            continue
        recs.append(run_one({"P": P, "v": v}, {"powder": layer},
                            tag="powder" if layer else "no_powder"))
        _save("powder", recs)


def exposure(patch: list[str] | None = None, name: str = "exposure") -> None:
    """``consolidation="exposure"`` from both starts at run 104 and the five settings,
    default resolution, into ``results/exposure.json`` (``patch``: solver constants, as
    :func:`sanity`, into ``results/<name>.json``)."""
    cases = [RUN_104] + [{"P": P, "v": v} for P, v in SETTINGS]
    recs = []
    for inputs, first in itertools.product(cases, ("rosenthal", "ambient")):
        recs.append(run_one(inputs, {"start": first, "consolidation": "exposure"},
                            tag=first, patch=patch))
        _save(name, recs)


def convergence_exposure() -> None:
    """``consolidation="exposure"`` at ``resolution`` 1 and 2 at 81 W / 1.5 and 152 W /
    0.32 m/s (the limits of ``convergence``), into ``results/convergence_exposure.json``."""
    recs = []
    for (P, v), res in itertools.product([(81.0, 1.5), (152.0, 0.32)], (1.0, 2.0)):
        opts = {"consolidation": "exposure", "resolution": res, "time_limit": 900.0} | (
            {"max_iter": 1500, "time_limit": 3600.0} if res > 1 else {})
        recs.append(run_one({"P": P, "v": v}, opts, tag=f"res{res:g}"))
        _save("convergence_exposure", recs)


def path() -> None:
    """Does the state depend on the solver's path? 152 W / 0.32 m/s with
    ``refine_outputs``, the continuation in power in steps of at most 1.5 (default), 1.3
    and 1.2, for the default consolidation and ``"exposure"``, into
    ``results/path.json``."""
    recs = []
    for form, ratio in itertools.product(("monotone", "exposure"), (1.5, 1.3, 1.2)):
        recs.append(run_one({"P": 152.0, "v": 0.32},
                            {"refine_outputs": True, "consolidation": form,
                             "continuation_ratio": ratio, "max_iter": 1500},
                            tag=f"{form}-{ratio:g}"))
        _save("path", recs)


def exposure_refined_long() -> None:
    """``consolidation="exposure"`` with ``refine_outputs`` at ``resolution`` 1 and
    ``max_iter`` 1500 at the two settings where 500 are too few, into
    ``results/convergence_exposure_refined_long.json``."""
    recs = []
    for P, v in ((243.0, 1.15), (236.0, 0.23)):
        recs.append(run_one({"P": P, "v": v}, {**EXPOSURE, "refine_outputs": True,
                                               "resolution": 1.0, "time_limit": 3600.0,
                                               "max_iter": 1500}, tag="res1-max_iter1500"))
        _save("convergence_exposure_refined_long", recs)


CLIP = ["solver.CLIP_CELLS=true"]
CLIP6 = [*CLIP, "solver.CYCLE_PERIODS=6"]
EXPOSURE = {"consolidation": "exposure"}

if __name__ == "__main__":
    PHASES = {"convergence": convergence, "sanity": sanity, "corners": corners,
             "start": start, "powder": powder, "exposure": exposure,
             "convergence-exposure": convergence_exposure,
             "sanity-reverse": lambda: sanity(True),
             "sanity-exposure": lambda: sanity(options={"consolidation": "exposure"},
                                               name="sanity_exposure"),
             "sanity-exposure-reverse": lambda: sanity(
                 True, options={"consolidation": "exposure"},
                 name="sanity_exposure_reverse"),
             "sanity-clip": lambda: sanity(options=EXPOSURE, name="sanity_clip", patch=CLIP),
             "sanity-clip-reverse": lambda: sanity(True, options=EXPOSURE,
                                                   name="sanity_clip_reverse", patch=CLIP),
             "exposure-clip": lambda: exposure(CLIP, "exposure_clip"),
             "sanity-clip6": lambda: sanity(options=EXPOSURE, name="sanity_clip6", patch=CLIP6),
             "sanity-clip6-reverse": lambda: sanity(True, options=EXPOSURE,
                                                    name="sanity_clip6_reverse", patch=CLIP6),
             "exposure-clip6": lambda: exposure(CLIP6, "exposure_clip6"),
             "convergence-res1": lambda: convergence((1.0,)),
             "convergence-res2": lambda: convergence((2.0,)),
             "sanity-refined": lambda: sanity(options={"refine_outputs": True},
                                              name="sanity_refined"),
             "path": path,
             "convergence-exposure-refined-long": exposure_refined_long,
             "sanity-exposure-refined": lambda: sanity(
                 options={**EXPOSURE, "refine_outputs": True}, name="sanity_exposure_refined"),
             "sanity-exposure-refined-reverse": lambda: sanity(
                 True, options={**EXPOSURE, "refine_outputs": True},
                 name="sanity_exposure_refined_reverse"),
             "convergence-exposure-refined": lambda: convergence(
                 name="convergence_exposure_refined",
                 options={**EXPOSURE, "refine_outputs": True}),
             "convergence-refined": lambda: convergence(name="convergence_refined",
                                                        options={"refine_outputs": True}),
             "convergence-refined-res1": lambda: convergence(
                 (1.0,), name="convergence_refined", options={"refine_outputs": True}),
             "convergence-refined-res2": lambda: convergence(
                 (2.0,), name="convergence_refined", options={"refine_outputs": True})}
    if len(sys.argv) > 2 and sys.argv[1] == "--worker":
        _worker(sys.argv[2])
    elif len(sys.argv) < 2 or not set(sys.argv[1:]) <= set(PHASES):
        bad = sorted(set(sys.argv[1:]) - set(PHASES) - {"-h", "--help"})
        print((f"unknown phase: {', '.join(bad)}\n" if bad else "")
              + "usage: run_benchmarks.py PHASE [PHASE ...]; phases: " + ", ".join(PHASES))
        sys.exit(2 if bad else 0)
    else:
        for phase in sys.argv[1:]:
            PHASES[phase]()
