"""One melt-pool run: parameters -> mesh -> Newton solve -> outputs (the driver).

Pipeline: Rosenthal estimate -> sizing :class:`~.mesh.Mesh` -> continuation in laser
power from a cold start (:func:`power_ladder`, each stage a
:func:`~.solver.newton_solve`) -> fine mesh around the computed pool -> fine solve from
the interpolated field -> :func:`~.outputs.extract`; if the fine pool left the finely
meshed box the mesh is rebuilt around it once more.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from scipy.interpolate import RegularGridInterpolator

from calnet.simulators.materials import NI5NB, STEFAN_BOLTZMANN, AlloyProperties
from calnet.simulators.melt_pool.assembly import Discretization
from calnet.simulators.melt_pool.mesh import Mesh, PoolBox, build_mesh, estimate_pool, pool_box
from calnet.simulators.melt_pool.options import MeltPoolOptions
from calnet.simulators.melt_pool.outputs import PoolGeometry, _outer_crossing, extract
from calnet.simulators.melt_pool.properties import (
    MaterialLaws,
    absorptivity_of_temperature,
    build_laws,
)
from calnet.simulators.melt_pool.solver import AbsorptivityLaw, SolveReport, newton_solve


@dataclass(frozen=True)
class RunRecord:
    """Everything one run produced (internal; turned into a SimResult by ``simulate``)."""

    geometry: PoolGeometry | None
    report: SolveReport
    mesh: Mesh
    remeshed: int
    seconds: float
    stages: tuple[dict, ...] = ()  # per Newton solve: mesh, power, iterations, CPU


def _absorptivity(disc: Discretization, laws: MaterialLaws, theta: dict[str, float],
                  opts: MeltPoolOptions, mat: AlloyProperties) -> AbsorptivityLaw:
    def by_temperature(T: np.ndarray) -> tuple[float, np.ndarray | None, float]:
        ts, dts = disc.surface_temperature(T, laws)
        A, dA = absorptivity_of_temperature(ts, theta, mat, opts.w_absorb)
        return float(A), dA * dts, ts

    def by_keyhole(T: np.ndarray) -> tuple[float, np.ndarray | None, float]:
        ts, _ = disc.surface_temperature(T, laws)
        zc, yc = Mesh.centres(disc.mesh.zf), Mesh.centres(disc.mesh.yf)
        T3 = T.reshape(disc.mesh.shape)
        col = T3[:, 0, :] + (T3[:, 0, :] - T3[:, 1, :]) * yc[0] ** 2 / (yc[1] ** 2 - yc[0] ** 2)
        depth = np.nan_to_num(_outer_crossing(col, zc, mat.T_boil), nan=0.0).max()
        frac = min(1.0, depth / mat.beam_radius)
        return theta["A_0"] + (theta["A_max"] - theta["A_0"]) * frac, None, ts

    return AbsorptivityLaw(by_temperature if opts.absorptivity == "surface_temperature"
                           else by_keyhole)


def _surface_loss(T: float, mat: AlloyProperties) -> float:
    """Radiative and convective loss (W/m^2) of the top surface at ``T``."""
    return (mat.emissivity * STEFAN_BOLTZMANN * (T**4 - mat.T_ambient**4)
            + mat.h_conv * (T - mat.T_ambient))


def initial_field(mesh: Mesh, P: float, v: float, absorb: float, k: float,
                  mat: AlloyProperties) -> np.ndarray:
    """Rosenthal field with the source smeared over the beam radius, capped at ``T_b``."""
    alpha = k / (mat.rho * mat.cp_solid)
    X, Y, Z = np.meshgrid(*(Mesh.centres(a) for a in (mesh.xf, mesh.yf, mesh.zf)),
                          indexing="ij")
    R = np.sqrt(X**2 + Y**2 + Z**2 + (0.5 * mat.beam_radius) ** 2)
    T = mat.T_ambient + absorb * P / (2 * math.pi * k * R) * np.exp(-v * (R + X) / (2 * alpha))
    return np.minimum(T, mat.T_boil).ravel()


def _box_from_geometry(g: PoolGeometry, resolution: float, mat: AlloyProperties
                       ) -> PoolBox:
    return pool_box(-g.x_tail, max(g.x_front, 0.0), 0.5 * g.W, g.D,
                    resolution=resolution, beam_radius=mat.beam_radius)


def _needs_remesh(g: PoolGeometry, box: PoolBox) -> bool:
    if not all(np.isfinite([g.W, g.D, g.x_tail])):
        return False
    return (-g.x_tail > box.tail - 2 * box.h or 0.5 * g.W > box.half_width - 2 * box.h
            or g.D > box.depth - 2 * box.h)


COARSE = 0.5  # resolution of the sizing pre-solve relative to the requested one
G_WINDOW_CELLS = 6.0  # G0 window half-width, in pool spacings of the resolution-1 mesh
# s, first pseudo time step of a warm-started solve. 1e-2 s against 2e-5: 20 % fewer Newton
# iterations at the 5 benchmark settings, and 96 W / 0.364 m/s converges; 1.0 (plain
# Newton) takes 6 % less CPU there but wanders at 250 W / 0.05 m/s with the upper
# parameter bounds (benchmarks/README.md, "What was tried for speed")
WARM_DT0 = 1e-2
COARSE_RTOL = 1e-4  # the sizing pre-solve only needs to place the pool
STAGE_RTOL, STAGE_TTOL = 1e-4, 1.0  # (-, K) continuation stages below P only stay on the branch


def power_ladder(P: float, v: float, theta: dict[str, float], ratio: float,
                 mat: AlloyProperties) -> list[float]:
    """Laser powers (W) of the continuation, increasing geometrically to ``P``.

    The first is the power at which the beam-smeared Rosenthal field with the largest
    absorptivity ``A_max`` and the solid conductivity ``K_S`` peaks at ``T_L``: far from
    the vapour switch, so the absorptivity stays at ``A_0`` and the steady problem has a
    single (conduction-mode) solution. Consecutive powers differ by at most ``ratio``.
    """
    k = theta["K_S"]
    alpha = k / (mat.rho * mat.cp_solid)
    r = 0.5 * mat.beam_radius
    rise = theta["A_max"] * P / (2 * math.pi * k * r) * math.exp(-v * r / (2 * alpha))
    s0 = min(1.0, (mat.T_liquidus - mat.T_ambient) / rise)
    n = math.ceil(math.log(1.0 / s0) / math.log(ratio) - 1e-9) if s0 < 1 else 0
    return [P * s0 ** (1.0 - j / n) for j in range(n)] + [P]


BRANCH_JUMP = 0.5  # share of A_max - A_0 by which the absorptivity changes between branches


def _left_branch(a: float, a_before: float, theta: dict[str, float]) -> bool:
    """Whether the absorptivity moved from conduction to keyhole mode or back."""
    return abs(a - a_before) > BRANCH_JUMP * (theta["A_max"] - theta["A_0"])


def _tolerance(final: float, last: bool, below_p: bool, sizing: float, stage: float
               ) -> float:
    """Tolerance of one solve: ``final`` for the last, looser on the sizing mesh."""
    return final if last else max(final, stage if below_p else sizing)


def _start(mesh: Mesh, P: float, v: float, theta: dict[str, float], opts: MeltPoolOptions,
           mat: AlloyProperties) -> np.ndarray:
    """Initial field of the first continuation stage (``opts.start``)."""
    if opts.start == "ambient":
        return np.full(mesh.size, mat.T_ambient)
    return initial_field(mesh, P, v, theta["A_0"], math.sqrt(theta["K_S"] * theta["K_L"]), mat)


def run(P: float, v: float, theta: dict[str, float], opts: MeltPoolOptions,
        mat: AlloyProperties = NI5NB, *,
        progress: Callable[[float, str], None] | None = None) -> RunRecord:
    """Solve one case; see :func:`calnet.simulators.melt_pool.simulate`.

    Continuation in laser power on the sizing mesh (half the resolution, sized by the
    Rosenthal estimate): from a cold, conduction-mode solution at the first power of
    :func:`power_ladder`, each stage warm-started from the previous one, so the run
    follows the conduction branch up to ``P`` wherever it exists and reaches the
    keyhole branch only where it stops existing (the state a track started on cold
    material reaches). The pool found at ``P`` sizes the fine mesh, and the fine solve
    starts from the interpolated field; a further re-mesh happens only if the fine pool
    still leaves its finely meshed box. ``progress``, when given, is called after every
    Newton solve with the share of ``max_iter`` spent and a line saying where the run is.
    """
    start = time.monotonic()
    deadline = None if opts.time_limit is None else start + opts.time_limit
    a_mid = 0.5 * (theta["A_0"] + theta["A_max"])
    k_est = math.sqrt(theta["K_S"] * theta["K_L"])
    tail, front, half = estimate_pool(P, v, a_mid, k_est, mat)
    k_p = mat.k_powder if opts.k_powder is None else opts.k_powder
    laws = build_laws(theta, mat, kvz_mode=opts.kvz_mode, anisotropy=opts.anisotropy,
                      w_vapour=opts.w_vapour, k_powder=k_p)
    res = opts.resolution * COARSE if opts.adapt_mesh else opts.resolution
    box = pool_box(tail, front, half, half + mat.powder_thickness * opts.powder,
                   resolution=res, beam_radius=mat.beam_radius)
    mesh = build_mesh(box, mat, resolution=res, powder=opts.powder,  # refined if final
                      refine=opts.refine_outputs and res == opts.resolution)
    powers = power_ladder(P, v, theta, opts.continuation_ratio, mat)
    T0 = _start(mesh, powers[0], v, theta, opts, mat)
    iterations, dt0, geometry, stages = 0, None, None, []
    below = None  # (power, field, mesh) of the last converged solve below P
    a_before = None  # absorptivity at P on the previous mesh
    for stage in range(3):
        final_stage = res == opts.resolution
        disc = Discretization(mesh, mat, P, v)
        disc.secant_faces = opts.consolidation == "exposure"  # continuous in frac
        disc.conserved_mass = opts.mass_flux == "conserved"
        queue, retried = (list(powers) if stage == 0 else [P]), False
        while queue:
            p_stage = queue.pop(0)
            last = p_stage == P and final_stage
            d = disc.with_power(p_stage)
            # the solve at P on a new mesh, from the coarser mesh's field interpolated
            # onto it: it must stay on the branch the coarser mesh was on
            watch = p_stage == P and not retried and below is not None and a_before is not None
            cpu = time.process_time()
            report = newton_solve(d, laws, T0, absorptivity=_absorptivity(d, laws, theta,
                                  opts, mat), k_powder=k_p,
                                  rtol=_tolerance(opts.rtol, last, p_stage < P,
                                                  COARSE_RTOL, STAGE_RTOL),
                                  ttol=_tolerance(opts.ttol, last, p_stage < P, 1.0, STAGE_TTOL),
                                  max_iter=opts.max_iter - iterations,
                                  max_update=opts.max_update, deadline=deadline,
                                  consolidation=opts.consolidation,
                                  abandon=(lambda a, a0=a_before: _left_branch(a, a0, theta))
                                  if watch else None,
                                  **({} if dt0 is None else {"dt0": dt0}))
            iterations += report.iterations
            stages.append({"mesh": "fine" if final_stage else "sizing", "P": p_stage,
                           "n_cells": mesh.size, "iterations": report.iterations,
                           "cpu_s": time.process_time() - cpu,
                           "converged": report.converged})
            if progress is not None:
                progress(min(iterations / opts.max_iter, 1.0),
                         f"{stages[-1]['mesh']} mesh ({mesh.size} cells) at {p_stage:.0f} W: "
                         f"{report.iterations} Newton iterations, "
                         + ("converged" if report.converged else "not converged"))
            if (report.reason == "left branch" if not report.converged
                    else watch and _left_branch(report.absorptivity, a_before, theta)):
                # it fell off that branch (given up, or converged on the other one):
                # reach P on this mesh by continuation instead
                stages[-1]["left_branch"] = retried = True
                T0, dt0 = _interpolate(below[1], below[2], mesh), WARM_DT0
                queue = [below[0], P]
                continue
            if not report.converged:
                break
            if p_stage < P:
                below = (p_stage, report.T, mesh)
            T0, dt0 = report.T, WARM_DT0
        if not report.converged:
            break
        a_before = report.absorptivity
        geometry = extract(report.T, report.frac, mesh, laws, v=v, T_liquidus=mat.T_liquidus,
                           g_window_cells=G_WINDOW_CELLS,
                           tail_flux=_surface_loss(mat.T_liquidus, mat))
        final = res == opts.resolution and (stage == 2 or not _needs_remesh(geometry, box))
        if final or not opts.adapt_mesh:
            break
        sized = all(np.isfinite([geometry.W, geometry.D, geometry.x_tail, geometry.x_front]))
        res = opts.resolution
        box = (_box_from_geometry(geometry, res, mat) if sized else  # else: Rosenthal box
               pool_box(tail, front, half, half + mat.powder_thickness * opts.powder,
                        resolution=res, beam_radius=mat.beam_radius))
        new_mesh = build_mesh(box, mat, resolution=res, powder=opts.powder,
                              refine=opts.refine_outputs)
        T0, dt0, mesh = _interpolate(report.T, mesh, new_mesh), WARM_DT0, new_mesh
    report = replace(report, iterations=iterations)
    return RunRecord(geometry if report.converged else None, report, mesh, stage,
                     time.monotonic() - start, tuple(stages))


def _interpolate(T: np.ndarray, old: Mesh, new: Mesh) -> np.ndarray:
    c_old = [Mesh.centres(a) for a in (old.xf, old.yf, old.zf)]
    c_new = np.meshgrid(*(Mesh.centres(a) for a in (new.xf, new.yf, new.zf)), indexing="ij")
    f = RegularGridInterpolator(c_old, T.reshape(old.shape), bounds_error=False, fill_value=None)
    pts = np.stack([np.clip(c, o[0], o[-1]) for c, o in zip(c_new, c_old, strict=True)], -1)
    return f(pts.reshape(-1, 3))
