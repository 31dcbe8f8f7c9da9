"""Validation of the phase-field M2 (``builtin:phase_field``); prints Markdown tables.

    PYTHONPATH=src nice -n 10 python benchmarks/phase_field/validate.py [SECTION ...]

planar   flat front in a 1-cell-wide strip: k_V and undercooling against Aziz's continuous
         growth model (V_D = P eta f''/8 as in ``solidification``), with and without the
         anti-trapping current
perm     flat front at p_int 1500, 5000 and 15000: does the permeability set the trapping?
scaling  spacing (counted cells) against G (factor 4) and S (factor 4): log-log slopes
grid     flat front (1-cell strip) at 5, 2.5 and 1.25 nm cells: k_V and undercooling
converge flat front at 0.3 m/s down to 0.625 nm cells, p_int 1500 and 15000
grid2d   spacing, k_V and undercooling at resolution default (5 nm) and fine (2.5 nm),
         the same 1.92 x 0.64 um domain (the fine run needs about 16 times the default's
         time per simulated microsecond)
compare  phase_field against the closed-form ``solidification`` over the ninb box
fine_g   fine resolution at 0.3 m/s and 2e7, 5e6 K/m (1e7 K/m is in grid2d)
seeds    0.3 m/s, 1e7 K/m and 0.3 m/s, 5e6 K/m with seeds 0, 1, 2 of the initial noise
coarsen  the cell count of one run at 0.3 m/s, 1e7 K/m over 6 freezing-range lengths of
         isotherm travel: does the array coarsen after the steady test accepts it?
band     the fine (2.5 nm) grid started from an array of 22 cells (the count the 5 nm grid
         selects) at 0.3 m/s, 1e7 K/m: does it keep it, or go to the 31-34 cells it selects
         from noise?
restart  the 5 nm grid's established array (4 dT0/G from noise) continued on the 2.5 nm
         grid (``solver.run(..., restart=)``, fields interpolated): kept or re-selected?
"""

from __future__ import annotations

import json
import sys
import time

import numpy as np

from calnet.simulators import phase_field, solidification
from calnet.simulators.phase_field import model
from calnet.simulators.phase_field.outputs import summary
from calnet.simulators.phase_field.solver import run

PARAMS = {"sigma": 2e-6, "M": 7.5, "p_int": 15000.0}  # physics.md worked check


_RUNS: dict[tuple, dict] = {}  # scaling and compare share two points


def _pf(S, G, **opts):
    key = (S, G, tuple(sorted(opts.items())))
    if key in _RUNS:
        return _RUNS[key]
    t0 = time.perf_counter()
    res = phase_field.simulate({"S": S, "G": G, **PARAMS}, **opts)
    o, d = res.outputs, res.diagnostics
    travel = S * d["simulated_time_s"] * G / model.CONSTANTS.freezing_range
    _RUNS[key] = {"S": S, "G": G, "status": res.status, "lambda": o.get("lambda"),
                  "k_V": o.get("k_V"), "dT": o.get("undercooling"),
                  "cells": d.get("cells"), "amp": o.get("amplitude"),
                  "tip_mode": d.get("tip_mode"), "tip_lambda": d.get("tip_wavelength_um"),
                  "steps": d["steps"], "sim_us": d["simulated_time_s"] * 1e6,
                  "travel": travel, "wall": time.perf_counter() - t0}
    print(json.dumps(_RUNS[key]), file=sys.stderr, flush=True)
    return _RUNS[key]


def _flat(S, p_int=PARAMS["p_int"], **opts):
    """A flat front in a 1-cell strip; returns the summary, the run and Aziz (A)."""
    kw = {"nx": 1, "ny": 128, "amplitude": 0.0, "max_steps": 80000, "window": 24,
          "min_travel": 8.0, **opts}
    opts = phase_field.PhaseFieldOptions(**kw)
    par = {**PARAMS, "p_int": p_int}
    rec = run(phase_field.parameters({"S": S, "G": 1e7, **par}), opts)
    a = float(solidification.simulate_batch(S, 1e7, **par, variant="A")["k_V"])
    return summary(rec.history, opts.window), rec, a


def _max_mixture_partition(rec) -> float:
    """x_s behind the front over the highest mixture concentration (the other reading)."""
    phi, xs, xl = (rec.fields[k][:, 0] for k in ("phi", "xs", "xl"))
    j = int(np.nonzero(phi >= 0.999)[0][-1])
    return float(xs[j] / (phi * xs + (1 - phi) * xl)[j:].max())


def planar() -> None:
    print("| S (m/s) | k_V PF | k_V Aziz (A) | diff | k_V max-mixture | diff | dT PF (K) "
          "| speed (m/s) | steps | k_V no AT | diff | wall (s) |\n"
          "|---|---|---|---|---|---|---|---|---|---|---|---|")
    for S in (0.05, 0.1, 0.2, 0.3, 0.6, 1.0):
        t0 = time.perf_counter()
        s, rec, a = _flat(S)
        km = _max_mixture_partition(rec)
        s0, rec0, _ = _flat(S, antitrapping=0.0)
        print(f"| {S} | {s['k_V']:.3f} | {a:.3f} | {s['k_V'] / a - 1:+.1%} | {km:.3f} | "
              f"{km / a - 1:+.1%} | {s['undercooling']:.2f} | {s['tip_speed']:.3f} | "
              f"{rec.steps} ({rec.status}) | {s0['k_V']:.3f} ({rec0.status}) | "
              f"{s0['k_V'] / a - 1:+.1%} | {time.perf_counter() - t0:.1f} |", flush=True)


def perm() -> None:
    print("| p_int (cm^3/(J s)) | S (m/s) | k_V PF | k_V Aziz (A) | diff | dT PF (K) | status |"
          "\n|---|---|---|---|---|---|---|")
    for p_int in (1500.0, 5000.0, 15000.0):
        for S in (0.1, 0.3, 1.0):
            s, rec, a = _flat(S, p_int)
            print(f"| {p_int:g} | {S} | {s['k_V']:.3f} | {a:.3f} | {s['k_V'] / a - 1:+.1%} | "
                  f"{s['undercooling']:.2f} | {rec.status} |", flush=True)


def _table(rows) -> None:
    print("| S (m/s) | G (K/m) | status | lambda (um) | cells | tip-height mode (um) | k_V "
          "| dT (K) | steps | simulated (us) | travel (dT0/G) | wall (s) |\n"
          "|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        _table_row(r)


def _table_row(r) -> None:
    print(f"| {r['S']} | {r['G']:.3g} | {r['status']} | {r['lambda']:.3f} | "
          f"{r['cells']:.1f} | {r['tip_mode']} ({r['tip_lambda']:.3f}) | {r['k_V']:.3f} | "
          f"{r['dT']:.2f} | {r['steps']} | {r['sim_us']:.1f} | {r['travel']:.1f} | "
          f"{r['wall']:.0f} |", flush=True)


def _slope(x, y) -> float:
    return float(np.polyfit(np.log(x), np.log(y), 1)[0])


def scaling() -> None:
    rows = [_pf(0.3, G) for G in (5e6, 1e7, 2e7)] + [_pf(S, 1e7) for S in (0.15, 0.6)]
    _table(rows)
    g_rows, s_rows = rows[:3], [rows[3], rows[1], rows[4]]
    sg = _slope([r["G"] for r in g_rows], [r["lambda"] for r in g_rows])
    ss = _slope([r["S"] for r in s_rows], [r["lambda"] for r in s_rows])
    print(f"\nslope d ln lambda / d ln G = {sg:.2f} (expected -0.5); "
          f"d ln lambda / d ln S = {ss:.2f} (expected -0.25)")


def grid() -> None:
    print("| S (m/s) | dx (nm) | k_V | dT (K) | steps | status |\n|---|---|---|---|---|---|")
    for S in (0.3, 1.0):
        for dx in (5e-9, 2.5e-9, 1.25e-9):
            s, rec, _ = _flat(S, dx=dx, ny=int(round(128 * 5e-9 / dx)),
                              max_steps=int(80000 * (5e-9 / dx) ** 2))
            print(f"| {S} | {dx * 1e9:g} | {s['k_V']:.4f} | {s['undercooling']:.3f} | "
                  f"{rec.steps} | {rec.status} |", flush=True)


def converge() -> None:
    print("| p_int (cm^3/(J s)) | dx (nm) | k_V | k_V Aziz (A) | diff | dT (K) | status | "
          "wall (s) |\n|---|---|---|---|---|---|---|---|")
    for p_int in (1500.0, 15000.0):
        for dx in (2.5e-9, 1.25e-9, 0.625e-9):
            t0 = time.perf_counter()
            s, rec, a = _flat(0.3, p_int, dx=dx, ny=int(round(128 * 5e-9 / dx)),
                              max_steps=int(80000 * (5e-9 / dx) ** 2), min_travel=2.0)
            print(f"| {p_int:g} | {dx * 1e9:g} | {s['k_V']:.4f} | {a:.4f} | "
                  f"{s['k_V'] / a - 1:+.1%} | {s['undercooling']:.2f} | {rec.status} | "
                  f"{time.perf_counter() - t0:.0f} |", flush=True)


def grid2d() -> None:
    rows = [_pf(0.3, 1e7), _pf(0.3, 1e7, resolution="fine")]
    _table(rows)


def compare() -> None:
    print("| S (m/s) | G (K/m) | status | lambda PF (um) | cells | lambda closed form (um) | "
          "PF / closed form | k_V PF | k_V closed form | dT PF (K) | steps | wall (s) |"
          "\n|---|---|---|---|---|---|---|---|---|---|---|---|")
    # the reference box of solidification.BOUNDS (S 0.05-0.6 m/s, G 7e6-1.5e7 K/m)
    for S, G in ((0.05, 7e6), (0.05, 1.5e7), (0.15, 1e7), (0.3, 1e7), (0.6, 7e6),
                 (0.6, 1.5e7)):
        r = _pf(S, G)
        c = solidification.simulate_batch(S, G, **PARAMS)
        print(f"| {S} | {G:.3g} | {r['status']} | {r['lambda']:.3f} | {r['cells']:.1f} | "
              f"{c['lambda']:.3f} | {r['lambda'] / c['lambda']:.2f} | {r['k_V']:.3f} | "
              f"{c['k_V']:.3f} | {r['dT']:.2f} | {r['steps']} | {r['wall']:.0f} |",
              flush=True)


def fine_g() -> None:
    _table([])
    for G in (2e7, 5e6):
        _table_row(_pf(0.3, G, resolution="fine"))


def seeds() -> None:
    rows = [_pf(0.3, G, seed=k) for G in (1e7, 5e6) for k in (0, 1, 2)]
    print("| G (K/m) | seed | status | lambda (um) | cells | steps | wall (s) |\n"
          "|---|---|---|---|---|---|---|")
    for r, k in zip(rows, (0, 1, 2) * 2, strict=True):
        print(f"| {r['G']:.3g} | {k} | {r['status']} | {r['lambda']:.3f} | {r['cells']:.1f} | "
              f"{r['steps']} | {r['wall']:.0f} |")


def height() -> None:
    """The G slope with the default domain (0.38 um of solid and mushy zone below the
    tip) and with one four times as tall whose front row keeps 2.2 um below the tip:
    more than the freezing-range length dT0/G (1.5 um at 1e7 K/m) at every G here."""
    _table([])
    for ny, front_row in ((128, 0.6), (512, 0.85)):
        rows = [_pf(0.3, G, ny=ny, front_row=front_row) for G in (1e7, 2e7, 4e7)]
        for r in rows:
            _table_row(r)
        sg = _slope([r["G"] for r in rows], [r["lambda"] for r in rows])
        print(f"\nny {ny}, front_row {front_row}: slope d ln lambda / d ln G over "
              f"1e7-4e7 K/m = {sg:.2f} (expected -0.5)\n", flush=True)


def coarsen(**options) -> None:
    p = phase_field.parameters({"S": 0.3, "G": 1e7, **PARAMS})
    opts = phase_field.PhaseFieldOptions(**{"min_travel": 6.0, "steady_travel": 4.0,
                                            **options})
    t0 = time.perf_counter()
    rec = run(p, opts)
    length = model.CONSTANTS.freezing_range / p.G / p.S  # time for dT0 / G of travel
    print("| travel (dT0/G) | cells (mean over 0.5 dT0/G) | min | max | lambda (um) |\n"
          "|---|---|---|---|---|")
    t = np.array([s.t for s in rec.history]) / length
    cells = np.array([s.cells for s in rec.history])
    for a in np.arange(0.5, t[-1], 0.5):
        sel = cells[(t > a - 0.5) & (t <= a)]
        print(f"| {a - 0.5:.1f}-{a:.1f} | {sel.mean():.1f} | {sel.min()} | {sel.max()} | "
              f"{opts.nx * opts.dx * 1e6 / sel.mean():.3f} |")
    print(f"\n{rec.status} after {rec.steps} steps, {time.perf_counter() - t0:.0f} s")


def band() -> None:
    coarsen(resolution="fine", initial_cells=22, min_travel=4.0, steady_travel=2.0)


def _counts(rec, t0: float, length: float, width_um: float) -> None:
    """Cell count per half freezing-range length of travel since ``t0``."""
    print("| travel since the start (dT0/G) | cells (mean) | min | max | lambda (um) |\n"
          "|---|---|---|---|---|")
    t = (np.array([s.t for s in rec.history]) - t0) / length
    cells = np.array([s.cells for s in rec.history])
    for a in np.arange(0.5, t[-1] + 1e-9, 0.5):
        sel = cells[(t > a - 0.5) & (t <= a)]
        if sel.size:
            print(f"| {a - 0.5:.1f}-{a:.1f} | {sel.mean():.1f} | {sel.min()} | {sel.max()} | "
                  f"{width_um / sel.mean():.3f} |")


def restart() -> None:
    """The 5 nm grid's established array (from noise, 4 dT0/G of travel) continued on
    the 2.5 nm grid of the same domain for 3 dT0/G: does the finer grid keep the array
    or select its own count?"""
    p = phase_field.parameters({"S": 0.3, "G": 1e7, **PARAMS})
    length = model.CONSTANTS.freezing_range / p.G / p.S
    coarse = phase_field.PhaseFieldOptions(min_travel=4.0, steady_travel=2.0,
                                           max_steps=40000)
    width = coarse.nx * coarse.dx * 1e6
    t0 = time.perf_counter()
    first = run(p, coarse)
    print(f"5 nm from noise: {first.status} after {first.steps} steps, "
          f"{time.perf_counter() - t0:.0f} s\n")
    _counts(first, 0.0, length, width)
    fine = phase_field.PhaseFieldOptions(resolution="fine", min_travel=3.0,
                                         steady_travel=2.0)
    t0 = time.perf_counter()
    second = run(p, fine, restart=first)
    print(f"\n2.5 nm from the 5 nm state: {second.status} after {second.steps} steps, "
          f"{time.perf_counter() - t0:.0f} s\n")
    _counts(second, first.time, length, width)


if __name__ == "__main__":
    for name in sys.argv[1:] or ["planar", "perm", "grid", "converge", "scaling", "compare",
                                 "grid2d"]:
        print(f"\n### {name}\n", flush=True)
        globals()[name]()
