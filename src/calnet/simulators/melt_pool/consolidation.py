"""Powder consolidation as a function of the temperature field, and its Newton terms.

A powder column (the cells of the 30 um layer at one ``(x, y)``) is consolidated to the
degree that the hottest point of the layer upstream along the material's path, ``x' >= x``
in the laser frame, approached the solidus (physics.md, M1: powder counts as
consolidated once melted anywhere upstream). The hottest point of a column is a cell
centre or the top surface, whose temperature ``T_top + A q dz / (2 k_p)`` follows from the
absorbed flux ``A q``: in the insulating powder the centre of a top cell lags the surface
by an amount that scales with the cell size, so centres alone would move the powder edge
with the mesh. With ``s = clip((T_hot - T_S) / CONSOLIDATION_RAMP + 1, 0, 1)`` the fraction
is the smoothstep ``s^2 (3 - 2 s)``: 0 at ``T_S - CONSOLIDATION_RAMP``, 1 at ``T_S``.

With ``consolidation="field"`` the solver uses ``frac(T)`` of each iterate: the steady
problem ``R(T, frac(T)) = 0`` is one nonlinear system, and its Newton matrix includes
``dR/dfrac dfrac/dT`` (:func:`fraction_coupling`); ``dfrac/dT`` is nonzero only at the
cell that sets a column's upstream maximum, so the term is sparse, though not local. The
default ``"monotone"`` takes the largest ``frac(T)`` over a solve's iterates instead
(:func:`~.solver.newton_solve`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import scipy.sparse as sp

if TYPE_CHECKING:
    from calnet.simulators.melt_pool.assembly import Discretization
    from calnet.simulators.melt_pool.properties import MaterialLaws

CONSOLIDATION_RAMP = 100.0  # K, width of the loose -> consolidated powder ramp below T_S


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


def fraction_coupling(disc: Discretization, T: np.ndarray, frac: np.ndarray,
                      laws: MaterialLaws) -> sp.csr_matrix:
    """``dR/dfrac`` (W per unit fraction), shape (n_cells, n_cells), at fixed ``T``.

    Conduction through faces between cells of different laws (series conductance of
    two half cells, each ``k = exp(f ln k_d + (1 - f) ln k_p)``) and the advected mass
    flux (density ``(pack + (1 - pack) f) rho``). The hybrid-advection weight's
    dependence on the fraction is left out (the Newton matrix is then inexact only at
    the powder edge, where it is small).
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
        ld, ll = logs[fc.vertical]
        kP = np.exp(fP * ld[P] + (1 - fP) * ll[P])
        kN = np.exp(fN * ld[N] + (1 - fN) * ll[N])
        hP, hN = fc.hP[interior][mixed], fc.hN[interior][mixed]
        area = fc.G[interior][mixed] * (hP + hN)
        res = hP / kP + hN / kN
        common = area * (T[N] - T[P]) / res**2
        d_fP = common * hP / kP * (ld[P] - ll[P])  # d flux into P / d f_P
        d_fN = common * hN / kN * (ld[N] - ll[N])
        rows += [P, N, P, N]
        cols += [P, P, N, N]
        vals += [d_fP, -d_fP, d_fN, -d_fN]
    mat = disc.mat
    S, _ = laws.sensible(T)
    Lh, _ = laws.latent(T)
    dm = disc.v * disc.area_yz * (1.0 - mat.powder_packing) * mat.rho  # d mass flux / d f
    P, E = disc.x_down, disc.x_upstream
    powder = frac[E] < 1
    P, E = P[powder], E[powder]
    m = disc.v * disc.area_yz * disc.density(frac)
    # the flux F = m_E (...) into P out of E, linear in m_E except through the weight
    F, _, _ = disc.advective_flux(T, frac, laws)
    dF = F[powder] / m[E] * dm[E]
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

