"""What a run measures: the front, its spacing, partition and undercooling; steadiness.

Pure NumPy on fields pulled from the solver between chunks (axis 0 is ``y``, the growth
direction; axis 1 is ``x``, periodic).

The spacing counts cells: behind the leading tips the cells of the double-obstacle model
are fully solid (``phi = 1`` exactly) and the liquid grooves between them are not, so the
number of runs of not-fully-solid cells along a row is the number of cells across the
periodic domain. :func:`cell_count` takes that count on every row of a band from
:data:`BAND` ``= (4, 8)`` interface widths (80-160 nm at ``eta = 20 nm``, 16-32 cells at
5 nm) behind the highest tip and keeps the median. The band lies below tips that lag the
leading one by up to ``4 eta`` (35 nm at 0.3 m/s and 1e7 K/m, up to 90 nm at 0.05 m/s,
where after 33 us a band 2-6 eta behind counts 4 cells and this one 9), and above the
depth at which grooves pinch off into liquid droplets (rows 240 nm behind the tips at
0.3 m/s count 1-5 droplets more). The spacing is the domain width over that count. The
dominant Fourier mode of the front height ``h(x)`` (:func:`dominant_mode`) is kept as a
diagnostic: it sees only the tips, and on a fine array it measures a modulation of their
heights rather than the number of cells.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np

#: Solid fraction above which a cell counts as fully solid (reading ``x_s``, counting
#: grooves).
_SOLID = 0.999

#: Rows on which cells are counted: from ``BAND[0]`` to ``BAND[1]`` interface widths
#: behind the highest tip.
BAND = (4.0, 8.0)


@dataclass(frozen=True)
class FrontState:
    """The front at one instant.

    Attributes
    ----------
    t : float
        Simulated time, s.
    tip : float
        Height of the highest point of the ``phi = 1/2`` contour, lab frame, m.
    undercooling : float
        ``T0 - T(tip)``: the tip's temperature below the liquidus of ``c0``, K.
    k_V : float
        Partition at the tip: ``x_s`` of the solid just formed behind the tip divided by
        the liquid-phase concentration ``x_l`` at the tip's ``phi = 1/2`` crossing.
    cells : int
        Cells across the domain (:func:`cell_count`); 0 for a flat front.
    spacing : float
        ``width / cells``, m (NaN when flat).
    mode : int
        Dominant Fourier mode of the front height ``h(x)`` (a diagnostic of the tip
        heights, :func:`dominant_mode`); 0 when its amplitude is below one grid cell.
    wavelength : float
        ``width / mode``, m (NaN when ``mode`` is 0).
    amplitude : float
        Amplitude of that mode, m.
    """

    t: float
    tip: float
    undercooling: float
    k_V: float
    cells: int
    spacing: float
    mode: int
    wavelength: float
    amplitude: float

    def to_dict(self) -> dict[str, float]:
        return asdict(self)


def front_heights(phi: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Height of the highest ``phi = 1/2`` crossing in each column, shape ``(nx,)``, m.

    ``phi`` has shape ``(ny, nx)``, ``y`` the cell-centre heights ``(ny,)``; linear
    interpolation between the last cell with ``phi >= 1/2`` and the one above it. A
    column with no solid gets ``y[0]``.
    """
    ny = phi.shape[0]
    solid = phi >= 0.5
    top = np.where(solid.any(axis=0), ny - 1 - np.argmax(solid[::-1], axis=0), 0)
    above = np.minimum(top + 1, ny - 1)
    cols = np.arange(phi.shape[1])
    p0, p1 = phi[top, cols], phi[above, cols]
    frac = np.where(p0 > p1, (p0 - 0.5) / np.maximum(p0 - p1, 1e-12), 0.0)
    dy = y[1] - y[0]
    return y[top] + np.clip(frac, 0.0, 1.0) * dy


def dominant_mode(h: np.ndarray, dx: float) -> tuple[int, float]:
    """``(mode, amplitude)`` of the largest non-constant Fourier mode of ``h`` (m).

    The mode is 0 when that amplitude is below ``dx``: a modulation smaller than a cell,
    inside an interface four cells wide, is not resolved.
    """
    if h.size < 4:
        return 0, 0.0
    spec = np.abs(np.fft.rfft(h - h.mean())) * 2.0 / h.size
    m = int(np.argmax(spec[1:]) + 1)
    amp = float(spec[m])
    return (m, amp) if amp >= dx else (0, amp)


def grooves(row: np.ndarray) -> int | None:
    """Number of runs of not-fully-solid cells (``phi < 0.999``) along a periodic row.

    Returns 0 for a fully solid row and None for a row with no fully solid cell (it lies
    above some cell tips, or in the liquid, and cannot separate the cells).
    """
    open_ = np.asarray(row) < _SOLID
    if open_.all():
        return None
    return int(np.sum(open_ & ~np.roll(open_, 1)))


def cell_count(phi: np.ndarray, y: np.ndarray, tip: float, eta: float,
               band: tuple[float, float] = BAND) -> int:
    """Cells across the domain: the median of :func:`grooves` over the rows ``band[0]`` to
    ``band[1]`` interface widths ``eta`` (m) behind the height ``tip`` (m).

    ``phi`` has shape ``(ny, nx)`` and ``y`` the cell-centre heights ``(ny,)``, m. Rows
    outside the grid and rows without a fully solid cell are skipped; 0 when no row
    remains or the rows are fully solid (a flat front). The lower median is taken, so the
    count is one that a row actually showed.
    """
    rows = np.nonzero((y <= tip - band[0] * eta) & (y >= tip - band[1] * eta))[0]
    counts = sorted(c for c in (grooves(phi[j]) for j in rows) if c is not None)
    return int(counts[(len(counts) - 1) // 2]) if counts else 0


def measure(phi: np.ndarray, xs: np.ndarray, xl: np.ndarray, *, y: np.ndarray, t: float,
            dx: float, eta: float, temperature_at, T0: float) -> FrontState:
    """Measure the front of fields ``(ny, nx)`` at time ``t``.

    ``y`` holds the lab-frame cell heights (m), ``dx`` the grid spacing and ``eta`` the
    interface width (m), ``temperature_at(y, t)`` the frozen temperature (K) and ``T0``
    the liquidus of the alloy (K).
    """
    width = phi.shape[1] * dx
    h = front_heights(phi, y)
    col = int(np.argmax(h))
    tip = float(h[col])
    mode, amp = dominant_mode(h, dx)
    cells = cell_count(phi, y, tip, eta)
    return FrontState(t=float(t), tip=tip, undercooling=float(T0 - temperature_at(tip, t)),
                      k_V=_tip_partition(phi[:, col], xs[:, col], xl[:, col]), cells=cells,
                      spacing=width / cells if cells else math.nan, mode=mode,
                      wavelength=width / mode if mode else math.nan, amplitude=amp)


def _tip_partition(phi: np.ndarray, xs: np.ndarray, xl: np.ndarray) -> float:
    """``x_s`` of the just-solid cell below the tip over ``x_l`` at the tip's ``phi = 1/2``
    crossing (linear interpolation, as in :func:`front_heights`): the liquid-phase
    concentration where the sharp interface sits. NaN without solid or a crossing."""
    solid = np.nonzero(phi >= _SOLID)[0]
    half = np.nonzero(phi >= 0.5)[0]
    if solid.size == 0 or half[-1] + 1 >= phi.size:
        return math.nan
    top = int(half[-1])
    frac = (phi[top] - 0.5) / max(phi[top] - phi[top + 1], 1e-12)
    xl_half = xl[top] + min(max(frac, 0.0), 1.0) * (xl[top + 1] - xl[top])
    return float(xs[int(solid[-1])] / xl_half)


def steady(history: Sequence[FrontState], *, speed: float, min_time: float,
           window_time: float, rtol: float = 0.02, atol: float = 0.1,
           cells_rtol: float = 0.05) -> bool:
    """Whether the front has been steady over the last ``window_time`` (s).

    The window is every state with ``t >= t_last - window_time``; it must reach back at
    least that far (an earlier state exists) and the run must have lasted ``min_time``
    (s). Steady means, over the window:

    - the mean cell count (:func:`cell_count`) of its two halves differing by at most
      ``cells_rtol`` of the larger, and the front not flat in one half and cellular in
      the other: no coarsening or refinement while the isotherms moved
      ``speed * window_time``. The mean, not every count, because a cell array of this
      model keeps splitting tips and eliminating cells (the interface energy is
      isotropic): at 0.3 m/s and 1e7 K/m with the middle-of-bounds parameters the count
      of a statistically steady array moves between 23 and 27 from chunk to chunk;
    - the tip speed (least-squares slope of the tip height) within ``rtol`` of ``speed``
      (m/s);
    - the mean tip undercooling of the two halves differing by at most
      ``tol = max(rtol * mean, atol)`` (K), and its standard deviation below ``tol``,
      which rejects an oscillating front (a flat front at S <= 0.1 m/s oscillates by
      several K with the default parameters, see benchmarks/README.md).
    """
    if not history or history[-1].t < min_time:
        return False
    t_end = history[-1].t
    start = next(i for i, s in enumerate(history) if s.t >= t_end - window_time)
    last = history[start:]
    if start == 0 or len(last) < 4:
        return False
    half = len(last) // 2
    cells = np.array([s.cells for s in last], dtype=float)
    c1, c2 = cells[:half].mean(), cells[half:].mean()
    if abs(c1 - c2) > cells_rtol * max(c1, c2) or (c1 == 0) != (c2 == 0):
        return False
    t = np.array([s.t for s in last])
    tip_speed = float(np.polyfit(t - t[0], [s.tip for s in last], 1)[0])
    du = np.array([s.undercooling for s in last])
    first, second = du[:half].mean(), du[half:].mean()
    tol = max(rtol * abs(second), atol)
    return bool(abs(tip_speed - speed) <= rtol * speed and abs(first - second) <= tol
                and du.std() <= tol)


def summary(history: Sequence[FrontState], window: int) -> dict[str, float]:
    """Means over the last ``window`` states: cell count (0 when any state was flat),
    spacing (m, the domain width over that mean count), ``k_V``, undercooling (K), tip
    speed (m/s), tip-height amplitude and wavelength (m); and the most frequent
    tip-height mode."""
    last = history[-window:]
    t = np.array([s.t for s in last])
    tip = np.array([s.tip for s in last])
    speed = float(np.polyfit(t - t[0], tip, 1)[0]) if len(last) >= 2 else math.nan
    counts = [s.cells for s in last]
    cells = float(np.mean(counts)) if min(counts) > 0 else 0.0
    width = next((s.spacing * s.cells for s in last if s.cells), math.nan)
    modes = [s.mode for s in last]
    mode = max(set(modes), key=modes.count)
    waves = [s.wavelength for s in last if s.mode == mode]
    return {"spacing": width / cells if cells else math.nan, "cells": cells,
            "k_V": float(np.mean([s.k_V for s in last])),
            "undercooling": float(np.mean([s.undercooling for s in last])),
            "amplitude": float(np.mean([s.amplitude for s in last])),
            "wavelength": float(np.mean(waves)) if mode else math.nan,
            "tip_speed": speed, "mode": int(mode)}
