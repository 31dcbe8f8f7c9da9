"""Finite-volume residual and exact Newton Jacobian of the steady melt-pool equation.

Cell energy balance (W), positive for net inflow (physics.md, M1)::

    R_P = sum_f G_f (Phi_d(T_nb) - Phi_d(T_P))          conduction, Kirchhoff form
        + v A_yz (rho_E H(T_E) - rho_P H(T_P))            upwind advection, flow to -x
        + A(T_s) Q_P - A_top (eps sigma (T^4 - T_inf^4) + h (T - T_inf))

so ``dR/dT = L diag(k(T)) + advection + boundary terms + a rank-one absorptivity term``.
Never-melted powder cells use their own law (``k_p`` below ``T_S``, liquid above);
partly consolidated cells a log blend of the powder and dense laws; a face between
cells of different laws uses the series conductance of the two half cells, each with
its own ``k(T)``.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.special import erf

from calnet.simulators.materials import STEFAN_BOLTZMANN, AlloyProperties
from calnet.simulators.melt_pool.consolidation import consolidated
from calnet.simulators.melt_pool.mesh import Mesh
from calnet.simulators.melt_pool.properties import MaterialLaws, secant


def _blend(T: np.ndarray, f: np.ndarray, tabs, ev, idx: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray]:
    """``k`` and ``dk/dT`` of partly consolidated cells: log blend with weight ``f``."""
    kd, kl = ev[0][1][idx], ev[1][1][idx]
    k = np.exp(f * np.log(kd) + (1 - f) * np.log(kl))
    return k, k * (f * tabs[0].slope(T) / kd + (1 - f) * tabs[1].slope(T) / kl)


def _secant_mixed(T, P, N, fP, fN, tabs, ev, hP, hN, G):
    """Flux into ``P`` through faces between cells of different consolidated fractions,
    Kirchhoff-consistent: each half cell conducts with ``k = k_d^f k_p^(1 - f)`` of the
    two laws' secant conductivities over ``[T_P, T_N]``, so the flux is continuous
    in ``f`` and equals ``G (Phi(T_N) - Phi(T_P))`` of a single law at ``f = 0`` or 1.
    Returns the flux and its derivatives by ``T_P`` and ``T_N``."""
    kd, kdP, kdN = secant(T, P, N, tabs[0], ev[0])
    kl, klP, klN = secant(T, P, N, tabs[1], ev[1])
    kP = np.exp(fP * np.log(kd) + (1 - fP) * np.log(kl))
    kN = np.exp(fN * np.log(kd) + (1 - fN) * np.log(kl))
    area = G * (hP + hN)
    res = hP / kP + hN / kN
    g = area / res
    dT = T[N] - T[P]
    w = dT * area / res**2  # d flux / d k_half = w h / k_half^2

    def dk(f, kh, dd, dl):
        return kh * (f * dd / kd + (1 - f) * dl / kl)

    dflux_P = w * (hP / kP**2 * dk(fP, kP, kdP, klP) + hN / kN**2 * dk(fN, kN, kdP, klP))
    dflux_N = w * (hP / kP**2 * dk(fP, kP, kdN, klN) + hN / kN**2 * dk(fN, kN, kdN, klN))
    return g * dT, -g + dflux_P, g + dflux_N


@dataclass(frozen=True)
class _Pattern:
    """CSR pattern of the Jacobian and where each listed entry goes (see
    :meth:`Discretization._pattern`)."""

    slot: np.ndarray  # (n_entries,) CSR data index of each entry, in evaluate's order
    indices: np.ndarray
    indptr: np.ndarray
    diag: np.ndarray  # (n,) CSR data index of each diagonal entry


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
        self.x_down, self.x_upstream = idx[:-1].ravel(), idx[1:].ravel()  # face pairs
        xc = Mesh.centres(mesh.xf)
        w_up = (mesh.xf[1:-1] - xc[:-1]) / np.diff(xc)  # central weight of the upstream cell
        self.w_up = np.broadcast_to(w_up[:, None, None], (nx - 1, ny, nz)).ravel()
        self.gx = np.broadcast_to((np.multiply.outer(dy, dz) / np.diff(xc)[:, None, None]),
                                  (nx - 1, ny, nz)).ravel()  # area / distance (m)
        self._t_ref = np.array([mat.T_ambient])
        self.outflow = idx[0].ravel()
        self.top = idx[:, :, 0].ravel()
        self.area_top = np.multiply.outer(dx, dy).ravel()
        r0 = mat.beam_radius
        ex = np.diff(erf(np.sqrt(2) * mesh.xf / r0))
        ey = np.diff(erf(np.sqrt(2) * mesh.yf / r0))
        self.q_top = 0.25 * P * np.multiply.outer(ex, ey).ravel()  # W per face at A = 1
        self.beam = np.flatnonzero(self.q_top > 1e-12 * self.q_top.max())
        self.ts_cells, self.ts_weights = self._surface_stencil()
        self._patterns: dict[bool, _Pattern] = {}
        # faces between cells of different consolidated fractions: series conductance
        # of the cell-centre conductivities (False) or of the two laws' secant
        # conductivities over the face's temperature range (True, _secant_mixed)
        self.secant_faces = False
        # the mass flux of the powder layer: its bulk density whatever the consolidation
        # (True, mass conserved along every streamline), or the density of the cell's
        # consolidated fraction (False; :meth:`mass_density`)
        self.conserved_mass = True

    def with_power(self, P: float) -> Discretization:
        """The same discretization with laser power ``P`` (W); geometry shared."""
        out = copy.copy(self)
        out.P, out.q_top = P, self.q_top * (P / self.P)
        return out

    def _pattern(self, coupled: bool) -> _Pattern:
        """The Jacobian's sparsity (fixed per mesh), built on first use.

        :meth:`evaluate` lists its entries in the order of :meth:`_entries`; a
        precomputed map sends each to its CSR slot, so assembly is one ``bincount``
        instead of a COO -> CSR conversion (with sorting) at every Newton step.
        ``coupled``: with the rank-one absorptivity block.
        """
        if coupled not in self._patterns:
            rows, cols = self._entries(coupled)
            key = rows.astype(np.int64) * self.n + cols
            uniq, slot = np.unique(key, return_inverse=True)
            r, c = np.divmod(uniq, self.n)
            indptr = np.concatenate([[0], np.cumsum(np.bincount(r, minlength=self.n))])
            diag = np.searchsorted(uniq, np.arange(self.n, dtype=np.int64) * (self.n + 1))
            if not np.array_equal(uniq[diag], np.arange(self.n) * (self.n + 1)):
                raise RuntimeError("melt_pool: Jacobian pattern lacks a diagonal entry")
            self._patterns[coupled] = _Pattern(slot, c.astype(np.int32),
                                               indptr.astype(np.int32), diag)
        return self._patterns[coupled]

    def _entries(self, coupled: bool) -> tuple[np.ndarray, np.ndarray]:
        """Row and column of every Jacobian value :meth:`evaluate` appends, in order."""
        rows, cols = [], []
        for fc in self.faces:
            interior = fc.nb >= 0
            Pi, Ni = fc.P[interior], fc.nb[interior]
            rows += [fc.P, Pi, Ni, Ni]
            cols += [fc.P, Ni, Ni, Pi]
        P, E, o = self.x_down, self.x_upstream, self.outflow
        rows += [P, P, E, E, o, self.top]
        cols += [E, P, E, P, o, self.top]
        if coupled:
            b = self.top[self.beam]
            rows += [np.repeat(b, self.ts_cells.size)]
            cols += [np.tile(self.ts_cells, b.size)]
        return np.concatenate(rows), np.concatenate(cols)

    def system(self, J: sp.csr_matrix, diagonal: np.ndarray, *, coupled: bool
               ) -> sp.csr_matrix:
        """``diag(diagonal) - J`` on the pattern of a ``J`` from :meth:`evaluate`
        (``coupled``: it was given ``dabsorb``), without re-sorting."""
        pat = self._pattern(coupled)
        data = -J.data
        data[pat.diag] += diagonal
        return sp.csr_matrix((data, J.indices, J.indptr), shape=J.shape)

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

    def consolidated(self, T: np.ndarray, absorb: float = 0.0, k_powder: float = 1.0
                     ) -> np.ndarray:
        """Consolidated fraction of every cell (n_cells,), 1 for the substrate
        (:func:`~.consolidation.consolidated`)."""
        return consolidated(self, T, absorb, k_powder)[0]

    def surface_temperature(self, T: np.ndarray, laws: MaterialLaws
                            ) -> tuple[float, np.ndarray]:
        """Reconstructed ``T_s`` at the beam centre and ``dT_s/dT`` on its stencil."""
        Tc = T[self.ts_cells]
        phi, k = laws.phi_z(Tc)
        ts = float(laws.phi_z.inverse(np.array([self.ts_weights @ phi]))[0])
        lo, hi = Tc.min() - 200.0, Tc.max() + 200.0  # extrapolation guard (wild iterates)
        if not lo <= ts <= hi:
            return float(np.clip(ts, lo, hi)), np.zeros_like(k)
        _, k_s = laws.phi_z(np.array([ts]))
        return ts, self.ts_weights * k / k_s[0]

    def evaluate(self, T: np.ndarray, frac: np.ndarray, laws: MaterialLaws,
                 absorb: float, dabsorb: np.ndarray | None
                 ) -> tuple[np.ndarray, sp.csr_matrix]:
        """Residual ``R`` (W per cell) and Jacobian ``dR/dT`` (W/K).

        ``absorb`` is the absorptivity; ``dabsorb`` its gradient with respect to the
        temperatures of ``self.ts_cells`` (None when it is lagged).
        """
        R = np.zeros(self.n)
        vals: list[np.ndarray] = []
        tables = {False: (laws.phi_x, laws.powder_x), True: (laws.phi_z, laws.powder_z)}
        evals = {d: [tab(T) for tab in tabs] for d, tabs in tables.items()}
        for fc in self.faces:
            flux, dP, dN = self._conduction(fc, T, frac, tables[fc.vertical],
                                            evals[fc.vertical])
            interior = fc.nb >= 0
            R += np.bincount(fc.P, flux, self.n)
            Ni = fc.nb[interior]
            R -= np.bincount(Ni, flux[interior], self.n)
            vals += [dP, dN[interior], -dN[interior], -dP[interior]]
        self._advection(T, frac, laws, R, vals)
        self._surface(T, absorb, dabsorb, R, vals)
        pat = self._pattern(dabsorb is not None)
        data = np.bincount(pat.slot, np.concatenate(vals), pat.indptr[-1])
        return R, sp.csr_matrix((data, pat.indices, pat.indptr), shape=(self.n, self.n))

    def _conduction(self, fc: Faces, T: np.ndarray, frac: np.ndarray, tabs, ev
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Flux into ``P`` through each face and its derivatives by ``T_P``, ``T_nb``.

        Faces between two dense (``frac = 1``) or two loose-powder (``frac = 0``) cells:
        ``G (Phi(T_nb) - Phi(T_P))`` (Kirchhoff, exact). Other faces: series conductance
        of the two half cells, each with its own ``k(T, frac)`` (log blend of the powder
        and dense laws) at its centre temperature, or, with ``secant_faces``, of the
        laws' secant conductivities over ``[T_P, T_nb]`` (:func:`_secant_mixed`,
        continuous in ``frac``); differentiated exactly at fixed ``frac``.
        """
        interior = fc.nb >= 0
        nb = np.where(interior, fc.nb, fc.P)
        t_inf = np.array([self.mat.T_ambient])
        fP = frac[fc.P]
        fN = np.where(interior, frac[nb], fP)
        out_flux = np.empty(fc.P.size)
        out_dP = np.empty(fc.P.size)
        out_dN = np.zeros(fc.P.size)
        pure = np.zeros(fc.P.size, bool)
        for law, f in ((0, 1.0), (1, 0.0)):
            same = (fP == f) & (fN == f)
            pure |= same
            if not same.any():
                continue
            phi, k = ev[law]
            phi_b, _ = tabs[law](t_inf)
            P, N, I = fc.P[same], nb[same], interior[same]
            phi_n = np.where(I, phi[N], phi_b[0])
            out_flux[same] = fc.G[same] * (phi_n - phi[P])
            out_dP[same] = -fc.G[same] * k[P]
            out_dN[same] = np.where(I, fc.G[same] * k[N], 0.0)
        mixed = ~pure & interior
        if mixed.any() and self.secant_faces:
            P, N = fc.P[mixed], nb[mixed]
            flux, dP, dN = _secant_mixed(T, P, N, fP[mixed], fN[mixed], tabs, ev,
                                         fc.hP[mixed], fc.hN[mixed], fc.G[mixed])
            out_flux[mixed], out_dP[mixed], out_dN[mixed] = flux, dP, dN
        elif mixed.any():
            P, N = fc.P[mixed], nb[mixed]
            kP, sP = _blend(T[P], fP[mixed], tabs, ev, P)
            kN, sN = _blend(T[N], fN[mixed], tabs, ev, N)
            hP, hN = fc.hP[mixed], fc.hN[mixed]
            area = fc.G[mixed] * (hP + hN)
            res = hP / kP + hN / kN
            g = area / res
            dT = T[N] - T[P]
            out_flux[mixed] = g * dT
            out_dP[mixed] = -g + dT * area / res**2 * hP * sP / kP**2
            out_dN[mixed] = g + dT * area / res**2 * hN * sN / kN**2
        edge = ~pure & ~interior  # Dirichlet face of a partly consolidated cell
        if edge.any():
            P = fc.P[edge]
            kP, _ = _blend(T[P], fP[edge], tabs, ev, P)
            out_flux[edge] = fc.G[edge] * kP * (self.mat.T_ambient - T[P])
            out_dP[edge] = -fc.G[edge] * kP  # k is constant below T_S, where these live
        return out_flux, out_dP, out_dN

    def density(self, frac: np.ndarray) -> np.ndarray:
        """Cell density (kg/m^3): packing fraction for loose powder, blended by ``frac``."""
        pack = self.mat.powder_packing
        return (pack + (1.0 - pack) * frac) * self.mat.rho

    def mass_density(self, frac: np.ndarray) -> np.ndarray:
        """Density (kg/m^3) that carries the advected mass.

        With :attr:`conserved_mass` the powder layer's bulk density whatever its
        consolidation: the mass flux is the same along every streamline, as the powder's
        mass is (a consolidated track is denser and thinner; the model keeps the layer's
        thickness). Otherwise :meth:`density`: the mass flux then grows where powder
        consolidates, and the enthalpy flux ``m H`` of the mass it gains, referred to
        ``T_ambient``, is a heat sink at the consolidation front, as if cold metal were
        added there."""
        if not self.conserved_mass:
            return self.density(frac)
        return np.where(self.powder_cells.ravel(), self.mat.powder_packing, 1.0) * self.mat.rho

    def advective_flux(self, T: np.ndarray, frac: np.ndarray, laws: MaterialLaws
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Enthalpy flux (W) through every interior x face towards ``-x``, shape
        (n_x_faces,), and its derivatives by the upstream and downstream temperatures.

        Latent part upwind; sensible part blended between central and upwind with the
        face weight ``beta = min(1, 1.8 / Pe_face)`` (hybrid scheme), where
        ``Pe_face = v rho c_p,l dx / k_ref`` uses ``k_ref = K_S`` (``k_p`` next to loose
        powder), so ``beta`` does not depend on ``T`` and the Jacobian stays exact:
        central (second order, no numerical diffusion) in the pool region, upwind in
        the stretched far field.
        """
        S, cp = laws.sensible(T)
        Lh, dl = laws.latent(T)
        m = self.v * self.area_yz * self.mass_density(frac)  # kg/s through a cross-section
        P, E = self.x_down, self.x_upstream
        mE = m[E]
        k_d, k_l = laws.phi_x(self._t_ref)[1][0], laws.powder_x(self._t_ref)[1][0]
        f_face = np.minimum(frac[P], frac[E])
        k_ref = np.exp(f_face * np.log(k_d) + (1 - f_face) * np.log(k_l))
        beta = np.minimum(1.0, 1.8 * self.gx * k_ref / (mE * self.mat.cp_liquid))
        wE, wP = beta * self.w_up, beta * (1 - self.w_up)
        F = mE * ((1 - beta) * S[E] + wE * S[E] + wP * S[P] + Lh[E])
        return F, mE * ((1 - beta + wE) * cp[E] + dl[E]), mE * wP * cp[P]

    def _advection(self, T, frac, laws, R, vals) -> None:
        """Enthalpy advection towards ``-x`` (:meth:`advective_flux`) and the outflow."""
        F, dFE, dFP = self.advective_flux(T, frac, laws)
        P, E = self.x_down, self.x_upstream
        R += np.bincount(P, F, self.n) - np.bincount(E, F, self.n)
        S, cp = laws.sensible(T)
        Lh, dl = laws.latent(T)
        o = self.outflow
        m_o = self.v * self.area_yz[o] * self.mass_density(frac)[o]
        R[o] -= m_o * (S[o] + Lh[o])
        vals += [dFE, dFP, -dFE, -dFP, -m_o * (cp[o] + dl[o])]  # order of _entries

    def _surface(self, T, absorb, dabsorb, R, vals) -> None:
        mat = self.mat
        Tt = T[self.top]
        es = mat.emissivity * STEFAN_BOLTZMANN
        loss = self.area_top * (es * (Tt**4 - mat.T_ambient**4) + mat.h_conv * (Tt - mat.T_ambient))
        R[self.top] += absorb * self.q_top - loss
        vals += [-self.area_top * (4 * es * Tt**3 + mat.h_conv)]
        if dabsorb is not None:
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
