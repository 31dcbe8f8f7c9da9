"""calnet: Bayesian calibration of networks of coupled simulation models."""

__version__ = "0.1.0"
