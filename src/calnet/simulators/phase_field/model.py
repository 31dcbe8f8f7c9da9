"""Equations of the finite-interface-dissipation phase-field model (docs/physics.md, M2
phase-field version), as pure JAX functions of the fields.

Fields live on a cell-centred grid of shape ``(ny, nx)``: axis 0 is the growth direction
``y`` (no-flux top and bottom), axis 1 the lateral direction ``x`` (periodic). ``phi`` is
the solid (FCC, alpha) fraction, ``xs`` and ``xl`` the Nb mole fractions of the solid and
the liquid (beta) phase at each point. Units are SI; concentrations are mole fractions, so
the permeability ``P`` (m^3/(J s)) and the free energies (J/m^3) are consistent.

Free energies (dilute solution, fitted to ``k_e`` and ``m_l``)::

    f_l(x)    = A (x ln x - x)
    f_s(x, T) = A (x ln x - x - x ln k_e) + dS_v (T - T_m)
    A         = |m_l| dS_v / (1 - k_e)          (m_l per unit mole fraction)

so that ``mu_s = A ln(x_s / k_e)``, ``mu_l = A ln x_l``: equal chemical potentials give
``x_s = k_e x_l`` and equal grand potentials give the liquidus ``T = T_m + m_l x_l``.
``T_m`` is chosen so that the liquidus of ``c0`` is ``T0 = 1695 K``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import jax
import jax.numpy as jnp

from calnet.simulators.solidification import CONSTANTS as _M2

_PI2 = math.pi**2


@dataclass(frozen=True)
class PhaseFieldConstants:
    """Material constants, SI and mole fractions (physics.md M2; values shared with
    :data:`calnet.simulators.solidification.CONSTANTS`).

    Attributes
    ----------
    k_e : float
        Equilibrium partition coefficient.
    m_l : float
        Liquidus slope, K per unit mole fraction (``-10.3 K/at%`` times 100).
    c0 : float
        Alloy composition, mole fraction.
    T0 : float
        Liquidus temperature of ``c0``, K (physics.md: equilibrium at 1695 K).
    D_l, D_s : float
        Solute diffusivity in the liquid and the solid, m^2/s. ``D_s`` is not given by the
        reference; 1e-4 ``D_l`` makes solid diffusion negligible, as it is in Ni.
    dS_v : float
        Entropy of fusion per volume, J/(m^3 K).
    eta : float
        Interface width, m.
    """

    k_e: float = _M2.k_e
    m_l: float = _M2.m_l * 100.0
    c0: float = _M2.c0 / 100.0
    T0: float = 1695.0
    D_l: float = _M2.D_l
    D_s: float = _M2.D_l * 1e-4
    dS_v: float = _M2.dS_v
    eta: float = _M2.eta

    @property
    def A(self) -> float:
        """Prefactor of the dilute-solution free energies, J/m^3."""
        return abs(self.m_l) * self.dS_v / (1.0 - self.k_e)

    @property
    def T_m(self) -> float:
        """Melting point of the solvent implied by ``T0`` and ``m_l``, K."""
        return self.T0 - self.m_l * self.c0

    @property
    def freezing_range(self) -> float:
        """Equilibrium freezing range of ``c0``, ``|m_l| c0 (1 - k_e) / k_e``, K."""
        return abs(self.m_l) * self.c0 * (1.0 - self.k_e) / self.k_e


CONSTANTS = PhaseFieldConstants()


def chemical_potentials(xs: jax.Array, xl: jax.Array, c: PhaseFieldConstants):
    """``(mu_s, mu_l)``, J/m^3 per unit mole fraction, same shape as the inputs."""
    return c.A * jnp.log(xs / c.k_e), c.A * jnp.log(xl)


def driving_force(phi, xs, xl, T, c: PhaseFieldConstants) -> jax.Array:
    """Driving force ``dG`` (J/m^3) of the phase-field equation; negative favours solid.

    ``dG = f_s - f_l - (phi mu_s + (1 - phi) mu_l)(x_s - x_l)`` (Steinbach, Zhang & Plapp
    2012; Zhang & Steinbach 2012): the difference of the grand potentials taken at the
    phase-averaged chemical potential. It is unchanged when a common linear term is added
    to both free energies, and equals ``dS_v (T - T_liquidus(x_l))`` when ``x_s = k_e x_l``.
    """
    mu_s, mu_l = chemical_potentials(xs, xl, c)
    f_l = c.A * (xl * jnp.log(xl) - xl)
    f_s = c.A * (xs * jnp.log(xs) - xs - xs * math.log(c.k_e)) + c.dS_v * (T - c.T_m)
    return f_s - f_l - (phi * mu_s + (1.0 - phi) * mu_l) * (xs - xl)


def kinetic_coefficient(xs, xl, mobility, permeability, c: PhaseFieldConstants):
    """Kinetic coefficient ``K`` of physics.md eq. (4), m^4/(J s).

    ``K = 8 P eta mu / (8 P eta + mu pi^2 (x_s - x_l)^2)``: the interface mobility ``mu``
    reduced by the finite rate ``P`` of solute exchange across the interface.
    """
    a = 8.0 * permeability * c.eta
    return a * mobility / (a + mobility * _PI2 * (xs - xl) ** 2)


def neighbours(a: jax.Array):
    """``(x+, x-, y+, y-)`` neighbours: periodic in x (axis 1), mirrored in y (no flux)."""
    xp = jnp.roll(a, -1, axis=1)
    xm = jnp.roll(a, 1, axis=1)
    yp = jnp.concatenate([a[1:], a[-1:]], axis=0)
    ym = jnp.concatenate([a[:1], a[:-1]], axis=0)
    return xp, xm, yp, ym


def phase_rate(phi, xs, xl, T, sigma, mobility, permeability, dx, c: PhaseFieldConstants,
               coupling: str = "profile"):
    """``dphi/dt`` (1/s) with the double-obstacle potential, zero in the bulk.

    ``K { sigma [lap(phi) + (pi^2/eta^2)(phi - 1/2)] - g(phi) dG }`` on the cells of the
    interface and their neighbours; elsewhere the obstacle holds ``phi`` at 0 or 1.
    ``coupling="profile"`` (default) uses ``g = (pi/eta) sqrt(phi (1 - phi))`` (Steinbach
    et al.), ``"constant"`` the ``g = pi^2/(8 eta)`` of physics.md. Both integrate to the
    same front kinetics ``v = K dG`` across the equilibrium profile; the constant form
    turns undercooled liquid next to the interface solid wherever ``|dG| > 4 sigma/eta``
    (about 2.6 K of undercooling at sigma 2e-6 J/cm^2), which smears the interface at the
    undercoolings of rapid solidification.
    """
    nb = neighbours(phi)
    lap = (sum(nb) - 4.0 * phi) / dx**2
    hi = jnp.maximum(jnp.maximum(jnp.maximum(nb[0], nb[1]), jnp.maximum(nb[2], nb[3])), phi)
    lo = jnp.minimum(jnp.minimum(jnp.minimum(nb[0], nb[1]), jnp.minimum(nb[2], nb[3])), phi)
    active = (hi > 0.0) & (lo < 1.0)
    k = kinetic_coefficient(xs, xl, mobility, permeability, c)
    if coupling == "constant":
        g = _PI2 / (8.0 * c.eta)
    else:
        g = math.pi / c.eta * jnp.sqrt(jnp.clip(phi * (1.0 - phi), 0.0, None))
    rate = k * (sigma * (lap + _PI2 / c.eta**2 * (phi - 0.5))
                - g * driving_force(phi, xs, xl, T, c))
    return jnp.where(active, rate, 0.0)


def weighted_divergence(w: jax.Array, x: jax.Array, diffusivity: float, dx: float):
    """``div(w D grad x)`` with face weights ``min(w_i, w_j)`` (conservative), 1/s.

    The minimum keeps ``div(w D grad x) / w`` bounded by ``4 D max|dx| / dx^2`` where ``w``
    is small, so the explicit step stays stable at the edge of the interface.
    """
    total = jnp.zeros_like(x)
    for wn, xn in zip(neighbours(w), neighbours(x), strict=True):
        total = total + jnp.minimum(w, wn) * (xn - x)
    return diffusivity * total / dx**2


def antitrapping_divergence(phi, rate, xs, xl, coefficient: float, dx: float,
                            c: PhaseFieldConstants):
    """``-div(j_at)`` (1/s): the mixture's gain from the anti-trapping current.

    ``j_at = a eta (x_l - x_s) (1 - phi) (dphi/dt) n`` with ``n = -grad(phi)/|grad(phi)|``
    the unit normal pointing into the liquid and ``a`` the ``coefficient``. Fluxes live on
    cell faces: the face value of ``(x_l - x_s)(1 - phi) dphi/dt`` is the mean of its two
    cells, the normal component of ``grad(phi)`` is the difference across the face and
    the tangential one the mean of the two cells' central differences. Periodic in x,
    no flux through the top and bottom.

    Across a steady planar front ``integral j_at / (D_l (1 - phi)) dz`` is
    ``a eta V (1 - k_e) x_l / D_l`` for any monotone profile, and the diffuse interface's
    own excess of ``x_l`` between ``phi = 1/2`` and the solid edge is
    ``(1 - k_e) V eta x_l / (2 D_l)`` to first order, so ``a = 1/2`` cancels it.

    Parameters
    ----------
    phi, rate, xs, xl : jax.Array, shape (ny, nx)
        Solid fraction, its rate of change (1/s) and the phase concentrations.
    coefficient : float
        ``a``.
    dx : float
        Grid spacing, m.
    """
    g = (xl - xs) * (1.0 - phi) * rate
    xp, xm, yp, ym = neighbours(phi)
    cx = (xp - xm) / (2.0 * dx)
    cy = (yp - ym) / (2.0 * dx)

    def face(gn, gt, g_next):
        norm = jnp.sqrt(gn**2 + gt**2)
        safe = jnp.where(norm > 1e-6 / dx, norm, 1.0)
        return jnp.where(norm > 1e-6 / dx, -gn / safe, 0.0) * 0.5 * (g + g_next)

    fx = face((xp - phi) / dx, 0.5 * (cy + jnp.roll(cy, -1, axis=1)), jnp.roll(g, -1, axis=1))
    g_up = jnp.concatenate([g[1:], g[-1:]], axis=0)
    fy = face((yp - phi) / dx, 0.5 * (cx + jnp.concatenate([cx[1:], cx[-1:]], axis=0)), g_up)
    fy = fy.at[-1].set(0.0)  # no flux through the top
    fy_below = jnp.concatenate([jnp.zeros_like(fy[:1]), fy[:-1]], axis=0)
    scale = coefficient * c.eta / dx
    return -scale * (fx - jnp.roll(fx, 1, axis=1) + fy - fy_below)


def step(phi, xs, xl, T, sigma, mobility, permeability, dt, dx, c: PhaseFieldConstants,
         coupling: str = "profile", antitrapping: float = 0.0):
    """One explicit Euler step of the three fields; returns ``(phi, xs, xl)``.

    Concentrations (physics.md, divided by the phase fractions, evaluated with the new
    ``phi`` so that the mixture ``phi x_s + (1 - phi) x_l`` is conserved exactly)::

        dx_s/dt = div(phi D_s grad x_s)/phi + P (1 - phi)(mu_l - mu_s) + phi_t (x_l - x_s)
        dx_l/dt = div((1-phi) D_l grad x_l)/(1-phi) + P phi (mu_s - mu_l) + phi_t (x_l - x_s)

    With ``antitrapping`` (the coefficient ``a``, 0 for none) the mixture also gains
    ``-div(j_at)`` (:func:`antitrapping_divergence`, with the new ``phi`` and its rate),
    shared between ``x_s`` and ``x_l`` in their local ratio so that the exchange term is
    not disturbed and the mixture stays conserved.

    In pure bulk cells the absent phase is kept at its equilibrium partner
    (``x_s = k_e x_l`` in the liquid, ``x_l = x_s / k_e`` in the solid).
    """
    rate = phase_rate(phi, xs, xl, T, sigma, mobility, permeability, dx, c, coupling)
    new = jnp.clip(phi + dt * rate, 0.0, 1.0)
    dphi = new - phi
    liq = 1.0 - new
    div_s = weighted_divergence(new, xs, c.D_s, dx) / jnp.where(new > 0, new, 1.0)
    div_l = weighted_divergence(liq, xl, c.D_l, dx) / jnp.where(liq > 0, liq, 1.0)
    exchange = exchange_integral(new, xs, xl, permeability, dt, c)
    xs_new = xs + dt * div_s + liq * exchange + dphi * (xl - xs)
    xl_new = xl + dt * div_l - new * exchange + dphi * (xl - xs)
    if antitrapping:
        gain = dt * antitrapping_divergence(new, dphi / dt, xs, xl, antitrapping, dx, c)
        ratio = xs / xl
        dxl = gain / (new * ratio + liq)
        xs_new = xs_new + ratio * dxl
        xl_new = xl_new + dxl
    xs_new = jnp.where(new <= 0.0, c.k_e * xl_new, xs_new)
    xl_new = jnp.where(new >= 1.0, xs_new / c.k_e, xl_new)
    return new, jnp.clip(xs_new, 1e-8, 0.5), jnp.clip(xl_new, 1e-8, 0.5)


def exchange_integral(phi, xs, xl, permeability, dt, c: PhaseFieldConstants):
    """``integral of P (mu_l - mu_s) dt`` over one step, per unit phase fraction.

    Solute exchange across the interface is stiff (rate ``P A (phi/x_l + (1-phi)/x_s)``,
    about 3e9 1/s, ten times faster than diffusion on a 5 nm grid), so it is integrated
    exactly for the linearised decay of ``d = mu_l - mu_s``:
    ``P d (1 - exp(-r dt)) / r``. The solid gains ``(1 - phi)`` times it and the liquid
    loses ``phi`` times it, which conserves the mixture and cannot overshoot.
    """
    mu_s, mu_l = chemical_potentials(xs, xl, c)
    r = permeability * c.A * (phi / xl + (1.0 - phi) / xs)
    return permeability * (mu_l - mu_s) * -jnp.expm1(-r * dt) / r


def stable_time_step(sigma, mobility, dx, c: PhaseFieldConstants, *,
                     safety: float = 0.8) -> float:
    """Largest stable explicit step (s): diffusion ``dx^2/(4 D_l)`` and phase field
    ``dx^2/(4 mu sigma)`` (``K <= mu``), times ``safety``. (Solute exchange is integrated
    exactly, :func:`exchange_integral`, and sets no limit.)"""
    return safety * min(dx**2 / (4.0 * c.D_l), dx**2 / (4.0 * mobility * sigma))
