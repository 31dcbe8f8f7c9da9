"""Grid convergence and spacing scaling of the phase-field M2 on an accelerator.

    PYTHONPATH=src python benchmarks/phase_field/device.py OUT_DIR [--set grid|seeds]
        [--deadline S] [--min-travel T] [--smoke]

Runs the cases of :data:`SETS` in order (``grid``: resolutions and the spacing's
scaling; ``seeds``: other seeds of the initial noise at 0.3 m/s; ``long``: the seeds
again, for a run with a larger ``--min-travel``) on jax's default device
(a GPU where there is one) at the physics.md worked-check parameters, on the 1.92 x 0.64
um domain of the ``default`` and ``fine`` resolutions at 5, 2.5, 1.25 and 0.625 nm cells.
Before each run a probe times the run's chunk of steps; the run's step budget is cut to
what fits before ``--deadline`` seconds (from the start of the script), so a run that
would not finish ends ``budget`` with its history kept, and a run that cannot take a
tenth of its expected steps is skipped. Each finished run appends one JSON line to
``OUT_DIR/pf_device.jsonl`` (summary, steps, wall time, time per step, and the front
after every chunk: time in us, cells, undercooling, k_V, tip-height mode). ``--smoke``
shrinks every grid (a check of the script on a CPU).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import jax
import numpy as np

from calnet.simulators import phase_field
from calnet.simulators.phase_field import model, outputs, solver
from calnet.simulators.phase_field.options import PhaseFieldOptions

PARAMS = {"sigma": 2e-6, "M": 7.5, "p_int": 15000.0}  # physics.md worked check
WIDTH, HEIGHT = 1.92e-6, 0.64e-6  # m, the domain of the named resolutions

#: (S m/s, G K/m, dx nm, seed) of each set, in order of priority
SETS = {
    "grid": [
        (0.3, 1e7, 5.0, 0),  # the default grid: the CPU's 0.083 um, 23 cells, 6000 steps
        (0.3, 1e7, 1.25, 0),
        (0.3, 2e7, 1.25, 0),
        (0.3, 5e6, 1.25, 0),
        (0.3, 1e7, 0.625, 0),
        (0.15, 1e7, 1.25, 0),
        (0.6, 1e7, 1.25, 0),
        (0.15, 1e7, 2.5, 0),
        (0.6, 1e7, 2.5, 0),
        (0.3, 2e7, 0.625, 0),
        (0.3, 5e6, 0.625, 0),
    ],
    "seeds": [(0.3, 1e7, dx, seed) for dx in (2.5, 1.25, 5.0) for seed in (0, 1, 2, 3)]
    + [(0.3, G, 1.25, seed) for G in (2e7, 5e6) for seed in (1, 2)],
    # run with --min-travel 6: does the spacing still move after 2 dT0/G?
    "long": [(0.3, 1e7, 2.5, seed) for seed in (0, 1, 2, 3)]
    + [(0.3, 1e7, 1.25, seed) for seed in (0, 1, 2)]
    + [(0.3, 1e7, 5.0, seed) for seed in (0, 1, 2, 3)] + [(0.3, 1e7, 0.625, 0)],
}


def _options(dx_nm: float, seed: int, smoke: bool, min_travel: float) -> PhaseFieldOptions:
    dx = dx_nm * 1e-9
    nx, ny = int(round(WIDTH / dx)), int(round(HEIGHT / dx))
    steps = int(160000 * (2.5 / dx_nm) ** 2 * max(1.0, min_travel / 2.0))
    if smoke:  # a small grid and a short budget
        nx, ny, dx, steps = 24, 32, 5e-9, 600
    return PhaseFieldOptions(dx=dx, nx=nx, ny=ny, max_steps=steps, seed=seed,
                             min_travel=min_travel)


def _expected_steps(p, opts: PhaseFieldOptions, dt: float) -> int:
    """Steps for ``min_travel`` plus half a freezing-range length of isotherm travel."""
    travel = (opts.min_travel + 0.5) * model.CONSTANTS.freezing_range / p.G / p.S
    return int(math.ceil(travel / dt))


def _probe(p, opts: PhaseFieldOptions, dt: float, chunk: int) -> float:
    """Seconds per step of the run's chunk (compiled first, then timed twice)."""
    phi, xs, xl, y_front = solver.initial_fields(opts, model.CONSTANTS, p.S)
    T_ref = model.CONSTANTS.T0 - model.CONSTANTS.freezing_range
    par = jax.numpy.array([p.S, p.G, p.sigma, p.mobility, p.permeability, T_ref, y_front])
    target = int(round(opts.front_row * opts.ny))
    state = (jax.numpy.asarray(phi), jax.numpy.asarray(xs), jax.numpy.asarray(xl), 0.0, 0.0)

    def go(state):
        out = solver.advance(*state[:3], np.float64(state[3]), np.float64(state[4]), dt, par,
                             n_steps=chunk, dx=opts.dx, c=model.CONSTANTS, target=target,
                             coupling=opts.coupling, antitrapping=opts.antitrapping)
        jax.block_until_ready(out)
        return out

    state = go(state)
    t0 = time.perf_counter()
    go(go(state))
    return (time.perf_counter() - t0) / (2 * chunk)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--set", choices=sorted(SETS), default="grid")
    ap.add_argument("--deadline", type=float, default=480.0)
    ap.add_argument("--min-travel", type=float, default=PhaseFieldOptions.min_travel,
                    help="isotherm travel before a steady state is accepted, dT0/G")
    ap.add_argument("--smoke", action="store_true")
    args = ap.parse_args()
    start = time.perf_counter()
    args.out.mkdir(parents=True, exist_ok=True)
    dest = args.out / "pf_device.jsonl"
    dev = jax.devices()[0]
    print(f"jax {jax.__version__}, device {dev.platform}: {dev.device_kind}, "
          f"default float {jax.numpy.asarray(1.0).dtype}", flush=True)
    for S, G, dx_nm, seed in SETS[args.set]:
        left = args.deadline - (time.perf_counter() - start)
        p = phase_field.parameters({"S": S, "G": G, **PARAMS})
        opts = _options(dx_nm, seed, args.smoke, args.min_travel)
        dt = model.stable_time_step(p.sigma, p.mobility, opts.dx, model.CONSTANTS)
        chunk = min(max(math.ceil(opts.chunk_cells * opts.dx / (p.S * dt)), 10), 4000)
        need = _expected_steps(p, opts, dt)
        t_probe = time.perf_counter()
        per_step = _probe(p, opts, dt, chunk)
        left -= time.perf_counter() - t_probe
        # the run's own compile, the per-chunk measurement and transfers: 1.3 times
        fits = int(0.9 * left / (1.3 * per_step))
        label = f"S {S} G {G:.3g} dx {dx_nm} nm ({opts.nx} x {opts.ny}) seed {seed}"
        print(f"{label}: {per_step * 1e6:.1f} us/step, chunk {chunk}, expected {need} "
              f"steps, {fits} fit in {left:.0f} s", flush=True)
        if fits < max(need // 10, 2 * chunk):
            print(f"{label}: skipped", flush=True)
            continue
        opts = opts.with_(max_steps=min(opts.max_steps, fits))
        rec = solver.run(p, opts)
        s = outputs.summary(rec.history, opts.window) if rec.history else {}
        travel = p.S * rec.time * p.G / model.CONSTANTS.freezing_range
        row = {"S": S, "G": G, "dx_nm": dx_nm, "seed": seed, "nx": opts.nx, "ny": opts.ny,
               "status": rec.status, "steps": rec.steps, "max_steps": opts.max_steps,
               "sim_us": rec.time * 1e6, "travel": travel, "dt": rec.dt,
               "wall": rec.wall_seconds, "us_per_step": per_step * 1e6,
               "lambda_um": s.get("spacing", math.nan) * 1e6, "cells": s.get("cells"),
               "k_V": s.get("k_V"), "dT": s.get("undercooling"),
               "tip_speed": s.get("tip_speed"), "mode": s.get("mode"),
               "min_travel": opts.min_travel, "version": phase_field.VERSION,
               "history": [[h.t * 1e6, h.cells, round(h.undercooling, 4), round(h.k_V, 5),
                            h.mode] for h in rec.history],
               "device": dev.device_kind, "jax": jax.__version__, "smoke": args.smoke}
        with dest.open("a") as f:
            f.write(json.dumps(row) + "\n")
        print(f"{label}: {rec.status}, lambda {row['lambda_um']:.4f} um, cells "
              f"{row['cells']}, k_V {row['k_V']:.4f}, dT {row['dT']:.3f} K, "
              f"{rec.steps} steps, travel {travel:.2f}, {rec.wall_seconds:.1f} s", flush=True)
    print(f"done in {time.perf_counter() - start:.0f} s", flush=True)


if __name__ == "__main__":
    sys.exit(main())
