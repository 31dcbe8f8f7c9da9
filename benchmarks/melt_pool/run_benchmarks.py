"""Benchmarks of the M1 melt-pool simulator: mesh convergence, speed, sanity, robustness.

Every run is a fresh subprocess (one at a time, one BLAS thread) so that wall time and
peak memory (``ru_maxrss``) are per run. Results go to ``results/<phase>.json``;
``report.py`` turns them into the markdown tables of ``benchmarks/README.md``.

Usage (from the repository root)::

    OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 \\
        .venv/bin/python benchmarks/melt_pool/run_benchmarks.py convergence sanity corners

Phases ``convergence-res1`` and ``convergence-res2`` run one half of ``convergence``;
``start`` (start independence), ``powder`` (W with and without the powder layer),
``sanity-reverse`` (``sanity`` from the last row, to share the work with a second
process), ``path`` (the continuation step) and ``coarse`` (speed and mesh error at
``resolution=0.7``) are further phases. ``--help`` lists them.
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
    t0, cpu0 = time.perf_counter(), time.process_time()
    res = melt_pool.simulate(job["inputs"], **job.get("options", {}))
    wall = time.perf_counter() - t0
    cpu = time.process_time()  # the process's: Python start-up and imports included
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # MiB on Linux
    d = res.diagnostics
    print(json.dumps({**job, "version": melt_pool.VERSION, "status": res.status,
                      "message": res.message,
                      "outputs": res.outputs, "wall_s": wall, "cpu_s": cpu,
                      "sim_cpu_s": cpu - cpu0,
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
        # the other resolutions' records as the file holds them now: the phases
        # convergence-res1 and convergence-res2 may run at the same time
        others = [r for r in (json.loads(path.read_text()) if path.exists() else [])
                  if r.get("tag") not in tags]
        _save(name, others + recs)


def sanity(reverse: bool = False, options: dict | None = None, name: str | None = None,
           patch: list[str] | None = None) -> None:
    """Mid-range parameters at the 40 experimental settings, default resolution.

    ``reverse`` (phase ``sanity-reverse``): from the last row backwards, into
    ``results/sanity_reverse.json``, so that a second process can share the work;
    ``report.py`` merges the two files (one record per sample). ``options``, ``name``
    and ``patch`` (solver constants, ``"solver.COLD_MARGIN=0"``) run a variant. A
    stopped phase resumes: records of this version with the same options are reused.
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
    """Both initial fields of the first continuation stage at run 104 and the five
    convergence settings, default resolution."""
    cases = [RUN_104] + [{"P": P, "v": v} for P, v in SETTINGS]
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


def path() -> None:
    """Does the state depend on the solver's path? 152 W / 0.32 m/s, the continuation in
    power in steps of at most 1.5 (default), 1.3 and 1.2, for the default consolidation
    (``"exposure"``) and ``"monotone"``, into ``results/path.json``."""
    recs = []
    for form, ratio in itertools.product(("exposure", "monotone"), (1.5, 1.3, 1.2)):
        recs.append(run_one({"P": 152.0, "v": 0.32},
                            {"consolidation": form,
                             "continuation_ratio": ratio, "max_iter": 1500},
                            tag=f"{form}-{ratio:g}"))
        _save("path", recs)


def coarse(resolution: float) -> None:
    """The speed and mesh error a coarser default mesh would give: the 5 convergence
    settings at ``resolution`` (against the halved mesh of ``convergence-res2`` in
    ``report.py``) and the 40 sanity settings, into ``results/sanity_res<r>.json``."""
    convergence((resolution,))
    sanity(options={"resolution": resolution}, name=f"sanity_res{resolution:g}")


if __name__ == "__main__":
    PHASES = {"convergence": convergence, "sanity": sanity, "corners": corners,
              "start": start, "powder": powder, "path": path,
              "sanity-reverse": lambda: sanity(True),
              "convergence-res1": lambda: convergence((1.0,)),
              "convergence-res2": lambda: convergence((2.0,)),
              "coarse": lambda: coarse(0.7)}
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
