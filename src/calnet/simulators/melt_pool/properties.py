"""Temperature-dependent material laws as exact piecewise-quadratic tables.

Every nonlinear law ``f(T)`` that the residual needs (Kirchhoff potentials ``Phi_x``,
``Phi_z`` and the enthalpy ``H``) is stored as the exact integral of a piecewise-linear
derivative on a uniform temperature grid. The derivative used in the Newton Jacobian
(``k_x``, ``k_z``, ``c_eff``) is then *exactly* the derivative of the tabulated law,
so Newton converges quadratically (physics.md, "Numerics that are known to work").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calnet.simulators.materials import AlloyProperties

_T_LO, _T_HI, _DT = 100.0, 12100.0, 1.0


@dataclass(frozen=True)
class Table:
    """``F(T) = int f dT`` with ``f`` piecewise linear on a uniform grid.

    Outside the grid ``f`` is held constant (``F`` linear), which keeps wild Newton
    iterates finite.
    """

    f: np.ndarray  # (n,) derivative at grid nodes
    F: np.ndarray  # (n,) integral at grid nodes, F[0] = 0

    @classmethod
    def from_derivative(cls, f: np.ndarray) -> Table:
        F = np.concatenate([[0.0], np.cumsum(0.5 * (f[1:] + f[:-1]) * _DT)])
        return cls(f=np.asarray(f, float), F=F)

    def _locate(self, T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        s = (np.asarray(T, float) - _T_LO) / _DT
        i = np.clip(np.floor(s).astype(np.intp), 0, self.f.size - 2)
        return i, (s - i) * _DT

    def __call__(self, T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Return ``(F(T), f(T))``."""
        i, t = self._locate(T)
        f0, slope = self.f[i], (self.f[i + 1] - self.f[i]) / _DT
        inside = (t >= 0.0) & (t <= _DT)
        slope = np.where(inside, slope, 0.0)
        t_in = np.clip(t, 0.0, _DT)
        F = self.F[i] + f0 * t_in + 0.5 * slope * t_in**2
        f_edge = f0 + slope * t_in
        F = F + f_edge * (t - t_in)  # linear continuation outside the table
        return F, f0 + slope * t_in

    def slope(self, T: np.ndarray) -> np.ndarray:
        """``df/dT`` (piecewise constant; zero outside the table)."""
        i, t = self._locate(T)
        inside = (t >= 0.0) & (t <= _DT)
        return np.where(inside, (self.f[i + 1] - self.f[i]) / _DT, 0.0)

    def inverse(self, F: np.ndarray) -> np.ndarray:
        """Temperature with ``F(T) = F``, exact (root of the quadratic piece)."""
        F = np.asarray(F, float)
        i = np.clip(np.searchsorted(self.F, F, side="right") - 1, 0, self.f.size - 2)
        dF = F - self.F[i]
        f0, slope = self.f[i], (self.f[i + 1] - self.f[i]) / _DT
        inside = (dF >= 0) & (F <= self.F[-1])
        root = np.sqrt(np.maximum(f0**2 + 2 * slope * dF, 0.0))
        t = np.where(inside, 2 * dF / (f0 + root), dF / f0)
        high = F > self.F[-1]
        t = np.where(high, _DT + (F - self.F[-1]) / self.f[-1], t)
        return _T_LO + i * _DT + t


def _grid() -> np.ndarray:
    return np.arange(_T_LO, _T_HI + 0.5 * _DT, _DT)


@dataclass(frozen=True)
class MaterialLaws:
    """Phase-dependent laws of the dense alloy for one parameter vector.

    Attributes
    ----------
    phi_x, phi_z : Table
        Kirchhoff potentials (W/m) of the lateral (x, y) and vertical conductivities.
    powder_x, powder_z : Table
        The same for never-melted powder: ``k_p`` up to ``T_S - POWDER_RAMP``, then a
        smooth log blend to the dense law, reached at ``T_L`` (powder above ``T_S``
        is essentially liquid). The ramp makes the 100x conductivity switch at the
        pool edge resolvable on the mesh; a switch within the 15 K mushy zone moved
        the lateral pool edge by O(h) (W changed 6 % when halving h).
    enthalpy : Table
        ``H(T) - H(T_inf)`` (J/kg) including latent heat; derivative ``c_eff``.
    sensible, latent : Table
        The two parts of ``H``: ``int c_p dT`` and ``L_f f_l(T)`` (J/kg).
    """

    phi_x: Table
    phi_z: Table
    enthalpy: Table
    powder_x: Table
    powder_z: Table
    sensible: Table
    latent: Table


POWDER_RAMP = 100.0  # K below T_S where loose powder starts to sinter (conductivity rises)
MUSHY_ROUNDING = 4.0  # K, width over which the corners of f_l at T_S and T_L are rounded


def liquid_fraction(T: np.ndarray, mat: AlloyProperties) -> np.ndarray:
    """``f_l`` linear from ``T_S`` to ``T_L`` (physics.md), corners rounded.

    The linear ramp is convolved with a ``MUSHY_ROUNDING`` wide box, which keeps
    ``f_l`` exact outside ``T_S +- 2 K`` and ``T_L +- 2 K`` and makes ``c_eff`` continuous
    (a jump in ``c_eff`` lets Newton 2-cycle at cells near ``T_S``).
    """
    d, span = MUSHY_ROUNDING, mat.T_liquidus - mat.T_solidus

    def ramp_integral(x: np.ndarray) -> np.ndarray:  # int of clip(x, 0, 1) (x in units)
        return np.where(x < 0, 0.0, np.where(x > 1, x - 0.5, 0.5 * x**2))

    x = (T - mat.T_solidus) / span
    h = 0.5 * d / span
    return (ramp_integral(x + h) - ramp_integral(x - h)) / (2 * h)


def conductivities(T: np.ndarray, theta: dict[str, float], mat: AlloyProperties, *,
                   kvz_mode: str, anisotropy: str, w_vapour: float,
                   k_solid: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Lateral and vertical conductivity (W/(m K)) of the dense alloy, blended in log k.

    Solid ``K_S``; liquid ``K_L`` and ``K_Lz K_L``; vapour ``K_V`` and ``K_Vz K_V``
    (``K_Vz`` absolute with ``kvz_mode="absolute"``); the mushy zone is linear in
    ``f_l`` and the vapour switch is ``s_v = 0.5 (1 + tanh((T - T_b)/w_v))``.
    """
    fl = liquid_fraction(T, mat)
    sv = 0.5 * (1.0 + np.tanh((T - mat.T_boil) / w_vapour))
    kvz = theta["K_Vz"] if kvz_mode == "absolute" else theta["K_Vz"] * theta["K_V"]
    aniso_l, aniso_v = theta["K_Lz"], kvz / theta["K_V"]
    ks = theta["K_S"] if k_solid is None else k_solid
    plain = (ks, theta["K_L"], theta["K_V"])
    enhanced = (ks, theta["K_L"] * aniso_l, theta["K_V"] * aniso_v)

    def blend(ks: float, kl: float, kv: float) -> np.ndarray:
        log_k = (1 - fl) * np.log(ks) + fl * np.log(kl)
        return np.exp((1 - sv) * log_k + sv * np.log(kv))

    if anisotropy == "vertical":
        return blend(*plain), blend(*enhanced)
    return blend(*enhanced), blend(*plain)


def build_laws(theta: dict[str, float], mat: AlloyProperties, *, kvz_mode: str,
               anisotropy: str, w_vapour: float, k_powder: float) -> MaterialLaws:
    """Tabulate the laws for one parameter vector (a few ms)."""
    T = _grid()
    kw = dict(kvz_mode=kvz_mode, anisotropy=anisotropy, w_vapour=w_vapour)
    kx, kz = conductivities(T, theta, mat, **kw)
    # loose powder: k_p, sintering to the dense law between T_S - POWDER_RAMP and T_L
    x = np.clip((T - mat.T_solidus + POWDER_RAMP) / (mat.T_liquidus - mat.T_solidus
                                                     + POWDER_RAMP), 0.0, 1.0)
    w = x * x * (3 - 2 * x)
    px, pz = (np.exp((1 - w) * np.log(k_powder) + w * np.log(k)) for k in (kx, kz))
    fl = liquid_fraction(T, mat)
    cp = (1 - fl) * mat.cp_solid + fl * mat.cp_liquid
    dfl = np.gradient(fl, T)
    sensible, latent, enthalpy = (_from_ambient(Table.from_derivative(f), mat) for f in
                                  (cp, mat.latent_fusion * dfl, cp + mat.latent_fusion * dfl))
    return MaterialLaws(*(Table.from_derivative(k) for k in (kx, kz)), enthalpy,
                        *(Table.from_derivative(k) for k in (px, pz)), sensible, latent)


def _from_ambient(table: Table, mat: AlloyProperties) -> Table:
    """Shift ``F`` so that ``F(T_inf) = 0`` (cold inflow carries no enthalpy)."""
    f_inf, _ = table(np.array([mat.T_ambient]))
    return Table(f=table.f, F=table.F - f_inf[0])


def absorptivity_of_temperature(Ts: float, theta: dict[str, float], mat: AlloyProperties,
                                w_absorb: float) -> tuple[float, float]:
    """``A(T_s)`` and ``dA/dT_s`` (physics.md, absorptivity, default form)."""
    th = np.tanh((Ts - mat.T_boil) / w_absorb)
    span = theta["A_max"] - theta["A_0"]
    return theta["A_0"] + span * 0.5 * (1 + th), span * 0.5 * (1 - th**2) / w_absorb


SECANT_DT = 1e-3  # K, below this temperature difference a secant is the mean conductivity


def secant(T: np.ndarray, P: np.ndarray, N: np.ndarray, tab, ev
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Secant conductivity ``(Phi(T_N) - Phi(T_P)) / (T_N - T_P)`` of one law between
    the cells ``P`` and ``N``, and its derivatives by ``T_P`` and ``T_N``."""
    phi, k = ev
    d = T[N] - T[P]
    small = np.abs(d) < SECANT_DT
    safe = np.where(small, 1.0, d)
    ks = np.where(small, 0.5 * (k[P] + k[N]), (phi[N] - phi[P]) / safe)
    half = 0.25 * (tab.slope(T[P]) + tab.slope(T[N]))
    dsP = np.where(small, half, (ks - k[P]) / safe)
    dsN = np.where(small, half, (k[N] - ks) / safe)
    return ks, dsP, dsN
