"""Powder consolidation as a function of the temperature field, and its Newton terms.

Two memoryless forms of the consolidated fraction ``frac(T)`` of the 30 um powder layer
(physics.md, M1: powder counts as consolidated once melted upstream). In the laser frame
the material moves towards ``-x``, so the powder in a column at ``(x, y)`` has passed
every ``x' >= x`` at the same ``y``.

*Upstream maximum* (:func:`consolidated`; ``consolidation="monotone"`` and ``"field"``):
a column is consolidated to the degree that the hottest point of the layer upstream
approached the solidus. The hottest point of a column is a cell centre or the top
surface, whose temperature ``T_top + A q dz / (2 k_p)`` follows from the absorbed flux
``A q``: in the insulating powder the centre of a top cell lags the surface by an amount
that scales with the cell size, so centres alone would move the powder edge with the
mesh. With ``s = clip((T_hot - T_S) / CONSOLIDATION_RAMP + 1, 0, 1)`` the fraction is the
smoothstep ``s^2 (3 - 2 s)``: 0 at ``T_S - CONSOLIDATION_RAMP``, 1 at ``T_S``.
``dfrac/dT`` is nonzero only at the cell that sets a column's upstream maximum, so the
term is sparse, though not local, and it switches cells as the maximum moves.

*Cumulative exposure* (:func:`exposure`; ``consolidation="exposure"``)::

    D(x, y) = int_{x' > x} s(T_s(x', y)) dx',    frac = 1 - (1 - min(D / l_c, 1))^3,

with ``s`` the same smoothstep of the column's surface temperature ``T_s`` and
``l_c = CONSOLIDATION_LENGTH``: a column consolidates over a path length ``l_c`` at or
above the solidus (63 % after ``l_c / 3``), and reaches ``frac = 1`` exactly, so that
consolidated powder conducts through the exact Kirchhoff faces of the dense law. ``D``
is a cumulative sum along ``x`` (one linear operator applied to ``s(T)``): ``frac`` is a
smooth function of the field with no maximum and no memory, and its exact derivative is
applied as an operator (:class:`Exposure`), never formed. Faces between cells of
different fractions then use the laws' secant conductivities
(:attr:`~.assembly.Discretization.secant_faces`), so the residual is continuous where a
fraction reaches 0 or 1; with centre conductivities it jumps there, and under the beam
the series form throttles the vapour's vertical conduction, which kept the iteration
from converging at the large keyhole pools.

With ``"field"`` and ``"exposure"`` the Newton matrix includes
``dR/dfrac dfrac/dT`` (:func:`fraction_coupling`), so a converged state solves
``R(T, frac(T)) = 0`` whatever the path. The default ``"monotone"`` takes the largest
upstream-maximum ``frac(T)`` over a solve's iterates instead (:func:`~.solver.newton_solve`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import scipy.sparse as sp

from calnet.simulators.melt_pool.properties import secant

if TYPE_CHECKING:
    from calnet.simulators.melt_pool.assembly import Discretization
    from calnet.simulators.melt_pool.properties import MaterialLaws

CONSOLIDATION_RAMP = 100.0  # K, width of the loose -> consolidated powder ramp below T_S
# m, path length at or above T_S that consolidates fully (exposure form), the beam's
# radius: a column consolidates within about one beam radius of travel above the
# solidus. It must span at least a cell of the sizing mesh (x spacings 15-25 um): a
# shorter length turns the fraction behind a column crossing the solidus into a near
# switch within one cell, on which Newton cycles at keyhole-threshold settings.
CONSOLIDATION_LENGTH = 40e-6


def consolidated(disc: Discretization, T: np.ndarray, absorb: float, k_powder: float
                 ) -> tuple[np.ndarray, sp.csr_matrix]:
    """Consolidated fraction of every cell and its derivative by ``T``.

    Parameters
    ----------
    disc : Discretization
        The mesh's discretization (geometry, beam flux per top face ``q_top``).
    T : ndarray, shape (n_cells,)
        Temperatures (K).
    absorb : float
        Absorptivity, scaling the surface term (held fixed in the derivative).
    k_powder : float
        Loose-powder conductivity (W/(m K)).

    Returns
    -------
    frac : ndarray, shape (n_cells,)
        Fraction in [0, 1]; 1 in the substrate.
    dfrac : scipy.sparse.csr_matrix, shape (n_cells, n_cells)
        ``d frac_i / d T_j`` (1/K): one entry per powder cell inside the ramp, at the
        cell that sets its column's upstream maximum.
    """
    mesh = disc.mesh
    n, n_p = mesh.size, mesh.n_powder
    frac = np.ones(mesh.shape)
    if n_p == 0:
        return frac.ravel(), sp.csr_matrix((n, n))
    nx, ny, _ = mesh.shape
    T3 = T.reshape(mesh.shape)
    dz0 = mesh.zf[1] - mesh.zf[0]
    q = (absorb * disc.q_top / disc.area_top).reshape(nx, ny)
    cand = np.concatenate([T3[:, :, :n_p], (T3[:, :, 0] + q * dz0 / (2 * k_powder))[..., None]],
                          axis=2)
    z_hot = cand.argmax(axis=2)
    hot0 = np.take_along_axis(cand, z_hot[..., None], axis=2)[..., 0]
    z_hot = np.where(z_hot == n_p, 0, z_hot)  # the surface term moves with the top cell
    rev = hot0[::-1]
    hot = np.maximum.accumulate(rev, axis=0)
    setter = np.where(rev >= hot, np.arange(nx)[:, None], 0)
    x_hot = (nx - 1 - np.maximum.accumulate(setter, axis=0))[::-1]  # argmax over x' >= x
    hot = hot[::-1]
    s = np.clip((hot - disc.mat.T_solidus) / CONSOLIDATION_RAMP + 1.0, 0.0, 1.0)
    frac[:, :, :n_p] = (s * s * (3 - 2 * s))[:, :, None]
    slope = 6 * s * (1 - s) / CONSOLIDATION_RAMP  # d frac / d T_hot, zero outside the ramp
    i, j = np.nonzero(slope > 0)
    src = (x_hot[i, j] * ny + j) * mesh.shape[2] + z_hot[x_hot[i, j], j]
    rows = ((i * ny + j)[:, None] * mesh.shape[2] + np.arange(n_p)).ravel()
    cols = np.repeat(src, n_p)
    vals = np.repeat(slope[i, j], n_p)
    return frac.ravel(), sp.csr_matrix((vals, (rows, cols)), shape=(n, n))


def _upstream_sum(a: np.ndarray, dx: np.ndarray) -> np.ndarray:
    """``int_{x' > x_i} a dx'`` per cell (axis 0), shape of ``a``: the cells strictly
    upstream of ``i``, none of cell ``i`` itself. Any share of its own length makes a top
    powder cell's fraction rise with its own temperature, and with it the conductance to
    its hot neighbours: its residual can then grow with its temperature (the cell takes
    up more heat the hotter it is), the steady problem has several solutions at such
    cells, and Newton cycles between them."""
    w = a * dx[:, None]
    return np.cumsum(w[::-1], axis=0)[::-1] - w


@dataclass(frozen=True)
class Exposure:
    """Exposure-consolidated fraction of every cell and the factors of its derivative.

    ``d frac / d T`` applied to ``d`` is ``g * U(dr * d_top)`` in every powder cell of a
    column (``U`` the upstream sum of :func:`_upstream_sum`, ``d_top`` the top-cell
    entries of ``d``), plus ``g * U(dr * q_s)`` times ``dA . d`` through the
    absorptivity in the surface term.
    """

    frac: np.ndarray  # (n_cells,) in [0, 1]; 1 in the substrate
    g: np.ndarray  # (nx, ny) exp(-E), d frac / d E
    dr: np.ndarray  # (nx, ny) d r / d T_s (1/(m K))
    surface_gain: np.ndarray  # (nx, ny) d T_s / d A (K)
    dx: np.ndarray  # (nx,) cell lengths (m)
    shape: tuple[int, int, int]
    n_powder: int

    def _spread(self, col: np.ndarray) -> np.ndarray:
        out = np.zeros(self.shape)
        out[:, :, : self.n_powder] = col[:, :, None]
        return out.ravel()

    def apply(self, d: np.ndarray) -> np.ndarray:
        """``(d frac / d T) d`` at fixed absorptivity, shape (n_cells,)."""
        if self.n_powder == 0:
            return np.zeros(d.size)
        top = d.reshape(self.shape)[:, :, 0]
        return self._spread(self.g * _upstream_sum(self.dr * top, self.dx))

    def by_absorptivity(self) -> np.ndarray:
        """``d frac / d A``, shape (n_cells,)."""
        if self.n_powder == 0:
            return np.zeros(int(np.prod(self.shape)))
        return self._spread(self.g * _upstream_sum(self.dr * self.surface_gain, self.dx))

    def matrix(self) -> sp.csr_matrix:
        """``d frac / d T`` at fixed absorptivity as a sparse matrix (dense along each
        streamline: for tests and small meshes only)."""
        n = int(np.prod(self.shape))
        nx, ny, nz = self.shape
        if self.n_powder == 0:
            return sp.csr_matrix((n, n))
        i, ip, j = np.nonzero((np.arange(nx)[:, None, None] < np.arange(nx)[None, :, None])
                              & (self.dr[None, :, :] != 0))
        w = self.dx[ip] * self.g[i, j] * self.dr[ip, j]
        k = np.arange(self.n_powder)
        rows = ((i * ny + j)[:, None] * nz + k).ravel()
        cols = np.repeat((ip * ny + j) * nz, self.n_powder)
        return sp.csr_matrix((np.repeat(w, self.n_powder), (rows, cols)), shape=(n, n))


def exposure(disc: Discretization, T: np.ndarray, absorb: float, k_powder: float
             ) -> Exposure:
    """Consolidated fraction by cumulative exposure (``consolidation="exposure"``) and
    the factors of its derivative by ``T``.

    Parameters
    ----------
    disc : Discretization
        The mesh's discretization (geometry, beam flux per top face ``q_top``).
    T : ndarray, shape (n_cells,)
        Temperatures (K).
    absorb : float
        Absorptivity, scaling the surface term.
    k_powder : float
        Loose-powder conductivity (W/(m K)).

    Returns
    -------
    Exposure
        ``frac`` (n_cells,), in [0, 1], 1 in the substrate, and the factors of
        ``d frac / d T``.
    """
    mesh = disc.mesh
    nx, ny, _ = mesh.shape
    n_p = mesh.n_powder
    dx = np.diff(mesh.xf)
    if n_p == 0:
        z = np.zeros((nx, ny))
        return Exposure(np.ones(mesh.size), z, z, z, dx, mesh.shape, 0)
    T3 = T.reshape(mesh.shape)
    dz0 = mesh.zf[1] - mesh.zf[0]
    gain = (disc.q_top / disc.area_top).reshape(nx, ny) * dz0 / (2 * k_powder)
    ts = T3[:, :, 0] + absorb * gain
    s = np.clip((ts - disc.mat.T_solidus) / CONSOLIDATION_RAMP + 1.0, 0.0, 1.0)
    rate = s * s * (3 - 2 * s)
    drate = 6 * s * (1 - s) / CONSOLIDATION_RAMP
    rest = 1.0 - np.minimum(_upstream_sum(rate, dx) / CONSOLIDATION_LENGTH, 1.0)
    frac = np.ones(mesh.shape)
    frac[:, :, :n_p] = (1.0 - rest**3)[:, :, None]
    g = 3.0 * rest**2 / CONSOLIDATION_LENGTH
    return Exposure(frac.ravel(), g, drate, gain, dx, mesh.shape, n_p)


def fraction_coupling(disc: Discretization, T: np.ndarray, frac: np.ndarray,
                      laws: MaterialLaws) -> sp.csr_matrix:
    """``dR/dfrac`` (W per unit fraction), shape (n_cells, n_cells), at fixed ``T``.

    Conduction through faces between cells of different laws (series conductance of
    two half cells, each ``k = exp(f ln k_d + (1 - f) ln k_p)`` of the laws' centre or,
    with ``disc.secant_faces``, secant conductivities) and the advected mass
    flux (density ``(pack + (1 - pack) f) rho``, and the hybrid-advection weight through
    the mass flux and the upstream cell's reference conductivity).
    """
    rows: list[np.ndarray] = []
    cols: list[np.ndarray] = []
    vals: list[np.ndarray] = []
    tables = {False: (laws.phi_x, laws.powder_x), True: (laws.phi_z, laws.powder_z)}
    logs = {}
    for vertical, (dense, loose) in tables.items():
        kd, kl = dense(T)[1], loose(T)[1]
        logs[vertical] = (np.log(kd), np.log(kl))
    for fc in disc.faces:
        interior = fc.nb >= 0
        P, N = fc.P[interior], fc.nb[interior]
        fP, fN = frac[P], frac[N]
        mixed = ~(((fP == 1) & (fN == 1)) | ((fP == 0) & (fN == 0)))
        if not mixed.any():
            continue
        P, N, fP, fN = P[mixed], N[mixed], fP[mixed], fN[mixed]
        if disc.secant_faces:
            dense, loose = tables[fc.vertical]
            evs = [tab(T) for tab in (dense, loose)]
            lgd = np.log(secant(T, P, N, dense, evs[0])[0])
            lgl = np.log(secant(T, P, N, loose, evs[1])[0])
            ldP, llP, ldN, llN = lgd, lgl, lgd, lgl
        else:
            ld, ll = logs[fc.vertical]
            ldP, llP, ldN, llN = ld[P], ll[P], ld[N], ll[N]
        kP = np.exp(fP * ldP + (1 - fP) * llP)
        kN = np.exp(fN * ldN + (1 - fN) * llN)
        hP, hN = fc.hP[interior][mixed], fc.hN[interior][mixed]
        area = fc.G[interior][mixed] * (hP + hN)
        res = hP / kP + hN / kN
        common = area * (T[N] - T[P]) / res**2
        d_fP = common * hP / kP * (ldP - llP)  # d flux into P / d f_P
        d_fN = common * hN / kN * (ldN - llN)
        rows += [P, N, P, N]
        cols += [P, P, N, N]
        vals += [d_fP, -d_fP, d_fN, -d_fN]
    mat = disc.mat
    S, _ = laws.sensible(T)
    Lh, _ = laws.latent(T)
    dm = disc.v * disc.area_yz * (1.0 - mat.powder_packing) * mat.rho  # d mass flux / d f
    if disc.conserved_mass:  # the powder layer's mass flux does not depend on f
        dm = 0.0 * dm
    P, E = disc.x_down, disc.x_upstream
    powder = frac[E] < 1
    P, E = P[powder], E[powder]
    m = disc.v * disc.area_yz * disc.mass_density(frac)
    # F = m_E (S_E + beta (1 - w) (S_P - S_E) + L_E) into P out of E, with the hybrid
    # weight beta = min(1, c k_ref(min(f_P, f_E)) / m_E); both forms of frac(T) grow
    # downstream (f_P >= f_E), so the minimum is f_E
    F, _, _ = disc.advective_flux(T, frac, laws)
    F, mE, dmE = F[powder], m[E], dm[E]
    k_d, k_l = laws.phi_x(disc._t_ref)[1][0], laws.powder_x(disc._t_ref)[1][0]
    k_ref = np.exp(frac[E] * np.log(k_d) + (1 - frac[E]) * np.log(k_l))
    beta = 1.8 * disc.gx[powder] * k_ref / (mE * mat.cp_liquid)
    dbeta = np.where(beta < 1, beta * (np.log(k_d / k_l) - dmE / mE), 0.0)
    wP = 1 - disc.w_up[powder]
    dF = F / mE * dmE + mE * wP * (S[P] - S[E]) * dbeta
    rows += [P, E]
    cols += [E, E]
    vals += [dF, -dF]
    o = disc.outflow[frac[disc.outflow] < 1]
    rows.append(o)
    cols.append(o)
    vals.append(-dm[o] * (S[o] + Lh[o]))
    n = disc.n
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                         shape=(n, n))
