"""Kennedy-O'Hagan calibration: priors, log-density, NUTS sampling, diagnostics.

Names are imported lazily so that ``calnet.calibration.devices.configure_host_devices``
can run before jax is imported.

Low level (composes)::

    ld = build_logdensity(mean_fn, y, x_disc, theta_priors=[Beta(lo, hi), ...])
    idata = sample_nuts(ld, seed=0)
    summary = summarize(idata)
"""

from __future__ import annotations

import importlib

_EXPORTS = {
    "build_logdensity": "koh", "KOHLogDensity": "koh", "KOHSpec": "koh",
    "check_initial": "koh",
    "Beta": "priors", "Uniform": "priors", "Normal": "priors", "TruncatedNormal": "priors",
    "LogNormal": "priors", "InverseGamma": "priors", "Prior": "priors",
    "sample_nuts": "sampling",
    "summarize": "diagnostics", "PosteriorSummary": "diagnostics",
    "fixed_input_gp": "emulator",
    "configure_host_devices": "devices",
}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name in _EXPORTS:
        return getattr(importlib.import_module(f"{__name__}.{_EXPORTS[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
