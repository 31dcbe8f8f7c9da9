"""Keyword-only options of the phase-field simulator, with documented defaults."""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace
from typing import Any

from calnet.simulators.base import check_option_types

#: Named resolutions: grid spacing (m), domain width and height (cells), step budget.
RESOLUTIONS: dict[str, dict[str, float]] = {
    "default": {"dx": 5e-9, "nx": 384, "ny": 128, "max_steps": 40000},
    "fine": {"dx": 2.5e-9, "nx": 768, "ny": 256, "max_steps": 160000},
    "xfine": {"dx": 1.25e-9, "nx": 1536, "ny": 512, "max_steps": 640000},
}


@dataclass(frozen=True)
class PhaseFieldOptions:
    """Numerical options of :func:`calnet.simulators.phase_field.simulate`.

    Parameters
    ----------
    resolution : {"default", "fine", "xfine"}, default "default"
        All on the same 1.92 x 0.64 um domain. ``"default"``: 5 nm cells (4 across the
        20 nm interface), about a minute per run on 2 CPU cores, under a second on an
        H200 GPU. ``"fine"``: 2.5 nm cells, 16 times the work (about 12 min per run on
        one core, 1-5 s on an H200). ``"xfine"``: 1.25 nm cells, 16 times ``"fine"``,
        for an accelerator (8-39 s per run on an H200 from 0.15 to 0.6 m/s; hours on a
        CPU). Measured costs and what each resolution gives: benchmarks/README.md. The
        fields below override the preset.
    dx : float or None
        Grid spacing, m.
    nx, ny : int or None
        Cells across (periodic, x) and along the growth direction (y).
    max_steps : int or None
        Step budget; a run not steady by then is reported ``"nonconverged"``.
    seed : int, default 0
        Seed of the random interface perturbation (same seed, same result).
    noise_cell : float, default 5e-9
        Width of the perturbation's cells, m. The initial front height is drawn once per
        noise cell, the whole number of them nearest to ``nx dx / noise_cell`` across the
        domain, and is constant within one; so grids of different spacing over one domain
        start from the same front. The default is the ``default`` preset's cell, on
        which every grid cell has its own draw.
    amplitude : float, default 1.0
        Amplitude of the perturbation, in noise cells (0 gives a flat front).
    initial_cells : int, default 0
        When > 0, a cosine with this many periods across the domain, of twice the noise's
        amplitude, is added to the random heights: the front starts as an array of that
        many cells, a way to ask whether an array of a given spacing is stable.
    front_row : float, default 0.6
        Fraction of ``ny`` at which the moving frame holds the front tip.
    chunk_cells : float, default 8.0
        Steps are taken in jitted chunks during which the isotherms move this many cells;
        the frame shifts and the front is measured between chunks.
    window : int, default 12
        The outputs are means over the last ``window`` chunks (the spacing: the domain
        width over the mean cell count).
    start : {"solidus", "equilibrium"}, default "solidus"
        Initial state: a flat front at the solidus isotherm of ``c0`` with the planar
        steady boundary layer ahead, or the reference's equilibrium start (front at the
        liquidus ``T0``, solid ``k_e c0``, liquid ``c0``).
    coupling : {"profile", "constant"}, default "profile"
        How the driving force enters the phase-field equation
        (:func:`calnet.simulators.phase_field.model.phase_rate`).
    antitrapping : float, default 0.5
        Coefficient ``a`` of the anti-trapping current
        (:func:`calnet.simulators.phase_field.model.antitrapping_divergence`); 0.5 cancels
        the diffuse interface's own solute trapping to first order in ``V eta / D_l``, 0
        gives the reference's equations as written (docs/physics.md).
    min_travel : float, default 2.0
        Minimum isotherm travel before a steady state is accepted, in units of the
        freezing-range length ``dT0 / G`` (1.5 um at 1e7 K/m).
    steady_travel : float, default 1.0
        Isotherm travel, in freezing-range lengths, over which the mean cell count (within
        5 %), the tip speed and the undercooling must have stayed constant for the front
        to count as steady (``calnet.simulators.phase_field.outputs.steady``); the window
        ends at the last chunk and may overlap ``min_travel``.
    """

    resolution: str = "default"
    dx: float | None = None
    nx: int | None = None
    ny: int | None = None
    max_steps: int | None = None
    seed: int = 0
    noise_cell: float = 5e-9
    amplitude: float = 1.0
    initial_cells: int = 0
    front_row: float = 0.6
    chunk_cells: float = 8.0
    window: int = 12
    min_travel: float = 2.0
    steady_travel: float = 1.0
    coupling: str = "profile"
    antitrapping: float = 0.5
    start: str = "solidus"

    def __post_init__(self) -> None:
        if self.resolution not in RESOLUTIONS:
            raise ValueError(f"resolution must be one of {sorted(RESOLUTIONS)}, got "
                             f"{self.resolution!r}")
        preset = RESOLUTIONS[self.resolution]
        for name in ("dx", "nx", "ny", "max_steps"):
            if getattr(self, name) is None:
                value = preset[name] if name == "dx" else int(preset[name])
                object.__setattr__(self, name, value)
        if not (self.dx > 0 and self.nx >= 1 and self.ny >= 16 and self.max_steps >= 1):
            raise ValueError(f"need dx > 0, nx >= 1, ny >= 16 and max_steps >= 1, got dx="
                             f"{self.dx}, nx={self.nx}, ny={self.ny}, max_steps="
                             f"{self.max_steps}")
        if self.start not in ("solidus", "equilibrium"):
            raise ValueError(f"start must be 'solidus' or 'equilibrium', got {self.start!r}")
        if self.coupling not in ("profile", "constant"):
            raise ValueError(f"coupling must be 'profile' or 'constant', got {self.coupling!r}")
        if not (0.0 <= self.antitrapping <= 2.0):
            raise ValueError(f"antitrapping must be in [0, 2], got {self.antitrapping}")
        if not 0.3 <= self.front_row <= 0.9:
            raise ValueError(f"front_row must be in [0.3, 0.9], got {self.front_row}")
        if self.window < 3 or self.chunk_cells <= 0 or self.amplitude < 0:
            raise ValueError("need window >= 3, chunk_cells > 0 and amplitude >= 0")
        if self.initial_cells < 0 or 2 * self.initial_cells > self.nx:
            raise ValueError(f"initial_cells must be in [0, nx/2] = [0, {self.nx // 2}], got "
                             f"{self.initial_cells}")
        if not self.noise_cell > 0:
            raise ValueError(f"need noise_cell > 0 (m), got {self.noise_cell}")
        if not (self.min_travel >= 0 and self.steady_travel > 0):
            raise ValueError(f"need min_travel >= 0 and steady_travel > 0, got "
                             f"{self.min_travel} and {self.steady_travel}")

    @classmethod
    def from_kwargs(cls, **kwargs: Any) -> PhaseFieldOptions:
        """Build from keyword options, naming any unknown one."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(kwargs) - known)
        if unknown:
            raise ValueError(f"unknown phase_field options {unknown}; expected some of "
                             f"{sorted(known)}")
        check_option_types(cls, kwargs, "phase_field")
        floats = {f.name for f in fields(cls) if str(f.type).startswith("float")}
        return cls(**{k: float(v) if k in floats and v is not None else v
                      for k, v in kwargs.items()})

    def with_(self, **changes: Any) -> PhaseFieldOptions:
        """A copy with ``changes``."""
        return replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)
