"""M2, the solidification microstructure simulator (``solidification``).

Kurz-Fisher primary dendrite arm spacing with rapid-solidification corrections, for
Ni-3.2 at% Nb, as specified in ``docs/physics.md`` section M2:

- Gibbs-Thomson coefficient ``Gamma = sigma / dS_v`` from the interface energy ``sigma``;
- Aziz continuous-growth solute trapping ``k_V(V)`` with a diffusive speed ``V_D`` built
  from the interface permeability ``p_int``;
- velocity-dependent liquidus slope ``m_V`` and freezing range ``dT0_V``;
- kinetic undercooling ``dT_k = V / mu_k`` with ``mu_k = M dS_v`` from the interface
  mobility ``M``, entering the spacing through ``sqrt(max(1 - dT_k / dT0_V, 0.05))``.

Everything is vectorised: :func:`simulate_batch` broadcasts NumPy arrays, and
:func:`simulate` is the one-point adapter to :class:`calnet.simulators.base.SimResult`.

Variants
--------
``"A"`` (default)
    The model above.
``"B"``
    Closer to a diffuse-interface (phase-field) model: trapping across the finite interface
    is added, ``1/V_D = 1/V_D,P + 1/(1.3 D_l / eta)``, and the kinetic factor is dropped
    (so ``M`` has no effect on ``lambda`` or ``k_V`` in this variant).

Planar-front convention
-----------------------
The front is flagged planar, never silently, when ``V >= V_a = D_l dT0_V / (k_V Gamma)``
(absolute stability) or, in variant A, when the kinetic factor ``1 - dT_k / dT0_V`` reaches
its floor 0.05. Outputs always include ``planar`` (``True``/``False`` in
:func:`simulate_batch`, ``1.0``/``0.0`` in :func:`simulate`), with the reason in
``planar_absolute`` / ``planar_kinetic``. ``lambda`` is *not* replaced by NaN or zero for
planar cases: it stays the finite formula value. The floor keeps it finite and continuous
across the planar boundary, which a Gaussian-process surrogate needs; downstream code that
wants to exclude planar runs must use the flag. A planar run still has status ``"ok"``.

Units
-----
Inputs and parameters are in the reference units of the case study (:data:`UNITS`):
``S`` m/s, ``G`` K/m, ``sigma`` J/cm^2, ``M`` cm^4/(J s), ``p_int`` cm^3/(J s). They are
converted to SI once, by :func:`parameters_to_si` (factors in :data:`TO_SI`); all internal
quantities are SI, and ``lambda`` is returned in micrometres.

Examples
--------
>>> out = simulate_batch(0.3, 1e7, 2e-6, 7.5, 15000.0)
>>> round(float(out["lambda"]), 2), round(float(out["k_V"]), 3), bool(out["planar"])
(0.27, 0.715, False)
>>> simulate({"S": 0.3, "G": 1e7}).status
'ok'
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from calnet.simulators.base import SimResult, check_input_names


@dataclass(frozen=True)
class SolidificationConstants:
    """Material and model constants of M2, SI units (physics.md M2).

    Attributes
    ----------
    k_e : float
        Equilibrium partition coefficient, ``2.2 / 3.2`` (solidus / liquidus Nb content at
        the Ni-rich liquidus, Ni-Nb phase diagram; value of the reference study). Used as
        given, not derived from ``m_l``.
    m_l : float
        Equilibrium liquidus slope, K per at% Nb (reference study).
    c0 : float
        Nominal alloy composition, at% Nb (Ni-5 wt% Nb = Ni-3.2 at% Nb).
    D_l : float
        Solute diffusivity in the liquid, m^2/s (typical liquid-metal value, reference study).
    dS_v : float
        Entropy of fusion per unit volume, J/(m^3 K): ``rho L_f / T_m`` with
        rho 8900 kg/m^3, L_f 2.98e5 J/kg (physics.md M1 table) and T_m 1728 K (pure Ni).
    f_pp : float
        Curvature of the liquid free energy with composition, J/m^3 (reference study's
        finite-interface-dissipation phase-field model).
    eta : float
        Diffuse-interface width, m (same phase-field model).
    kf_prefactor : float
        Kurz-Fisher prefactor (Kurz & Fisher 1981, Acta Metall. 29, 11).
    kinetic_floor : float
        Floor of ``1 - dT_k / dT0_V`` (physics.md M2); reaching it flags a planar front.
    interface_trapping : float
        Factor ``a`` of the interface diffusive speed ``a D_l / eta`` in variant B.
    """

    k_e: float = 2.2 / 3.2
    m_l: float = -10.3
    c0: float = 3.2
    D_l: float = 3e-9
    dS_v: float = 1.535e6
    f_pp: float = 8.2e10
    eta: float = 20e-9
    kf_prefactor: float = 4.3
    kinetic_floor: float = 0.05
    interface_trapping: float = 1.3


CONSTANTS = SolidificationConstants()

NAME = "solidification"
VERSION = "1.0.0"
INPUTS: tuple[str, ...] = ("S", "G")
PARAMETERS: tuple[str, ...] = ("sigma", "M", "p_int")
OUTPUTS: tuple[str, ...] = ("lambda", "k_V", "planar")
VARIANTS: tuple[str, ...] = ("A", "B")

UNITS: dict[str, str] = {
    "S": "m/s",
    "G": "K/m",
    "sigma": "J/cm^2",
    "M": "cm^4/(J s)",
    "p_int": "cm^3/(J s)",
    "lambda": "um",
    "k_V": "1",
    "planar": "1",
}

#: Reference design bounds (method.md section 1), in :data:`UNITS`.
BOUNDS: dict[str, tuple[float, float]] = {
    "S": (0.05, 0.60),
    "G": (7e6, 1.5e7),
    "sigma": (6e-7, 4e-6),
    "M": (4.0, 11.0),
    "p_int": (5000.0, 30000.0),
}

#: Multiply a parameter in :data:`UNITS` by this to get SI (physics.md M2, unit conversions):
#: 1 J/cm^2 = 1e4 J/m^2, 1 cm^4 = 1e-8 m^4, 1 cm^3 = 1e-6 m^3.
TO_SI: dict[str, float] = {"sigma": 1e4, "M": 1e-8, "p_int": 1e-6}

_M_TO_UM = 1e6


def parameters_to_si(
    sigma: ArrayLike, M: ArrayLike, p_int: ArrayLike
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Convert the calibration parameters from reference units to SI.

    Parameters
    ----------
    sigma : array_like
        Interface energy, J/cm^2.
    M : array_like
        Interface mobility, cm^4/(J s).
    p_int : array_like
        Interface permeability, cm^3/(J s).

    Returns
    -------
    sigma_si, M_si, P_si : ndarray
        J/m^2, m^4/(J s) and m^3/(J s), same shapes as the inputs.
    """
    return (
        np.asarray(sigma, dtype=float) * TO_SI["sigma"],
        np.asarray(M, dtype=float) * TO_SI["M"],
        np.asarray(p_int, dtype=float) * TO_SI["p_int"],
    )


def _check_positive(**arrays: np.ndarray) -> None:
    """Raise ``ValueError`` naming the first argument that is not finite and > 0."""
    for name, a in arrays.items():
        bad = ~(np.isfinite(a) & (a > 0))
        if np.any(bad):
            first = float(a[bad].flat[0])
            where = (f" at {int(bad.sum())} of {a.size} points; fix or drop those points"
                     if a.size > 1 else "")
            raise ValueError(f"{name} must be finite and > 0 (in {UNITS[name]}), got "
                             f"{first:g}{where}")


def _diffusive_speed(P_si: np.ndarray, variant: str, c: SolidificationConstants) -> np.ndarray:
    """Diffusive speed V_D (m/s) from the interface permeability P (m^3/(J s))."""
    v_d = P_si * c.eta * c.f_pp / 8.0  # physics.md M2: V_D = P eta f'' / 8
    if variant == "B":
        # physics.md M2 variant B: 1/V_D = 1/V_D,P + 1/(1.3 D_l / eta)
        v_d = 1.0 / (1.0 / v_d + c.eta / (c.interface_trapping * c.D_l))
    return v_d


def simulate_batch(
    S: ArrayLike,
    G: ArrayLike,
    sigma: ArrayLike,
    M: ArrayLike,
    p_int: ArrayLike,
    *,
    variant: str = "A",
    constants: SolidificationConstants = CONSTANTS,
) -> dict[str, np.ndarray]:
    """Run M2 on many points at once (physics.md M2).

    Parameters
    ----------
    S : array_like
        Growth (solidification) speed V, m/s.
    G : array_like
        Temperature gradient, K/m.
    sigma : array_like
        Interface energy, J/cm^2.
    M : array_like
        Interface mobility, cm^4/(J s).
    p_int : array_like
        Interface permeability, cm^3/(J s).
    variant : {"A", "B"}, keyword-only
        ``"A"`` the default model; ``"B"`` adds interface trapping and drops the kinetic
        factor (see the module docstring).
    constants : SolidificationConstants, keyword-only
        Material constants, SI (default :data:`CONSTANTS`).

    Returns
    -------
    dict of str to ndarray
        All arrays have the broadcast shape of the five arguments.
        ``lambda`` primary spacing (um), finite also for planar fronts;
        ``k_V`` partition coefficient (1); ``planar`` bool;
        ``planar_absolute`` (``V >= V_a``) and ``planar_kinetic`` (kinetic floor) bool;
        ``Gamma`` (K m); ``V_D``, ``V_a`` (m/s); ``m_V`` (K/at%); ``dT0_V``, ``dT_k`` (K);
        ``kinetic_factor`` (1, the square-root factor, all ones in variant B).

    Raises
    ------
    ValueError
        If an argument is not finite and strictly positive, or ``variant`` is unknown.
    """
    if variant not in VARIANTS:
        raise ValueError(f"variant must be one of {VARIANTS}, got {variant!r}")
    V, G_, sig, M_, p = np.broadcast_arrays(
        *(np.asarray(a, dtype=float) for a in (S, G, sigma, M, p_int))
    )
    _check_positive(S=V, G=G_, sigma=sig, M=M_, p_int=p)
    sig_si, M_si, P_si = parameters_to_si(sig, M_, p)
    c = constants

    gamma = sig_si / c.dS_v  # Gibbs-Thomson coefficient, K m
    v_d = _diffusive_speed(P_si, variant, c)
    r = V / v_d
    k_v = (c.k_e + r) / (1.0 + r)  # Aziz (1982) continuous growth
    one_minus_k = (1.0 - c.k_e) / (1.0 + r)  # = 1 - k_V, without cancellation as V >> V_D
    # Velocity-dependent liquidus slope (Aziz & Kaplan 1988), physics.md M2
    m_v = c.m_l * (1.0 + (c.k_e - k_v * (1.0 - np.log(k_v / c.k_e))) / (1.0 - c.k_e))
    dt0 = np.abs(m_v) * c.c0 * one_minus_k / k_v  # freezing range dT0_V, K
    dt_k = V / (M_si * c.dS_v)  # kinetic undercooling dT_k = V / mu_k, mu_k = M dS_v
    v_a = c.D_l * dt0 / (k_v * gamma)  # absolute stability speed, m/s

    if variant == "A":
        raw = 1.0 - dt_k / dt0
        planar_kinetic = raw <= c.kinetic_floor
        kinetic = np.sqrt(np.maximum(raw, c.kinetic_floor))
    else:
        planar_kinetic = np.zeros(V.shape, dtype=bool)
        kinetic = np.ones(V.shape)
    # Kurz-Fisher (1981) primary spacing with the kinetic factor, physics.md M2
    lam = (c.kf_prefactor * (dt0 * c.D_l * gamma / k_v) ** 0.25 * V**-0.25 * G_**-0.5
           * kinetic)
    planar_absolute = V >= v_a
    return {
        "lambda": lam * _M_TO_UM,
        "k_V": k_v,
        "planar": planar_absolute | planar_kinetic,
        "planar_absolute": planar_absolute,
        "planar_kinetic": planar_kinetic,
        "Gamma": gamma,
        "V_D": v_d,
        "V_a": v_a,
        "m_V": m_v,
        "dT0_V": dt0,
        "dT_k": dt_k,
        "kinetic_factor": kinetic,
    }


def midpoint(name: str) -> float:
    """Arithmetic midpoint of :data:`BOUNDS` for ``name``, in :data:`UNITS`."""
    lo, hi = BOUNDS[name]
    return 0.5 * (lo + hi)


def simulate(inputs: Mapping[str, float], *, variant: str = "A") -> SimResult:
    """Run M2 at one point; the :class:`~calnet.simulators.base.Simulator` protocol.

    Parameters
    ----------
    inputs : mapping of str to float
        Must hold the control inputs ``S`` (m/s) and ``G`` (K/m); may hold ``sigma``,
        ``M``, ``p_int`` (:data:`UNITS`), each defaulting to the midpoint of
        :data:`BOUNDS`.
    variant : {"A", "B"}, keyword-only
        Model variant, see the module docstring.

    Returns
    -------
    SimResult
        ``outputs`` ``lambda`` (um), ``k_V`` and ``planar`` (1.0 or 0.0); ``diagnostics``
        the planar flag and its reasons, the intermediate quantities (SI) and the
        parameter values used, and ``planar_reason`` (a sentence, empty when cellular). A
        planar front is status ``"ok"``. Non-physical values (not finite or <= 0) give status
        ``"failed"`` with a message, not an exception.

    Raises
    ------
    ValueError
        If ``S`` or ``G`` is missing, a key is unknown (a typo would otherwise silently
        fall back to a default), or ``variant`` is unknown.
    """
    check_input_names(NAME, inputs, INPUTS, PARAMETERS, UNITS)
    if variant not in VARIANTS:
        raise ValueError(f"variant must be one of {VARIANTS}, got {variant!r}")
    values = {k: float(inputs[k]) if k in inputs else midpoint(k) for k in INPUTS + PARAMETERS}
    try:
        out = simulate_batch(**values, variant=variant)
    except ValueError as err:
        return SimResult({}, "failed", f"{NAME}: {err}", {"parameters": values})
    scalars = {k: v.item() for k, v in out.items()}
    outputs = {"lambda": scalars["lambda"], "k_V": scalars["k_V"],
               "planar": 1.0 if scalars["planar"] else 0.0}
    diagnostics = {"variant": variant, "parameters": values, **scalars,
                   "planar_reason": _planar_reason(scalars)}
    return SimResult(outputs, "ok", "", diagnostics).checked(OUTPUTS)


def _planar_reason(s: Mapping[str, float]) -> str:
    """Human-readable reason for a planar flag (empty when the front is cellular)."""
    reasons = []
    if s["planar_absolute"]:
        reasons.append(f"V >= V_a = {s['V_a']:.3g} m/s (absolute stability)")
    if s["planar_kinetic"]:
        reasons.append(f"kinetic factor at its floor (dT_k {s['dT_k']:.3g} K vs "
                       f"dT0_V {s['dT0_V']:.3g} K)")
    if not reasons:
        return ""
    return "planar front: " + "; ".join(reasons) + "; lambda is the finite formula value"


__all__ = [
    "BOUNDS", "CONSTANTS", "INPUTS", "NAME", "OUTPUTS", "PARAMETERS", "TO_SI", "UNITS",
    "VARIANTS", "VERSION", "SolidificationConstants", "midpoint", "parameters_to_si",
    "simulate", "simulate_batch",
]
