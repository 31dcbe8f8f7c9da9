"""Gaussian-process surrogates (Matern 3/2 ARD) with k-fold cross-validation.

method.md section 2. The verbs: :func:`fit_gp` -> :class:`FittedGP`;
:func:`cross_validate` -> :class:`CVResult`; :func:`parity_plot` draws a
:class:`CVResult`. :func:`condition` and :func:`neg_log_marginal_likelihood` are the low
level they are built from.
"""

from calnet.surrogates.cv import CVResult, cross_validate, cv_metrics, kfold_indices
from calnet.surrogates.fit import fit_gp, validate_training_data
from calnet.surrogates.gp import FittedGP, condition
from calnet.surrogates.kernels import matern32
from calnet.surrogates.likelihood import neg_log_marginal_likelihood, nlml_value_and_grad
from calnet.surrogates.persist import load_gp, save_gp
from calnet.surrogates.plots import parity_plot

__all__ = [
    "CVResult",
    "FittedGP",
    "condition",
    "cross_validate",
    "cv_metrics",
    "fit_gp",
    "kfold_indices",
    "load_gp",
    "matern32",
    "neg_log_marginal_likelihood",
    "nlml_value_and_grad",
    "parity_plot",
    "save_gp",
    "validate_training_data",
]
