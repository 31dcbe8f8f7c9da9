"""Keyword-only options of the melt-pool simulator, with documented defaults.

Choices that the reference study does not publish (docs/physics.md, *inferred*) are
options here; the default is the form stated in physics.md.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields
from typing import Any

from calnet.simulators.base import check_option_types

ABSORPTIVITY_LAWS = ("surface_temperature", "keyhole_depth")
KVZ_MODES = ("factor", "absolute")
ANISOTROPY_DIRECTIONS = ("vertical", "lateral")
STARTS = ("rosenthal", "ambient")
CONSOLIDATIONS = ("exposure", "field", "monotone")
MASS_FLUXES = ("conserved", "blended")


@dataclass(frozen=True)
class MeltPoolOptions:
    """Numerical and modelling options of :func:`calnet.simulators.melt_pool.simulate`.

    Parameters
    ----------
    resolution : float, default 1.0
        Mesh refinement factor: the pool-region spacing is divided by it and the far-field
        stretching ratio is raised to ``1/resolution`` (``2.0`` halves every spacing).
    absorptivity : {"surface_temperature", "keyhole_depth"}, default "surface_temperature"
        ``A = A_0 + (A_max - A_0) 0.5 (1 + tanh((T_s - T_b)/w_A))`` with ``T_s`` the
        reconstructed surface temperature at the beam centre, or the keyhole-depth form
        ``A = A_0 + (A_max - A_0) min(1, d_v / r_0)`` (``d_v`` depth of the ``T_b`` isotherm).
    kvz_mode : {"factor", "absolute"}, default "factor"
        ``"factor"``: vapour z-conductivity ``K_Vz * K_V`` (physics.md table);
        ``"absolute"``: ``K_Vz`` is the z-conductivity itself in W/(m K).
    anisotropy : {"vertical", "lateral"}, default "vertical"
        Which conductivity the factors ``K_Lz``/``K_Vz`` multiply: ``k_z`` (physics.md
        table, keyhole-like downward conduction) or ``k_x = k_y``.
    w_absorb : float, default 150.0
        Width ``w_A`` (K) of the absorptivity switch.
    w_vapour : float, default 75.0
        Width ``w_v`` (K) of the vapour switch ``s_v``.
    powder : bool, default True
        Model the 30 um powder layer (False: dense substrate up to the top surface).
    k_powder : float or None, default None
        Powder conductivity (W/(m K)); None uses the material constant (1.0).
    rtol : float, default 1e-6
        Convergence when ``max|R| / (A P / 2) <= rtol`` (R in W per cell) and the last
        temperature update is below ``ttol``.
    ttol : float, default 0.05
        Temperature-update tolerance (K).
    max_iter : int, default 500
        Newton iterations allowed over all stages (the continuation in power, the
        sizing pre-solve and the fine solve).
    max_update : float, default 800.0
        Cap on each cell's temperature update per Newton step (K).
    time_limit : float or None, default None
        Wall-clock limit (s); exceeding it returns status ``"timeout"``.
    adapt_mesh : bool, default True
        Re-mesh once around the computed pool if it left the fine region.
    continuation_ratio : float, default 1.5
        Largest ratio of consecutive laser powers in the continuation from a cold,
        conduction-mode solution (:func:`~.model.power_ladder`); must exceed 1.
    consolidation : {"exposure", "field", "monotone"}, default "exposure"
        How a solve treats the consolidated powder fraction ``frac(T)``
        (:mod:`~.consolidation`). ``"exposure"``: a cumulative exposure to heat along
        the material path strictly upstream of each column, a smooth function of the
        current field without maximum or memory, its exact coupling in the Newton
        operator, and faces between cells of different fractions with secant
        conductivities: the converged state solves ``R(T, frac(T)) = 0`` whatever the
        solver's path, so the outputs are a function of the inputs. Its Newton iteration
        halves updates that 2-cycle and the updates of powder cells that cycle with
        period 2-4 (:func:`~.solver._cycle_factor`). ``"field"``: ``frac(T)`` of the
        hottest point upstream in the current iterate, with its coupling; at most
        powder settings of the reference box the iteration cycles at the lateral edge
        of the consolidation front and does not converge.
        ``"monotone"``: the largest upstream-maximum ``frac(T)`` over the solve's
        iterates (each continuation stage starts afresh), so the front only advances;
        it converges, but the state depends on the iteration path by a few per cent.
    mass_flux : {"conserved", "blended"}, default "conserved"
        Mass flux of the powder layer along the laser's path: ``"conserved"``, the
        powder's bulk density whatever the consolidation (the energy equation
        ``rho_p v dH/dx`` of physics.md along each streamline); ``"blended"``, the
        density of each cell's consolidated fraction, so the flux grows where powder
        consolidates and the mass it gains enters at the ambient temperature's enthalpy,
        a heat sink at the consolidation front (narrower pools, most at the small,
        fast ones).
    refine_outputs : bool, default False
        Refine the final mesh where the outputs are read: the lateral spacing at the
        pool edge 1.25 um instead of 2.5 um (``W``) and the pool region's ``x`` spacing
        halved (the tail window of ``G0``); both scale with ``resolution``, and the
        sizing mesh is the default's. More cells than the default mesh and several
        times its CPU; for studies of the outputs' mesh dependence
        (benchmarks/README.md, "Mesh convergence").
    start : {"rosenthal", "ambient"}, default "rosenthal"
        Initial field of the first continuation stage: the beam-smeared Rosenthal field
        at that stage's power and ``A_0``, or the ambient temperature everywhere. The
        first stage has a single solution, so the outputs do not depend on it.
    """

    resolution: float = 1.0
    absorptivity: str = "surface_temperature"
    kvz_mode: str = "factor"
    anisotropy: str = "vertical"
    w_absorb: float = 150.0
    w_vapour: float = 75.0
    powder: bool = True
    k_powder: float | None = None
    rtol: float = 1e-6
    ttol: float = 0.05
    max_iter: int = 500
    max_update: float = 800.0
    time_limit: float | None = None
    adapt_mesh: bool = True
    continuation_ratio: float = 1.5
    start: str = "rosenthal"
    refine_outputs: bool = False
    consolidation: str = "exposure"
    mass_flux: str = "conserved"

    def __post_init__(self) -> None:
        checks = [
            ("absorptivity", self.absorptivity in ABSORPTIVITY_LAWS, ABSORPTIVITY_LAWS),
            ("kvz_mode", self.kvz_mode in KVZ_MODES, KVZ_MODES),
            ("anisotropy", self.anisotropy in ANISOTROPY_DIRECTIONS, ANISOTROPY_DIRECTIONS),
            ("start", self.start in STARTS, STARTS),
            ("consolidation", self.consolidation in CONSOLIDATIONS, CONSOLIDATIONS),
            ("mass_flux", self.mass_flux in MASS_FLUXES, MASS_FLUXES),
        ]
        for name, ok, allowed in checks:
            if not ok:
                raise ValueError(f"option {name}: expected one of {allowed}, "
                                 f"got {getattr(self, name)!r}")
        positive = ("resolution", "w_absorb", "w_vapour", "rtol", "ttol", "max_update")
        for name in positive:
            if not float(getattr(self, name)) > 0:
                raise ValueError(f"option {name}: expected a positive number, "
                                 f"got {getattr(self, name)!r}")
        if not float(self.continuation_ratio) > 1:
            raise ValueError("option continuation_ratio: expected a number > 1, "
                             f"got {self.continuation_ratio!r}")
        if int(self.max_iter) < 1:
            raise ValueError(f"option max_iter: expected >= 1, got {self.max_iter!r}")

    @classmethod
    def from_kwargs(cls, **kwargs: Any) -> MeltPoolOptions:
        """Build options, rejecting unknown names with the list of known ones."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(kwargs) - known)
        if unknown:
            raise TypeError(f"unknown melt_pool option(s) {unknown}; known: {sorted(known)}")
        check_option_types(cls, kwargs, "melt_pool")
        return cls(**kwargs)

    def to_dict(self) -> dict[str, Any]:
        """JSON-serialisable view (stored in the result diagnostics)."""
        return asdict(self)
