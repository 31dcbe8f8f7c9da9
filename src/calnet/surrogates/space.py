"""The GP input space of a model: its inputs and parameters, ``ln x`` where declared log.

Inputs and parameters declared ``scale: log`` enter a surrogate GP as ``ln x``; the
campaign's chain-aware designs and the network's surrogates map values the same way.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from calnet.spec import Model


def log_mask(model: Model) -> np.ndarray:
    """Boolean mask over ``inputs + parameters``: True where the GP works in ``ln x``."""
    return np.array([getattr(v, "scale", "linear") == "log"
                     for v in (*model.inputs, *model.parameters)])


def gp_space(model: Model, z):
    """Map physical ``(..., n_inputs + n_parameters)`` values to the GP's input space."""
    mask = log_mask(model)
    if not mask.any():
        return z
    xp = jnp if not isinstance(z, np.ndarray) else np
    return xp.where(mask, xp.log(xp.where(mask, z, 1.0)), z)


def gp_bounds(model: Model) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper bounds of the GP input space, shape (n_inputs + n_parameters,)."""
    vars_ = (*model.inputs, *model.parameters)
    lower = np.array([v.lower for v in vars_], dtype=float)
    upper = np.array([v.upper for v in vars_], dtype=float)
    return gp_space(model, lower), gp_space(model, upper)
