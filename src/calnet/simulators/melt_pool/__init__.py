"""M1, the built-in melt-pool thermal simulator (docs/physics.md, section M1).

Steady 3D finite-volume conduction in the laser's frame with phase-dependent
anisotropic conductivity, temperature-dependent absorptivity, latent heat through
enthalpy advection and a 30 um powder layer consolidated by its cumulative exposure to
heat upstream along the material's path (a function of the temperature field, without
iteration memory); Newton with the exact Jacobian (Kirchhoff potentials),
pseudo-transient continuation and AMG-preconditioned GMRES on a mesh fine around the
pool and stretched outside. Each run continues in laser power from
a cold, conduction-mode solution, so it returns the steady state a track started on
cold material reaches: the conduction branch wherever it exists.

Examples
--------
>>> from calnet.simulators import melt_pool
>>> res = melt_pool.simulate({"P": 150.0, "v": 0.8}, resolution=0.5)
>>> res.status, sorted(res.outputs) == sorted(melt_pool.OUTPUTS)
('ok', True)
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from calnet.simulators.base import SimResult, check_input_names
from calnet.simulators.melt_pool.model import run
from calnet.simulators.melt_pool.options import MeltPoolOptions

NAME = "melt_pool"
VERSION = "0.15.0"
INPUTS = ("P", "v")
PARAMETERS = ("K_S", "K_L", "K_Lz", "K_V", "K_Vz", "A_0", "A_max")
OUTPUTS = ("D", "W", "L", "T0", "S0", "G0")
UNITS: dict[str, str] = {
    "P": "W", "v": "m/s",
    "K_S": "W/(m K)", "K_L": "W/(m K)", "K_Lz": "1", "K_V": "W/(m K)",
    "K_Vz": "1",  # a factor on K_V by default; W/(m K) with kvz_mode="absolute"
    "A_0": "1", "A_max": "1",
    "D": "um", "W": "um", "L": "um", "T0": "K", "S0": "m/s", "G0": "K/m",
}
BOUNDS: dict[str, tuple[float, float]] = {  # method.md section 1, reference study
    "P": (80.0, 250.0), "v": (0.05, 2.0),
    "K_S": (60.0, 100.0), "K_L": (100.0, 200.0), "K_Lz": (0.5, 1.5), "K_V": (5.0, 20.0),
    "K_Vz": (1000.0, 2000.0), "A_0": (0.25, 0.4), "A_max": (0.6, 0.8),
}

__all__ = ["BOUNDS", "INPUTS", "NAME", "OUTPUTS", "PARAMETERS", "UNITS", "VERSION",
           "MeltPoolOptions", "simulate"]


def _check_inputs(inputs: Mapping[str, float]
                  ) -> tuple[float, float, dict[str, float], str | None]:
    """``P``, ``v``, the parameters and, for values the model cannot take, a message
    (the names are checked first: a missing or unknown name raises ValueError)."""
    check_input_names(NAME, inputs, INPUTS, PARAMETERS, UNITS)
    values = {k: float(inputs[k]) for k in inputs}
    theta = {k: values.get(k, 0.5 * sum(BOUNDS[k])) for k in PARAMETERS}
    bad = [k for k, x in values.items() if not math.isfinite(x) or x <= 0]
    if bad:
        return (values["P"], values["v"], theta,
                f"melt_pool: inputs {bad} must be finite and positive, got "
                f"{ {k: values[k] for k in bad} }")
    if theta["A_max"] < theta["A_0"] or theta["A_max"] >= 1:
        return (values["P"], values["v"], theta,
                f"melt_pool: need A_0 <= A_max < 1, got A_0={theta['A_0']}, "
                f"A_max={theta['A_max']}")
    return values["P"], values["v"], theta, None


def simulate(inputs: Mapping[str, float], *,
             progress: Callable[[float, str], None] | None = None,
             **options: Any) -> SimResult:
    """Run the melt-pool model once.

    Parameters
    ----------
    inputs : mapping of str to float
        ``P`` (W) and ``v`` (m/s), and optionally any of :data:`PARAMETERS` (units in
        :data:`UNITS`); missing parameters default to the middle of :data:`BOUNDS`.
    progress : callable, optional
        Called after every Newton solve with the share of the iteration budget spent and
        a line of text (``calnet simulate`` passes :meth:`calnet.progress.Lines.update`).
    **options
        Keyword-only options, see :class:`MeltPoolOptions` (``resolution``,
        ``absorptivity``, ``kvz_mode``, ``anisotropy``, ``rtol``, ``max_iter``, ...).

    Returns
    -------
    SimResult
        ``outputs`` ``D, W, L`` (um), ``T0`` (K), ``S0`` (m/s), ``G0`` (K/m); status
        ``"ok"`` only if Newton converged and every output is finite, otherwise
        ``"nonconverged"``/``"timeout"``/``"failed"`` with NaN outputs and a message.
        ``diagnostics`` holds iterations, residual, mesh size, ``peak_temperature_K``
        (the hottest cell centre; ``T0`` is the hotter peak of the top surface, which
        the surface flux heats beyond the centre of the top cells), and
        ``stages``: per Newton solve (continuation stages on the sizing mesh, then the
        fine solve) the mesh, power, cells, iterations and CPU seconds.
    """
    opts = MeltPoolOptions.from_kwargs(**options)
    P, v, theta, bad = _check_inputs(inputs)
    if bad:  # values the model cannot take: a failed run, as for a run that fails
        return SimResult({k: float("nan") for k in OUTPUTS}, "failed", bad,
                         {"converged": False, "theta": theta, "options": opts.to_dict(),
                          "version": VERSION})
    try:
        rec = run(P, v, theta, opts, progress=progress)
    except (ValueError, FloatingPointError, np.linalg.LinAlgError, RuntimeError) as err:
        return SimResult({k: float("nan") for k in OUTPUTS}, "failed",
                         f"melt_pool raised {type(err).__name__}: {err}",
                         {"converged": False, "theta": theta, "options": opts.to_dict(),
                          "version": VERSION})
    rep = rec.report
    diag: dict[str, Any] = {
        "converged": rep.converged, "iterations": rep.iterations,
        "linear_iterations": rep.linear_iterations, "residual": rep.residual,
        "last_update_K": rep.update, "n_cells": rec.mesh.size,
        "mesh_shape": list(rec.mesh.shape), "remeshed": rec.remeshed,
        "peak_temperature_K": float(np.max(rep.T)),
        "absorptivity": rep.absorptivity, "surface_temperature_K": rep.surface_temperature,
        "seconds": rec.seconds, "stages": list(rec.stages), "theta": theta,
        "options": opts.to_dict(), "version": VERSION,
    }
    nan = {k: float("nan") for k in OUTPUTS}
    if not rep.converged:
        status = "timeout" if rep.reason == "time limit reached" else "nonconverged"
        msg = (f"Newton did not converge: {rep.reason} after {rep.iterations} iterations "
               f"(scaled residual {rep.residual:.2e}, last update {rep.update:.3g} K)")
        return SimResult(nan, status, msg, diag)
    g = rec.geometry
    assert g is not None
    outputs = {"D": g.D * 1e6, "W": g.W * 1e6, "L": g.L * 1e6, "T0": g.T0, "S0": g.S0,
               "G0": g.G0}
    bad = [k for k, x in outputs.items() if not math.isfinite(x)]
    if bad:
        diag["partial_outputs"] = {k: (x if math.isfinite(x) else None)
                                   for k, x in outputs.items()}
        return SimResult(nan, "failed", f"converged, but outputs {bad} could not be "
                         "extracted (pool too shallow for the mesh, or no liquidus "
                         "isotherm on the surface)", diag)
    return SimResult(outputs, "ok", "", diag).checked(OUTPUTS)
