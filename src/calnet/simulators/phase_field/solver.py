"""Explicit time stepping of the phase-field model in a frame that follows the front.

The low level is :func:`advance` (a jitted chunk of steps followed by a frame shift, pure
JAX); :func:`run` drives chunks until the front is steady, the step budget is spent or
the fields diverge, and returns a :class:`PhaseFieldRun`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from calnet.simulators.phase_field import outputs
from calnet.simulators.phase_field.model import (
    CONSTANTS,
    PhaseFieldConstants,
    stable_time_step,
    step,
)
from calnet.simulators.phase_field.options import PhaseFieldOptions


@dataclass(frozen=True)
class PhysicalParameters:
    """One run's physics, SI: speed ``S`` (m/s), gradient ``G`` (K/m), interface energy
    ``sigma`` (J/m^2), mobility (m^4/(J s)) and permeability (m^3/(J s))."""

    S: float
    G: float
    sigma: float
    mobility: float
    permeability: float


@dataclass(frozen=True)
class PhaseFieldRun:
    """Result of :func:`run`.

    Attributes
    ----------
    status : {"steady", "budget", "diverged"}
        Why the run stopped.
    history : tuple of FrontState
        The front measured after every chunk.
    steps : int
        Time steps taken.
    time : float
        Simulated time, s.
    dt : float
        Time step, s.
    wall_seconds : float
        Wall-clock time of the stepping (compilation included), s.
    fields : dict of str to ndarray
        Final ``phi``, ``xs``, ``xl`` (``(ny, nx)``) and lab heights ``y`` (``(ny,)``).
    """

    status: str
    history: tuple[outputs.FrontState, ...]
    steps: int
    time: float
    dt: float
    wall_seconds: float
    fields: dict[str, np.ndarray] = field(repr=False)


def front_noise(rng: np.random.Generator, nx: int, dx: float, noise_cell: float,
                amplitude: float) -> np.ndarray:
    """Height perturbation (m) of the ``nx`` columns: one uniform draw in
    ``[-amplitude, amplitude]`` noise cells per noise cell, held over the grid cells whose
    centres it covers.

    The number of noise cells is the whole number nearest to ``nx dx / noise_cell`` (at
    least 1), so two grids over one domain get the same front from the same seed; where
    it equals ``nx`` each grid cell has its own draw."""
    n = max(1, round(nx * dx / noise_cell))
    draws = rng.uniform(-1.0, 1.0, n)
    if n == nx:
        return amplitude * dx * draws
    cell = nx * dx / n
    owner = ((2 * np.arange(nx) + 1) * n) // (2 * nx)  # noise cell of each column centre
    return amplitude * cell * draws[owner]


def initial_fields(opts: PhaseFieldOptions, c: PhaseFieldConstants, speed: float):
    """Flat front at ``front_row`` with a seeded random height perturbation
    (:func:`front_noise`), plus a cosine of ``initial_cells`` periods.

    ``opts.start == "solidus"``: behind the front the solid has ``c0``; ahead, the liquid
    carries the steady planar (Tiller) boundary layer
    ``c0 [1 + (1 - k_e)/k_e exp(-S z / D_l)]``. ``"equilibrium"`` (the reference's set-up):
    liquid ``c0`` and solid ``k_e c0`` everywhere. The absent phase is the equilibrium
    partner. Returns ``phi, xs, xl`` of shape ``(ny, nx)`` and the front height (m).
    """
    rng = np.random.default_rng(opts.seed)
    dx, ny, nx = opts.dx, opts.ny, opts.nx
    y = (np.arange(ny) + 0.5)[:, None] * dx
    y_front = opts.front_row * ny * dx
    h = y_front + front_noise(rng, nx, dx, opts.noise_cell, opts.amplitude)
    if opts.initial_cells:
        x = (np.arange(nx) + 0.5) / nx
        h += 2.0 * opts.amplitude * opts.noise_cell * np.cos(2 * math.pi * opts.initial_cells * x)
    z = y - h[None, :]
    arg = np.clip(z / c.eta, -0.5, 0.5) * math.pi
    phi = 0.5 * (1.0 - np.sin(arg))
    if opts.start == "solidus":
        layer = (1.0 - c.k_e) / c.k_e * np.exp(-speed * np.maximum(z, 0.0) / c.D_l)
        xl = c.c0 * (1.0 + layer)
    else:
        xl = np.full_like(phi, c.c0)
    return phi, c.k_e * xl, xl, y_front


@partial(jax.jit, static_argnames=("n_steps", "dx", "c", "target", "coupling",
                                   "antitrapping"))
def advance(phi, xs, xl, t, y_off, dt, par, *, n_steps: int, dx: float,
            c: PhaseFieldConstants, target: int, coupling: str = "profile",
            antitrapping: float = 0.0):
    """``n_steps`` explicit steps, then shift the frame to hold the tip at row ``target``.

    ``par`` is ``[S, G, sigma, mobility, permeability, T_ref, y_ref]`` (SI): the frozen
    temperature is ``T = T_ref + G (y - y_ref - S t)`` with ``y = y_off + (j + 1/2) dx``.
    When the tip is above ``target``, the fields move down by the difference, the bottom
    rows leave the domain and fresh liquid (``c0``) enters at the top. Returns
    ``(phi, xs, xl, t, y_off)``.
    """
    S, G, sigma, mob, perm, T_ref, y_ref = (par[i] for i in range(7))
    ny = phi.shape[0]
    rows = jnp.arange(ny)

    def body(_, carry):
        phi, xs, xl, t = carry
        T = T_ref + G * (y_off + (rows[:, None] + 0.5) * dx - y_ref - S * t)
        phi, xs, xl = step(phi, xs, xl, T, sigma, mob, perm, dt, dx, c, coupling,
                              antitrapping)
        return phi, xs, xl, t + dt

    phi, xs, xl, t = jax.lax.fori_loop(0, n_steps, body, (phi, xs, xl, t))
    tip_row = jnp.max(jnp.where(jnp.any(phi >= 0.5, axis=1), rows, -1))
    shift = jnp.clip(tip_row - target, 0, ny // 2)
    fresh = (rows >= ny - shift)[:, None]

    def move(a, value):
        return jnp.where(fresh, value, jnp.roll(a, -shift, axis=0))

    return (move(phi, 0.0), move(xs, c.k_e * c.c0), move(xl, c.c0), t,
            y_off + shift * dx)


def diverged(xs: np.ndarray, xl: np.ndarray) -> bool:
    """Whether the concentrations are non-finite or pinned at the bounds that
    :func:`~calnet.simulators.phase_field.model.step` clips them to (1e-8 and 0.5 mole
    fraction): an unstable step shows up there, as no physical state of this alloy does."""
    lo, hi = min(xs.min(), xl.min()), max(xs.max(), xl.max())
    return not (np.isfinite(lo) and np.isfinite(hi) and lo > 1e-8 and hi < 0.5)


def regrid(fields: dict[str, np.ndarray], opts: PhaseFieldOptions
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """The final fields of another run (:attr:`PhaseFieldRun.fields`) on the grid of
    ``opts``: ``phi, xs, xl`` (``(ny, nx)``) and the frame's offset ``y_off`` (m).

    The domain must be the same (width ``nx dx`` and height ``ny dx`` within a part in
    1e9); the grid spacing may differ. Fields are interpolated linearly between cell
    centres, periodically in ``x``; the new frame starts where the old one was, and rows
    beyond the old centres (half an old cell at the bottom and top) take the nearest
    row's values. The interface keeps its physical width ``eta`` and relaxes to the new
    grid's profile within a few steps. On the same grid the fields are the state itself."""
    from scipy.interpolate import RegularGridInterpolator

    phi = np.asarray(fields["phi"], float)
    ny_o, nx_o = phi.shape
    y_o = np.asarray(fields["y"], float)
    dx_o = float(y_o[1] - y_o[0]) if ny_o > 1 else opts.dx
    for what, old, new in (("width", nx_o * dx_o, opts.nx * opts.dx),
                           ("height", ny_o * dx_o, opts.ny * opts.dx)):
        if abs(old - new) > 1e-9 * max(old, new):
            raise ValueError(f"the restart's domain {what} {old:.6g} m differs from this "
                             f"grid's {new:.6g} m; give nx, ny and dx of the same domain")
    y_off = float(y_o[0] - 0.5 * dx_o)
    if (ny_o, nx_o) == (opts.ny, opts.nx):  # the same grid: the state itself
        return (phi.copy(), np.array(fields["xs"], float), np.array(fields["xl"], float),
                y_off)
    x_o = (np.arange(nx_o) + 0.5) * dx_o
    x_pad = np.concatenate([[x_o[-1] - nx_o * dx_o], x_o, [x_o[0] + nx_o * dx_o]])
    y_n = np.clip(y_off + (np.arange(opts.ny) + 0.5) * opts.dx, y_o[0], y_o[-1])
    x_n = (np.arange(opts.nx) + 0.5) * opts.dx
    points = np.stack(np.meshgrid(y_n, x_n, indexing="ij"), axis=-1)
    out = []
    for name in ("phi", "xs", "xl"):
        a = np.asarray(fields[name], float)
        padded = np.concatenate([a[:, -1:], a, a[:, :1]], axis=1)
        out.append(RegularGridInterpolator((y_o, x_pad), padded)(points))
    return np.clip(out[0], 0.0, 1.0), out[1], out[2], y_off


def run(p: PhysicalParameters, opts: PhaseFieldOptions,
        c: PhaseFieldConstants = CONSTANTS, *, dt_scale: float = 1.0,
        progress: Callable[[float, str], None] | None = None,
        restart: PhaseFieldRun | None = None) -> PhaseFieldRun:
    """Integrate until the front is steady (:func:`~calnet.simulators.phase_field.outputs
    .steady` over the last ``opts.steady_travel`` freezing-range lengths of isotherm
    travel, after at least ``opts.min_travel``) or ``opts.max_steps`` is spent.

    The step is ``dt_scale`` times the stable explicit step of the run's parameters and
    grid (:func:`~calnet.simulators.phase_field.model.stable_time_step`), and the step
    budget ``opts.max_steps / dt_scale`` (the same simulated time). The run stops early
    with status ``"diverged"`` when :func:`diverged` says so. ``progress``, when given,
    is called after every chunk with the fraction done and a line saying where the run
    is (:meth:`calnet.progress.Lines.update` takes both). The fraction is that of the
    simulated time before the earliest steady end (``min_travel``; up to 0.95 of the
    whole, as a run may go on until its front is steady), or of the step budget where
    that is larger: a run that turns steady soon after ``min_travel`` does not end at
    a small share of a budget it never needed.

    ``restart``: go on from the final state of that run (the same parameters and domain,
    any grid spacing: :func:`regrid`), its clock and frame included; ``min_travel``
    counts from there. A grid-convergence test of an established array starts the finer
    grid from the coarser grid's state this way.
    """
    start = time.perf_counter()
    phi, xs, xl, y_front = initial_fields(opts, c, p.S)
    t0 = y_off0 = 0.0
    if restart is not None:
        phi, xs, xl, y_off0 = regrid(restart.fields, opts)
        t0 = restart.time
    # the flat front starts at the solidus (or, from equilibrium, the liquidus) of c0
    T_ref = c.T0 - (c.freezing_range if opts.start == "solidus" else 0.0)
    par = jnp.array([p.S, p.G, p.sigma, p.mobility, p.permeability, T_ref, y_front])
    target = int(round(opts.front_row * opts.ny))
    state = (jnp.asarray(phi), jnp.asarray(xs), jnp.asarray(xl), t0, y_off0)
    history: list[outputs.FrontState] = []
    travel_time = c.freezing_range / p.G / p.S  # isotherms move dT0 / G
    min_time = t0 + opts.min_travel * travel_time
    window_time = opts.steady_travel * travel_time
    steps, status = 0, "budget"
    dt = dt_scale * stable_time_step(p.sigma, p.mobility, opts.dx, c)
    max_steps = int(math.ceil(opts.max_steps / dt_scale))
    chunk = min(max(math.ceil(opts.chunk_cells * opts.dx / (p.S * dt)), 10), 4000)
    while steps < max_steps:
        n = int(min(chunk, max_steps - steps))
        state = advance(*state[:3], jnp.float64(state[3]), jnp.float64(state[4]), dt, par,
                        n_steps=n, dx=opts.dx, c=c, target=target,
                        coupling=opts.coupling, antitrapping=opts.antitrapping)
        steps += n
        phi, xs, xl = (np.asarray(a) for a in state[:3])
        t, y_off = float(state[3]), float(state[4])
        y = y_off + (np.arange(opts.ny) + 0.5) * opts.dx
        if diverged(xs, xl):
            status = "diverged"
            break
        history.append(outputs.measure(
            phi, xs, xl, y=y, t=t, dx=opts.dx, eta=c.eta, T0=c.T0,
            temperature_at=lambda yy, tt: T_ref + p.G * (yy - y_front - p.S * tt)))
        if progress is not None:  # the earliest end (min_time), else the step budget
            done = max(steps / max_steps, 0.95 * min((t - t0) / (min_time - t0), 1.0)
                       if min_time > t0 else 0.0)
            progress(done, f"{steps}/{max_steps} steps, {t * 1e6:.2f} us simulated (steady "
                     f"from {min_time * 1e6:.1f} us at the earliest), "
                     f"{history[-1].cells} cells")
        if outputs.steady(history, speed=p.S, min_time=min_time, window_time=window_time):
            status = "steady"
            break
    return PhaseFieldRun(status=status, history=tuple(history), steps=steps,
                         time=float(state[3]), dt=dt,
                         wall_seconds=time.perf_counter() - start,
                         fields={"phi": phi, "xs": xs, "xl": xl, "y": y})
