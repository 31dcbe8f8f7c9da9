"""Nonuniform tensor-product mesh, fine around the pool and stretched outside.

The pool region is sized from a quick Rosenthal estimate (:func:`estimate_pool`), or
from a previous solution when the mesh is adapted. Domain (physics.md, M1): inflow face
1.5 mm ahead of the beam, outflow 3.5 mm behind, half width 1.5 mm (``y >= 0``), depth
powder layer + 1 mm substrate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from calnet.simulators.materials import AlloyProperties

X_AHEAD, X_BEHIND, Y_SIDE = 1.5e-3, 3.5e-3, 1.5e-3
CELLS_PER_HALF_WIDTH = 7.0  # pool-region spacing h = min(W/2, D) / 7 at resolution 1
# The lateral pool edge in the powder layer (liquid next to 1 W/(m K) powder) needs a
# finer y spacing than x and z: with h_y = h, W changed by 6-8 % when halving h.
Y_REFINE = 2.0
H_EDGE = 2.5e-6  # m, largest lateral spacing at the pool edge (resolution 1)
# Far-field geometric growth ratio at resolution 1. 1.4 against 1.25: 20-44 % fewer
# cells, W and D within 1.3 % at 4 of the 5 benchmark settings, W at 243 W / 1.15 m/s
# 6.5 % apart (benchmarks/README.md, M1).
STRETCH = 1.4
H_MIN, H_MAX = 2.5e-6, 12e-6  # bounds on the pool-region spacing (resolution 1)
POWDER_DEPTH_FLOOR = 30e-6  # m: pools shallower than the powder layer are sized by it
# Fewest cell layers across the powder layer (times the resolution). The widest pools'
# lateral edge lies in the powder, and W there follows the layers' thickness: with 3
# layers (h = 10 um) W at 236 W / 0.23 m/s is 12 % above the halved mesh's, with 6 within
# 1 %. With 12 layers on the default mesh (6 on the sizing mesh) the run at 152 W /
# 0.32 m/s does not converge.
POWDER_LAYERS = 6
# ``refine=True`` (the simulator's ``refine_outputs``): finer where the outputs are read
REFINED_H_EDGE = 1.25e-6  # m, lateral spacing at the pool edge (W)
REFINED_X = 2.0  # the pool region's x spacing is h / REFINED_X (the tail window of G0)


@dataclass(frozen=True)
class PoolBox:
    """Extent of the region meshed finely (m): ``x`` in ``[-tail, front]``, ``y`` in
    ``[0, half_width]``, ``z`` in ``[0, depth]``, and the spacing ``h`` there."""

    tail: float
    front: float
    half_width: float
    depth: float
    h: float
    edge: float  # expected lateral pool edge W/2 (m), centre of the finer edge band


@dataclass(frozen=True)
class Mesh:
    """Cell faces along each axis (m); ``z`` points down from the powder top."""

    xf: np.ndarray
    yf: np.ndarray
    zf: np.ndarray
    n_powder: int  # number of cell layers in the powder layer

    @property
    def shape(self) -> tuple[int, int, int]:
        return (self.xf.size - 1, self.yf.size - 1, self.zf.size - 1)

    @property
    def size(self) -> int:
        nx, ny, nz = self.shape
        return nx * ny * nz

    @staticmethod
    def centres(f: np.ndarray) -> np.ndarray:
        return 0.5 * (f[1:] + f[:-1])


def estimate_pool(P: float, v: float, absorb: float, k: float, mat: AlloyProperties
                  ) -> tuple[float, float, float]:
    """Rosenthal point-source estimate of the liquidus pool: ``(tail, front, half_width)``.

    ``T - T_inf = A P / (2 pi k R) exp(-v (R + x) / (2 alpha))`` (Rosenthal 1946).
    """
    alpha = k / (mat.rho * mat.cp_solid)
    q = absorb * P / (2 * math.pi * k * (mat.T_liquidus - mat.T_ambient))
    tail = q  # R at x = -R
    lo, hi = 0.0, tail
    for _ in range(60):  # front: q/R exp(-v R / alpha) = 1
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if q / mid * math.exp(-v * mid / alpha) > 1 else (lo, mid)
    front = lo
    x = np.linspace(-tail, front, 400)
    R = np.maximum(np.abs(x), 1e-12)
    lo_r, hi_r = R.copy(), np.full_like(R, tail)
    for _ in range(60):  # largest R >= |x| on the isotherm, per x
        mid = 0.5 * (lo_r + hi_r)
        inside = np.log(q / mid) - v * (mid + x) / (2 * alpha) > 0
        lo_r, hi_r = np.where(inside, mid, lo_r), np.where(inside, hi_r, mid)
    half_width = float(np.sqrt(np.maximum(lo_r**2 - x**2, 0.0)).max())
    return tail, front, half_width


def pool_spacing(half_width: float, depth: float) -> float:
    """Pool-region spacing (m) of the resolution-1 mesh for a pool of this size."""
    h = min(half_width, max(depth, POWDER_DEPTH_FLOOR)) / CELLS_PER_HALF_WIDTH
    return min(max(h, H_MIN), H_MAX)


def pool_box(tail: float, front: float, half_width: float, depth: float, *,
             resolution: float, beam_radius: float) -> PoolBox:
    """Fine region around a pool of the given size, with margins."""
    h = pool_spacing(half_width, depth) / resolution
    return PoolBox(tail=1.15 * tail + 3 * h, front=max(front, beam_radius) + 3 * h,
                   half_width=1.15 * half_width + 3 * h, depth=1.15 * depth + 3 * h, h=h,
                   edge=half_width)


def _stretched(length: float, h0: float, ratio: float) -> np.ndarray:
    """Spacings growing geometrically from about ``h0`` that sum exactly to ``length``."""
    n = max(1, math.ceil(math.log(1 + length * (ratio - 1) / h0) / math.log(ratio)))
    d = h0 * ratio ** np.arange(1, n + 1)
    return d * (length / d.sum())


def _axis(lo_len: float, fine_lo: float, fine_hi: float, hi_len: float, h: float,
          ratio: float) -> np.ndarray:
    """Faces on ``[-lo_len, hi_len]`` uniform (spacing ~h) on ``[-fine_lo, fine_hi]``."""
    n = max(1, math.ceil((fine_lo + fine_hi) / h))
    core = np.linspace(-fine_lo, fine_hi, n + 1)
    hh = (fine_lo + fine_hi) / n
    parts = [core]
    if hi_len > fine_hi:
        parts.append(fine_hi + np.cumsum(_stretched(hi_len - fine_hi, hh, ratio)))
    if lo_len > fine_lo:
        parts.insert(0, (-fine_lo - np.cumsum(_stretched(lo_len - fine_lo, hh, ratio)))[::-1])
    return np.concatenate(parts)


def _lateral_axis(box: PoolBox, resolution: float, ratio: float, h_edge: float = H_EDGE
                  ) -> np.ndarray:
    """``y`` faces: spacing ``h`` inside the pool, a band of ``h_e`` around its edge
    (``0.75 W/2`` to ``1.15 W/2 + 3 h_e``), geometric transitions, stretched outside.

    ``h_e = min(h / 2, H_EDGE / resolution)``: where liquid meets loose powder
    (k_p ~ 1 W/(m K)) the lateral edge needs a spacing of a few um whatever the pool
    size (W changed by 6 % when halving a 6 um lateral spacing at 152 W, 0.32 m/s).
    """
    h = box.h
    h_e = min(h / Y_REFINE, h_edge / resolution)
    hi = min(1.15 * box.edge + 3 * h_e, 0.8 * Y_SIDE)
    lo = max(min(0.75 * box.edge, hi - 3 * h_e), 0.0)
    n_band = max(3, math.ceil((hi - lo) / h_e))
    band = np.linspace(hi - n_band * h_e, hi, n_band + 1)
    inner, d = [band[0]], h_e
    while inner[-1] > 0:  # grow inwards from h_e to h
        d = min(d * 1.3, h)
        inner.append(inner[-1] - d)
    inner = np.array(inner[::-1])
    inner = (inner - inner[0]) * (band[0] / (band[0] - inner[0]))  # start exactly at 0
    outer = hi + np.cumsum(_stretched(Y_SIDE - hi, h_e, ratio))
    return np.concatenate([inner[:-1], band, outer])


def build_mesh(box: PoolBox, mat: AlloyProperties, *, resolution: float,
               powder: bool, refine: bool = False) -> Mesh:
    """Tensor mesh for ``box``; the powder/substrate interface is a face, and at least
    ``POWDER_LAYERS * resolution`` cell layers cross the powder layer.

    ``refine``: the lateral spacing at the pool edge ``REFINED_H_EDGE / resolution``
    instead of ``H_EDGE / resolution`` and the pool region's ``x`` spacing ``h /
    REFINED_X`` (benchmarks/README.md, "Mesh convergence").
    """
    ratio = STRETCH ** (1.0 / resolution)
    h = box.h
    tail = min(box.tail, 0.8 * X_BEHIND)
    front = min(box.front, 0.8 * X_AHEAD)
    xf = _axis(X_BEHIND, tail, front, X_AHEAD, h / REFINED_X if refine else h, ratio)
    yf = _lateral_axis(box, resolution, ratio, REFINED_H_EDGE if refine else H_EDGE)
    t_p = mat.powder_thickness if powder else 0.0
    n_p = max(math.ceil(t_p / h), math.ceil(POWDER_LAYERS * resolution)) if powder else 0
    zp = np.linspace(0.0, t_p, n_p + 1) if powder else np.zeros(1)
    fine_sub = min(max(box.depth - t_p, h), 0.8 * mat.substrate_thickness)
    zs = _axis(0.0, 0.0, fine_sub, mat.substrate_thickness, h, ratio)
    zf = np.concatenate([zp, t_p + zs[1:]])
    return Mesh(xf=xf, yf=yf, zf=zf, n_powder=n_p)
