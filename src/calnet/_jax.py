"""JAX configuration for all of calnet, applied once when :mod:`calnet` is imported.

calnet computes in 64-bit floats (GP Cholesky factors and KOH log-densities lose too much
in 32 bits). Importing jax takes longer than the whole command line, so when jax is not
imported yet this sets ``JAX_ENABLE_X64``, which jax reads when it starts (subprocesses
inherit it, as they inherit ``XLA_FLAGS``); when jax is already imported it updates
jax's configuration. XLA host devices and the compilation cache are configured by the
entry points (:mod:`calnet.calibration.devices`), not here.
"""

from __future__ import annotations

import os
import sys

__all__ = ["enable_x64"]


def enable_x64() -> None:
    """Make jax use 64-bit floats and integers by default, whether or not it is imported."""
    if "jax" in sys.modules:
        sys.modules["jax"].config.update("jax_enable_x64", True)
    else:
        os.environ["JAX_ENABLE_X64"] = "true"


enable_x64()
