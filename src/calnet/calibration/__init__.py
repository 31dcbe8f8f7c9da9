"""Kennedy-O'Hagan calibration of a network: priors, the KOH model, NUTS, diagnostics.

Names are imported lazily so that ``calnet.calibration.devices.configure_host_devices``
can run before jax is imported.

Typical use::

    post = calibrate(network, surrogates)          # calnet.calibration.calibrate_network
    summary = summarize(post.stages[0].idata)
"""

from __future__ import annotations

import importlib

_EXPORTS = {
    "calibrate": "calibrate_network", "NetworkPosterior": "calibrate_network",
    "build_koh": "calibrate_network",
    "KOHModel": "koh", "KOHDensity": "koh", "Term": "koh", "check_initial": "koh",
    "Beta": "priors", "Uniform": "priors", "Normal": "priors", "TruncatedNormal": "priors",
    "LogNormal": "priors", "InverseGamma": "priors", "Prior": "priors",
    "parameter_prior": "priors",
    "sample_nuts": "sampling",
    "summarize": "diagnostics", "PosteriorSummary": "diagnostics",
    "configure_host_devices": "devices",
}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name in _EXPORTS:
        return getattr(importlib.import_module(f"{__name__}.{_EXPORTS[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
