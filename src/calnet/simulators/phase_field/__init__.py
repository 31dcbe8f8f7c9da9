"""M2 as the reference study's own model: a 2D phase-field solver with finite interface
dissipation (``phase_field``; docs/physics.md, "M2, phase-field version").

Two phase concentrations and a solid fraction on a periodic-sided grid, explicit finite
differences in JAX (x64, jitted chunks of steps), frozen temperature
``T = T0 + G (y - S t)`` and a frame that follows the front. Inputs, parameters and units
are those of :mod:`calnet.simulators.solidification`; outputs are the spacing of the
steady cell array (domain width over the number of cells counted behind the tips), the
partition at the tip, the tip undercooling and a steady flag.

Examples
--------
>>> from calnet.simulators import phase_field
>>> res = phase_field.simulate({"S": 0.3, "G": 1e7}, nx=1, ny=64, max_steps=200)
>>> res.status, res.diagnostics["steps"]
('nonconverged', 200)
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

from calnet.simulators.base import InputValueError, SimResult, check_input_names
from calnet.simulators.phase_field.options import RESOLUTIONS, PhaseFieldOptions
from calnet.simulators.phase_field.outputs import summary
from calnet.simulators.phase_field.solver import PhysicalParameters, run
from calnet.simulators.solidification import BOUNDS as _M2_BOUNDS
from calnet.simulators.solidification import TO_SI

NAME = "phase_field"
VERSION = "0.4.0"
MAX_HALVINGS = 2
"""Times a diverged run starts again with half the time step before it is reported failed."""
INPUTS: tuple[str, ...] = ("S", "G")
PARAMETERS: tuple[str, ...] = ("sigma", "M", "p_int")
OUTPUTS: tuple[str, ...] = ("lambda", "k_V", "undercooling", "amplitude", "steady")
UNITS: dict[str, str] = {
    "S": "m/s", "G": "K/m", "sigma": "J/cm^2", "M": "cm^4/(J s)", "p_int": "cm^3/(J s)",
    "lambda": "um", "k_V": "1", "undercooling": "K", "amplitude": "um", "steady": "1",
}
BOUNDS: dict[str, tuple[float, float]] = dict(_M2_BOUNDS)

__all__ = ["BOUNDS", "INPUTS", "MAX_HALVINGS", "NAME", "OUTPUTS", "PARAMETERS", "RESOLUTIONS",
           "UNITS", "VERSION", "PhaseFieldOptions", "parameters", "simulate"]


def parameters(inputs: Mapping[str, float]) -> PhysicalParameters:
    """SI parameters from ``S``, ``G`` and optional ``sigma``, ``M``, ``p_int``
    (:data:`UNITS`; missing parameters default to the middle of :data:`BOUNDS`).

    Raises
    ------
    ValueError
        On a missing input or an unknown key; :class:`InputValueError` (a ValueError) on
        a value that is not finite and > 0.
    """
    check_input_names(NAME, inputs, INPUTS, PARAMETERS, UNITS)
    v = {k: float(inputs[k]) if k in inputs else 0.5 * sum(BOUNDS[k])
         for k in INPUTS + PARAMETERS}
    bad = {k: x for k, x in v.items() if not (math.isfinite(x) and x > 0)}
    if bad:
        raise InputValueError(f"{NAME}: {bad} must be finite and > 0")
    return PhysicalParameters(S=v["S"], G=v["G"], sigma=v["sigma"] * TO_SI["sigma"],
                              mobility=v["M"] * TO_SI["M"],
                              permeability=v["p_int"] * TO_SI["p_int"])


#: fewest cells across the domain for a measured spacing: with fewer, the periodic domain
#: sets lambda (one cell across is lambda = the domain's width)
MIN_CELLS = 2


def simulate(inputs: Mapping[str, float], *,
             progress: Callable[[float, str], None] | None = None,
             **options: Any) -> SimResult:
    """Run the phase-field model once.

    Parameters
    ----------
    inputs : mapping of str to float
        ``S`` (m/s), ``G`` (K/m) and optionally ``sigma``, ``M``, ``p_int``.
    progress : callable, optional
        Called after every chunk of steps with the fraction of the step budget spent and
        a line of text (``calnet simulate`` passes :meth:`calnet.progress.Lines.update`).
    **options
        See :class:`PhaseFieldOptions` (``resolution``, ``seed``, ``nx``, ``ny``,
        ``max_steps``, ...).

    Returns
    -------
    SimResult
        ``outputs``: ``lambda`` (um, domain width over the number of cells counted along
        rows 4-8 interface widths behind the leading tip,
        :func:`~calnet.simulators.phase_field.outputs.cell_count`), ``k_V``,
        ``undercooling`` (K), ``amplitude`` (um, of the dominant Fourier mode of the tip
        heights: how unevenly the tips lead) and ``steady`` (1.0), over the last
        ``window`` chunks. Status ``"ok"`` for a steady cell array; ``"nonconverged"``
        (outputs of the last window, ``steady`` 0.0) when the step budget ran out first;
        ``"failed"`` for fields that diverged even with the time step halved
        :data:`MAX_HALVINGS` times, a steady front that stayed flat (no spacing), or a
        domain that held fewer than :data:`MIN_CELLS` cells (its width, not the front, set
        the spacing). The message says which. ``diagnostics``: steps, simulated time (s),
        time step (s), ``dt_halvings`` (how often the step was halved after a divergence;
        the step budget grows with it, so the simulated time available stays the same),
        wall time (s, all attempts), tip speed (m/s), ``cells`` (the count), ``tip_mode`` and
        ``tip_wavelength_um`` (dominant mode of the tip heights and its wavelength),
        options.

    Raises
    ------
    ValueError
        On a missing or unknown input name or a bad option; a value the model cannot
        take (not finite and > 0) gives a ``"failed"`` result instead.
    """
    opts = PhaseFieldOptions.from_kwargs(**options)
    try:
        p = parameters(inputs)
    except InputValueError as err:  # a value the model cannot take: a failed run
        return SimResult({k: math.nan for k in OUTPUTS}, "failed", str(err),
                         {"options": opts.to_dict(), "version": VERSION})
    # the stable step covers diffusion and the phase field, not the anti-trapping current,
    # which can make the explicit step unstable at a high interface permeability: a run
    # whose fields diverge starts again with half the step, at most MAX_HALVINGS times
    wall = 0.0
    for halvings in range(MAX_HALVINGS + 1):
        rec = run(p, opts, dt_scale=0.5**halvings, progress=progress)
        wall += rec.wall_seconds
        if rec.status != "diverged" and rec.history:
            break
    diag: dict[str, Any] = {"steps": rec.steps, "simulated_time_s": rec.time, "dt_s": rec.dt,
                            "dt_halvings": halvings, "wall_seconds": wall,
                            "stop": rec.status, "options": opts.to_dict(), "version": VERSION}
    if rec.status == "diverged" or not rec.history:
        return SimResult({k: math.nan for k in OUTPUTS}, "failed",
                         f"{NAME}: the fields diverged (non-finite or out-of-range "
                         f"concentrations) after {rec.steps} steps at dt {rec.dt:.3g} s; "
                         "report it with the inputs and options", diag)
    s = summary(rec.history, opts.window)
    diag.update(tip_speed=s["tip_speed"], cells=s["cells"], tip_mode=s["mode"],
                tip_wavelength_um=s["wavelength"] * 1e6)
    out = {"lambda": s["spacing"] * 1e6, "k_V": s["k_V"],
           "undercooling": s["undercooling"], "amplitude": s["amplitude"] * 1e6,
           "steady": 1.0 if rec.status == "steady" else 0.0}
    if rec.status != "steady":
        return SimResult(out, "nonconverged", f"{NAME}: not steady within max_steps "
                         f"{opts.max_steps} ({rec.time * 1e6:.2f} us simulated); raise "
                         "max_steps", diag)
    if s["cells"] == 0:
        return SimResult(out, "failed", f"{NAME}: the front stayed flat (no cell array, so "
                         f"no spacing); k_V {s['k_V']:.3f}, undercooling "
                         f"{s['undercooling']:.2f} K", diag)
    if s["cells"] < MIN_CELLS:
        width = opts.nx * opts.dx * 1e6
        return SimResult(out, "failed", f"{NAME}: the domain ({width:.3g} um across) held "
                         f"{s['cells']:.2g} cells, so lambda is its width, not a spacing "
                         f"the front selected; widen it (nx) to hold at least {MIN_CELLS}",
                         diag)
    return SimResult(out, "ok", "", diag).checked(OUTPUTS)
