"""Finite-volume residual and exact Newton Jacobian of the steady melt-pool equation.

Cell energy balance (W), positive for net inflow (physics.md, M1)::

    R_P = sum_f G_f (Phi_d(T_nb) - Phi_d(T_P))          conduction, Kirchhoff form
        + v A_yz (rho_E H(T_E) - rho_P H(T_P))            upwind advection, flow to -x
        + A(T_s) Q_P - A_top (eps sigma (T^4 - T_inf^4) + h (T - T_inf))

so ``dR/dT = L diag(k(T)) + advection + boundary terms + a rank-one absorptivity term``.
Never-melted powder cells use their own law (``k_p`` below ``T_S``, liquid above); a
face between a powder cell and a dense cell uses the series conductance of the two half
cells, each with its own ``k(T)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.special import erf

from calnet.simulators.materials import STEFAN_BOLTZMANN
from calnet.simulators.melt_pool.mesh import Mesh
from calnet.simulators.melt_pool.properties import MaterialLaws


@dataclass(frozen=True)
class Faces:
    """Interior (``nb >= 0``) or Dirichlet (``nb == -1``) faces of one direction."""

    P: np.ndarray
    nb: np.ndarray
    G: np.ndarray  # area / centre distance (m)
    hP: np.ndarray  # half widths (m)
    hN: np.ndarray
    vertical: bool


def _index(shape: tuple[int, int, int]) -> np.ndarray:
    return np.arange(np.prod(shape)).reshape(shape)


def _faces(mesh: Mesh, axis: int, dirichlet_high: bool) -> list[Faces]:
    idx = _index(mesh.shape)
    f = (mesh.xf, mesh.yf, mesh.zf)
    d = [np.diff(a) for a in f]
    dc = np.diff(Mesh.centres(f[axis]))
    other = [a for a in range(3) if a != axis]
    area = np.multiply.outer(d[other[0]], d[other[1]])  # (n_o0, n_o1)

    def take(a: np.ndarray, sl: slice) -> np.ndarray:
        return np.take(a, np.arange(a.shape[axis])[sl], axis=axis)

    def bcast(v: np.ndarray, n: int) -> np.ndarray:
        shape = [1, 1, 1]
        shape[axis] = n
        return np.broadcast_to(v.reshape(shape), idx[tuple(
            slice(0, n) if a == axis else slice(None) for a in range(3))].shape)

    def area_b(n: int) -> np.ndarray:
        return np.broadcast_to(np.expand_dims(area, axis), bcast(np.zeros(n), n).shape)

    n = mesh.shape[axis]
    out = [Faces(P=take(idx, slice(0, -1)).ravel(), nb=take(idx, slice(1, None)).ravel(),
                 G=(area_b(n - 1) / bcast(dc, n - 1)).ravel(),
                 hP=bcast(0.5 * d[axis][:-1], n - 1).ravel(),
                 hN=bcast(0.5 * d[axis][1:], n - 1).ravel(), vertical=axis == 2)]
    if dirichlet_high:
        P = take(idx, slice(n - 1, n)).ravel()
        h = 0.5 * d[axis][-1]
        out.append(Faces(P=P, nb=np.full(P.size, -1), G=area.ravel() / h,
                         hP=np.full(P.size, h), hN=np.zeros(P.size), vertical=axis == 2))
    return out


class Discretization:
    """Precomputed geometry of one mesh; :meth:`evaluate` gives ``R`` and ``dR/dT``."""

    def __init__(self, mesh: Mesh, mat: AlloyProperties, P: float, v: float) -> None:
        self.mesh, self.mat, self.P, self.v = mesh, mat, P, v
        nx, ny, nz = mesh.shape
        self.n = mesh.size
        self.faces = [*_faces(mesh, 0, True), *_faces(mesh, 1, True), *_faces(mesh, 2, True)]
        dx, dy, dz = (np.diff(a) for a in (mesh.xf, mesh.yf, mesh.zf))
        self.volume = np.multiply.outer(np.multiply.outer(dx, dy), dz).ravel()
        idx = _index(mesh.shape)
        self.powder_cells = np.zeros(mesh.shape, bool)
        self.powder_cells[:, :, : mesh.n_powder] = True
        self.area_yz = np.broadcast_to(np.multiply.outer(dy, dz), mesh.shape).ravel()
        self.x_up = (idx[:-1], idx[1:])  # (downstream P, upstream E) pairs
        self.outflow = idx[0].ravel()
        self.top = idx[:, :, 0].ravel()
        self.area_top = np.multiply.outer(dx, dy).ravel()
        r0 = mat.beam_radius
        ex = np.diff(erf(np.sqrt(2) * mesh.xf / r0))
        ey = np.diff(erf(np.sqrt(2) * mesh.yf / r0))
        self.q_top = 0.25 * P * np.multiply.outer(ex, ey).ravel()  # W per face at A = 1
        self.beam = np.flatnonzero(self.q_top > 1e-12 * self.q_top.max())
        self.ts_cells, self.ts_weights = self._surface_stencil()

    def _surface_stencil(self) -> tuple[np.ndarray, np.ndarray]:
        """Cells and weights reconstructing ``Phi_z`` at the surface at ``x = y = 0``."""
        xc, yc, zc = (Mesh.centres(a) for a in (self.mesh.xf, self.mesh.yf, self.mesh.zf))
        i = int(np.clip(np.searchsorted(xc, 0.0) - 1, 0, xc.size - 2))
        wx = np.array([xc[i + 1], -xc[i]]) / (xc[i + 1] - xc[i])
        wy = surface_weights(yc[0], yc[1], even=True)
        wz = surface_weights(zc[0], zc[1], even=False)
        idx = _index(self.mesh.shape)
        cells, weights = [], []
        for a, wa in zip((i, i + 1), wx, strict=True):
            for b, wb in zip((0, 1), wy, strict=True):
                for c, wc in zip((0, 1), wz, strict=True):
                    cells.append(idx[a, b, c])
                    weights.append(wa * wb * wc)
        return np.array(cells), np.array(weights)

    def consolidated(self, T: np.ndarray) -> np.ndarray:
        """True for dense cells and for powder melted at or upstream of the cell.

        A powder column counts as melted once any of its cells reached ``T_S`` (the
        30 um layer, about one particle diameter, collapses as a whole), and stays
        consolidated downstream: the max over ``x' >= x`` of physics.md, taken over
        the whole layer thickness.
        """
        T3 = T.reshape(self.mesh.shape)[:, :, : self.mesh.n_powder]
        melted = T3.max(axis=2, initial=-np.inf) >= self.mat.T_solidus
        melted = np.maximum.accumulate(melted[::-1], axis=0)[::-1]
        out = ~self.powder_cells
        out[:, :, : self.mesh.n_powder] |= melted[:, :, None]
        return out.ravel()

    def surface_temperature(self, T: np.ndarray, laws: MaterialLaws
                            ) -> tuple[float, np.ndarray]:
        """Reconstructed ``T_s`` at the beam centre and ``dT_s/dT`` on its stencil."""
        phi, k = laws.phi_z(T[self.ts_cells])
        ts = float(laws.phi_z.inverse(np.array([self.ts_weights @ phi]))[0])
        _, k_s = laws.phi_z(np.array([ts]))
        return ts, self.ts_weights * k / k_s[0]

    def evaluate(self, T: np.ndarray, dense: np.ndarray, laws: MaterialLaws,
                 absorb: float, dabsorb: np.ndarray | None
                 ) -> tuple[np.ndarray, sp.csr_matrix]:
        """Residual ``R`` (W per cell) and Jacobian ``dR/dT`` (W/K).

        ``absorb`` is the absorptivity; ``dabsorb`` its gradient with respect to the
        temperatures of ``self.ts_cells`` (None when it is lagged).
        """
        R = np.zeros(self.n)
        rows, cols, vals = [], [], []
        tables = {False: (laws.phi_x, laws.powder_x), True: (laws.phi_z, laws.powder_z)}
        evals = {d: [tab(T) for tab in tabs] for d, tabs in tables.items()}
        for fc in self.faces:
            flux, dP, dN = self._conduction(fc, T, dense, tables[fc.vertical],
                                            evals[fc.vertical])
            interior = fc.nb >= 0
            R += np.bincount(fc.P, flux, self.n)
            rows += [fc.P]
            cols += [fc.P]
            vals += [dP]
            Pi, Ni = fc.P[interior], fc.nb[interior]
            R -= np.bincount(Ni, flux[interior], self.n)
            rows += [Pi, Ni, Ni]
            cols += [Ni, Ni, Pi]
            vals += [dN[interior], -dN[interior], -dP[interior]]
        self._advection(T, dense, laws, R, rows, cols, vals)
        self._surface(T, absorb, dabsorb, R, rows, cols, vals)
        J = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                          shape=(self.n, self.n))
        return R, J

    def _conduction(self, fc: Faces, T: np.ndarray, dense: np.ndarray, tabs, ev
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Flux into ``P`` through each face and its derivatives by ``T_P``, ``T_nb``.

        Same-law faces: ``G (Phi(T_nb) - Phi(T_P))`` (Kirchhoff, exact). Faces between
        powder and dense cells: series conductance of the half cells with each side's
        own ``k(T)``, differentiated exactly.
        """
        interior = fc.nb >= 0
        nb = np.where(interior, fc.nb, fc.P)
        t_inf = np.array([self.mat.T_ambient])
        lawP = np.where(dense[fc.P], 0, 1)
        lawN = np.where(interior, np.where(dense[nb], 0, 1), lawP)
        out_flux = np.empty(fc.P.size)
        out_dP = np.empty(fc.P.size)
        out_dN = np.zeros(fc.P.size)
        for law in (0, 1):
            same = (lawP == law) & (lawN == law)
            if not same.any():
                continue
            phi, k = ev[law]
            phi_b, _ = tabs[law](t_inf)
            P, N, I = fc.P[same], nb[same], interior[same]
            phi_n = np.where(I, phi[N], phi_b[0])
            out_flux[same] = fc.G[same] * (phi_n - phi[P])
            out_dP[same] = -fc.G[same] * k[P]
            out_dN[same] = np.where(I, fc.G[same] * k[N], 0.0)
        mixed = lawP != lawN
        if mixed.any():
            P, N = fc.P[mixed], nb[mixed]
            kP = np.where(lawP[mixed] == 0, ev[0][1][P], ev[1][1][P])
            kN = np.where(lawN[mixed] == 0, ev[0][1][N], ev[1][1][N])
            sP = np.where(lawP[mixed] == 0, tabs[0].slope(T[P]), tabs[1].slope(T[P]))
            sN = np.where(lawN[mixed] == 0, tabs[0].slope(T[N]), tabs[1].slope(T[N]))
            hP, hN = fc.hP[mixed], fc.hN[mixed]
            area = fc.G[mixed] * (hP + hN)
            res = hP / kP + hN / kN
            g = area / res
            dT = T[N] - T[P]
            out_flux[mixed] = g * dT
            out_dP[mixed] = -g + dT * area / res**2 * hP * sP / kP**2
            out_dN[mixed] = g + dT * area / res**2 * hN * sN / kN**2
        return out_flux, out_dP, out_dN

    def density(self, dense: np.ndarray) -> np.ndarray:
        """Cell density (kg/m^3): powder packing for never-melted powder."""
        return np.where(dense, 1.0, self.mat.powder_packing) * self.mat.rho

    def _advection(self, T, dense, laws, R, rows, cols, vals) -> None:
        H, c = laws.enthalpy(T)
        rho = self.density(dense)
        m = self.v * self.area_yz * rho  # kg/s through the upstream face of each cell
        P, E = (a.ravel() for a in self.x_up)
        R[P] += m[E] * H[E]
        R -= m * H
        rows += [P, np.arange(self.n)]
        cols += [E, np.arange(self.n)]
        vals += [m[E] * c[E], -m * c]

    def _surface(self, T, absorb, dabsorb, R, rows, cols, vals) -> None:
        mat = self.mat
        Tt = T[self.top]
        es = mat.emissivity * STEFAN_BOLTZMANN
        loss = self.area_top * (es * (Tt**4 - mat.T_ambient**4) + mat.h_conv * (Tt - mat.T_ambient))
        R[self.top] += absorb * self.q_top - loss
        rows += [self.top]
        cols += [self.top]
        vals += [-self.area_top * (4 * es * Tt**3 + mat.h_conv)]
        if dabsorb is not None:
            b = self.top[self.beam]
            rows += [np.repeat(b, dabsorb.size)]
            cols += [np.tile(self.ts_cells, b.size)]
            vals += [np.outer(self.q_top[self.beam], dabsorb).ravel()]


def surface_weights(c0: float, c1: float, *, even: bool) -> np.ndarray:
    """Weights of the two first cell centres extrapolating to the boundary at 0.

    ``even``: symmetry plane, quadratic in the coordinate (zero slope); otherwise linear.
    """
    if even:
        a = c0**2 / (c1**2 - c0**2)
    else:
        a = c0 / (c1 - c0)
    return np.array([1 + a, -a])
