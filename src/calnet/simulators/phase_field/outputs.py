"""What a run measures: the front, its spacing, partition and undercooling; steadiness.

Pure NumPy on fields pulled from the solver between chunks (axis 0 is ``y``, the growth
direction; axis 1 is ``x``, periodic).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np

#: Solid fraction above which a cell counts as fully solid when reading ``x_s``.
_SOLID = 0.999


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
    mode : int
        Dominant Fourier mode of the front height ``h(x)`` (number of cells across the
        domain); 0 when the front is flat (amplitude below one grid cell).
    wavelength : float
        ``width / mode``, m (NaN when flat).
    amplitude : float
        Amplitude of that mode, m.
    """

    t: float
    tip: float
    undercooling: float
    k_V: float
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

    The mode is 0 (a flat front) when that amplitude is below ``dx``: a modulation
    smaller than a cell, inside an interface four cells wide, is no resolved cell array
    (at 0.3 m/s and 1e7 K/m the default-parameter front settles as a 3-4.5 nm one).
    """
    if h.size < 4:
        return 0, 0.0
    spec = np.abs(np.fft.rfft(h - h.mean())) * 2.0 / h.size
    m = int(np.argmax(spec[1:]) + 1)
    amp = float(spec[m])
    return (m, amp) if amp >= dx else (0, amp)


def measure(phi: np.ndarray, xs: np.ndarray, xl: np.ndarray, *, y: np.ndarray, t: float,
            dx: float, temperature_at, T0: float) -> FrontState:
    """Measure the front of fields ``(ny, nx)`` at time ``t``.

    ``y`` holds the lab-frame cell heights (m), ``temperature_at(y, t)`` the frozen
    temperature (K) and ``T0`` the liquidus of the alloy (K).
    """
    h = front_heights(phi, y)
    col = int(np.argmax(h))
    tip = float(h[col])
    mode, amp = dominant_mode(h, dx)
    wavelength = phi.shape[1] * dx / mode if mode else math.nan
    return FrontState(t=float(t), tip=tip, undercooling=float(T0 - temperature_at(tip, t)),
                      k_V=_tip_partition(phi[:, col], xs[:, col], xl[:, col]), mode=mode,
                      wavelength=wavelength, amplitude=amp)


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


def steady(history: Sequence[FrontState], *, window: int, min_time: float,
           rtol: float = 0.02, atol: float = 0.1) -> bool:
    """Whether the last ``window`` states show a steady front.

    Steady means: at least ``min_time`` (s) simulated; the same dominant mode throughout;
    the mean tip undercooling of the two halves of the window differing by at most
    ``tol = max(rtol * mean, atol)`` (K), so the tip keeps pace with the isotherms; its
    standard deviation over the window below ``tol``, which rejects an oscillating front
    (a flat front at S <= 0.1 m/s oscillates by several K with the default parameters,
    see benchmarks/README.md); and the mean amplitude of the dominant mode of the two
    halves within 5 % of each other, so that a growing perturbation is not taken for a
    cell array.
    """
    if len(history) < window or history[-1].t < min_time:
        return False
    last = history[-window:]
    if len({s.mode for s in last}) != 1:
        return False
    du = np.array([s.undercooling for s in last])
    first, second = du[: window // 2].mean(), du[window // 2:].mean()
    tol = max(rtol * abs(second), atol)
    amp = np.array([s.amplitude for s in last])
    a1, a2 = amp[: window // 2].mean(), amp[window // 2:].mean()
    return bool(abs(first - second) <= tol and du.std() <= tol
                and abs(a1 - a2) <= 0.05 * max(a2, 1e-12))


def summary(history: Sequence[FrontState], window: int) -> dict[str, float]:
    """Means over the last ``window`` states: wavelength and amplitude of the dominant
    mode (m), ``k_V``, undercooling (K), tip speed (m/s); and that mode."""
    last = history[-window:]
    t = np.array([s.t for s in last])
    tip = np.array([s.tip for s in last])
    speed = float(np.polyfit(t - t[0], tip, 1)[0]) if len(last) >= 2 else math.nan
    modes = [s.mode for s in last]
    mode = max(set(modes), key=modes.count)
    waves = [s.wavelength for s in last if s.mode == mode]
    return {"wavelength": float(np.mean(waves)) if mode else math.nan,
            "k_V": float(np.mean([s.k_V for s in last])),
            "undercooling": float(np.mean([s.undercooling for s in last])),
            "amplitude": float(np.mean([s.amplitude for s in last])),
            "tip_speed": speed, "mode": int(mode)}
