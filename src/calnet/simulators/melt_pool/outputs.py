"""Melt-pool outputs on the liquidus isotherm (physics.md, M1 "Outputs").

The surface field is reconstructed from the two top cell layers by extrapolating the
vertical Kirchhoff potential ``Phi_z`` (linear in z); the symmetry plane ``y = 0`` by
an even (quadratic in y) extrapolation. Isotherm positions are interpolated linearly
between cell centres, and maxima over ``x`` are refined with a parabola through the
three best columns, so outputs vary smoothly with the mesh.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calnet.simulators.melt_pool.assembly import surface_weights
from calnet.simulators.melt_pool.mesh import Mesh, pool_spacing
from calnet.simulators.melt_pool.properties import MaterialLaws


@dataclass(frozen=True)
class PoolGeometry:
    """Outputs (SI units) and the pool extent used for mesh adaptation."""

    D: float
    W: float
    L: float
    T0: float
    S0: float
    G0: float
    x_tail: float
    x_front: float


def surface_field(T3: np.ndarray, mesh: Mesh, laws: MaterialLaws) -> np.ndarray:
    """Reconstructed surface temperature, shape ``(nx, ny)`` (K).

    Linear extrapolation of ``Phi_z`` from the two top layers, or of ``T`` where that
    stays closer to the top cell: across the vapour switch ``k_z`` rises 100-fold
    between the two layers and a ``Phi_z`` extrapolation would overshoot by ~400 K.
    """
    zc = Mesh.centres(mesh.zf)
    w = surface_weights(zc[0], zc[1], even=False)
    top, second = T3[:, :, 0], T3[:, :, 1]
    by_phi = laws.phi_z.inverse(w[0] * laws.phi_z(top)[0] + w[1] * laws.phi_z(second)[0])
    by_t = w[0] * top + w[1] * second
    return np.where(np.abs(by_phi - top) <= np.abs(by_t - top), by_phi, by_t)


def _symmetry_plane(F: np.ndarray, yc: np.ndarray) -> np.ndarray:
    """Values at ``y = 0`` from the first two ``y`` columns (axis 1), even extrapolation."""
    w = surface_weights(yc[0], yc[1], even=True)
    return w[0] * F[:, 0] + w[1] * F[:, 1]


def _outer_crossing(F: np.ndarray, s: np.ndarray, level: float) -> np.ndarray:
    """Per row of ``F`` (rows, n), the largest ``s`` where ``F`` crosses ``level``.

    Rows entirely below ``level`` give NaN; rows above it up to the end give ``s[-1]``.
    """
    above = F >= level
    last = np.where(above.any(axis=1), F.shape[1] - 1 - np.argmax(above[:, ::-1], axis=1), -1)
    out = np.full(F.shape[0], np.nan)
    ok = (last >= 0) & (last < F.shape[1] - 1)
    r = np.flatnonzero(ok)
    a, b = F[r, last[r]], F[r, last[r] + 1]
    out[r] = s[last[r]] + (a - level) / (a - b) * (s[last[r] + 1] - s[last[r]])
    out[(last == F.shape[1] - 1)] = s[-1]
    return out


def _refined_max(x: np.ndarray, y: np.ndarray) -> float:
    """Maximum of samples ``y(x)`` refined by a parabola through the best three."""
    if not np.isfinite(y).any():
        return float("nan")
    i = int(np.nanargmax(y))
    if i == 0 or i == y.size - 1 or not np.isfinite(y[i - 1 : i + 2]).all():
        return float(y[i])
    c = np.polyfit(x[i - 1 : i + 2] - x[i], y[i - 1 : i + 2], 2)
    if c[0] >= 0:
        return float(y[i])
    return float(min(c[2] - c[1] ** 2 / (4 * c[0]), y[i] + abs(y[i] - y[i - 1])))


def _blended_k(table_d, table_p, T: np.ndarray, frac: np.ndarray) -> np.ndarray:
    """Conductivity of cells with consolidated fraction ``frac`` (log blend)."""
    kd, kp = table_d(T)[1], table_p(T)[1]
    return np.exp(frac * np.log(kd) + (1 - frac) * np.log(kp))


def _with_faces(F: np.ndarray, k: np.ndarray, s: np.ndarray, faces: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
    """Interleave cell values with flux-continuous face values along the last axis.

    ``T_f = (k_a T_a / d_a + k_b T_b / d_b) / (k_a / d_a + k_b / d_b)`` (``d`` centre-face
    distances): the temperature that makes the two half-cell fluxes equal. At the edge
    of the pool, where liquid (high k) meets loose powder (k ~ 1 W/(m K)), ``T_f`` sits
    near the liquid value, so the isotherm is found in the powder half cell rather than
    halfway between the centres (an O(h) bias that made W grow under refinement).
    """
    da, db = faces[1:-1] - s[:-1], s[1:] - faces[1:-1]
    wa, wb = k[..., :-1] / da, k[..., 1:] / db
    Tf = (wa * F[..., :-1] + wb * F[..., 1:]) / (wa + wb)
    V = np.empty(F.shape[:-1] + (2 * F.shape[-1] - 1,))
    V[..., 0::2], V[..., 1::2] = F, Tf
    S = np.empty(2 * s.size - 1)
    S[0::2], S[1::2] = s, faces[1:-1]
    return V, S


def _crossing_1d(x: np.ndarray, f: np.ndarray, level: float) -> tuple[float, float]:
    """Outermost ``x`` positions (low, high) where ``f(x) = level`` (NaN if none)."""
    hot = np.flatnonzero(f >= level)
    if hot.size == 0 or hot[0] == 0 or hot[-1] == f.size - 1:
        return float("nan"), float("nan")
    i, j = hot[0], hot[-1]
    lo = x[i - 1] + (level - f[i - 1]) / (f[i] - f[i - 1]) * (x[i] - x[i - 1])
    hi = x[j] + (f[j] - level) / (f[j] - f[j + 1]) * (x[j + 1] - x[j])
    return float(lo), float(hi)


def tail_gradient(s: np.ndarray, profile: np.ndarray, x_tail: float, half_width: float,
                  surface_flux: float, k_z: float) -> tuple[float, float]:
    """``(dT/dx, dT/dz)`` at the surface tail point ``(x_tail, 0, 0)``.

    ``dT/dx``: slope of the least-squares line through the surface centreline
    temperature ``profile(s)`` (interpolated linearly, sampled uniformly) over
    ``x_tail +- half_width``. The tail is a kink: steep on the solid side, which
    conducts the latent heat away, almost flat on the Marangoni-stirred liquid side,
    so a fit through the cell centres in the window weighs the two sides by where the
    cells happen to fall (G0 changed by up to 26 % when halving the spacing, with a
    window of 3 cells). Fitting the interpolated profile over a window fixed in metres
    (see :func:`extract`) removes that sampling noise.
    ``dT/dz`` from the boundary condition, ``k_z dT/dz = q_loss`` (W/m^2; the beam
    contributes nothing this far behind it). ``dT/dy = 0`` by symmetry.
    """
    u = np.linspace(-half_width, half_width, 401)
    T = np.interp(x_tail + u, s, profile)
    gx = float(u @ (T - T.mean()) / (u @ u))
    return gx, surface_flux / k_z


def extract(T: np.ndarray, frac: np.ndarray, mesh: Mesh, laws: MaterialLaws, *, v: float,
            T_liquidus: float, g_window_cells: float, tail_flux: float) -> PoolGeometry:
    """Pool outputs from the cell temperatures ``T`` and consolidated fractions ``frac``
    (both (n_cells,)); isotherms are located on flux-continuous profiles.

    The ``G0`` window half-width is ``g_window_cells`` pool spacings of the
    resolution-1 mesh for a pool of the computed ``W`` and ``D``
    (:func:`~.mesh.pool_spacing`): fixed in metres for a given pool, whatever the
    mesh it was computed on.
    """
    T3, f3 = T.reshape(mesh.shape), frac.reshape(mesh.shape)
    xc, yc, zc = (Mesh.centres(a) for a in (mesh.xf, mesh.yf, mesh.zf))
    Ts = surface_field(T3, mesh, laws)
    k_top = _blended_k(laws.phi_x, laws.powder_x, Ts, f3[:, :, 0])
    y_l = _outer_crossing(*_with_faces(Ts, k_top, yc, mesh.yf), T_liquidus)
    W = 2 * _refined_max(xc, y_l)
    col = _symmetry_plane(T3, yc)
    k_col = _blended_k(laws.phi_z, laws.powder_z, col, f3[:, 0, :])
    z_l = _outer_crossing(*_with_faces(col, k_col, zc, mesh.zf), T_liquidus)
    D = _refined_max(xc, z_l)
    line = _symmetry_plane(Ts, yc)
    k_line = _blended_k(laws.phi_x, laws.powder_x, line, f3[:, 0, 0])
    V, S = _with_faces(line, k_line, xc, mesh.xf)
    x_tail, x_front = _crossing_1d(S, V, T_liquidus)
    sized = np.isfinite([x_tail, W, D]).all()
    gx, gz = ((np.nan, np.nan) if not sized
              else tail_gradient(S, V, x_tail, g_window_cells * pool_spacing(0.5 * W, D),
                                 tail_flux, float(laws.phi_z(np.array([T_liquidus]))[1][0])))
    G0 = float(np.hypot(gx, gz))
    S0 = float(v * abs(gx) / G0) if G0 > 0 else float("nan")
    T0 = float(np.max(line))
    return PoolGeometry(D=D, W=W, L=x_front - x_tail, T0=T0, S0=S0, G0=G0,
                        x_tail=x_tail, x_front=x_front)
