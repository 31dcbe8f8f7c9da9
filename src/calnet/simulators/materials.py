"""Material constants of the built-in simulators, each with its source.

All values are SI unless the name says otherwise. The reference alloy is Ni-5 wt% Nb
(Ni-3.2 at% Nb); for most thermophysical properties the handbook values of pure nickel
are used, as the reference study does (docs/physics.md, table "Ni-5 wt% Nb properties").

Sources
-------
[CRC]    Haynes (ed.), CRC Handbook of Chemistry and Physics, 97th ed. (2016):
         Ni density 8908 kg/m^3, boiling point 3186 K, heat of fusion 17.48 kJ/mol
         (= 2.98e5 J/kg with M = 58.69 g/mol).
[Mills]  Mills, Recommended Values of Thermophysical Properties for Selected Commercial
         Alloys, Woodhead (2002), Ni-base alloys: c_p ~ 0.55 kJ/(kg K) near the solidus,
         ~0.70 kJ/(kg K) in the liquid; total hemispherical emissivity of oxidised
         Ni alloys 0.3-0.4.
[NiNb]   Ni-Nb phase diagram (Massalski, Binary Alloy Phase Diagrams, 2nd ed., 1990):
         liquidus of Ni-5 wt% Nb ~1695 K, freezing range ~15 K.
[Powder] Rombouts et al., J. Appl. Phys. 98 (2005) 013533; Gusarov & Kruth, Int. J. Heat
         Mass Transf. 48 (2005) 3423: effective conductivity of metal powder beds in
         gas 0.1-2 W/(m K), packing fraction 0.5-0.6.
[Spec]   docs/physics.md (reference study set-up: 30 um powder layer, 40 um beam radius,
         h = 10 W/(m^2 K), T_inf = 300 K).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class AlloyProperties:
    """Thermophysical constants of the melt-pool model (SI units)."""

    rho: float = 8900.0  # kg/m^3, solid density, constant in the moving frame [CRC, Spec]
    cp_solid: float = 550.0  # J/(kg K) [Mills]
    cp_liquid: float = 700.0  # J/(kg K) [Mills]
    latent_fusion: float = 2.98e5  # J/kg [CRC]
    T_solidus: float = 1680.0  # K [NiNb, Spec]
    T_liquidus: float = 1695.0  # K [NiNb, Spec]
    T_boil: float = 3186.0  # K, boiling point of Ni [CRC]
    emissivity: float = 0.4  # 1 [Mills, Spec]
    h_conv: float = 10.0  # W/(m^2 K), free convection of the shielding gas [Spec]
    T_ambient: float = 300.0  # K [Spec]
    k_powder: float = 1.0  # W/(m K), loose powder bed [Powder]
    powder_packing: float = 0.55  # 1, powder density / solid density [Powder, Spec]
    powder_thickness: float = 30e-6  # m [Spec]
    substrate_thickness: float = 1e-3  # m [Spec]
    beam_radius: float = 40e-6  # m, 1/e^2 radius (80 um diameter) [Spec]


NI5NB = AlloyProperties()
"""Ni-5 wt% Nb, the reference alloy."""

STEFAN_BOLTZMANN = 5.670374419e-8  # W/(m^2 K^4), CODATA 2018
