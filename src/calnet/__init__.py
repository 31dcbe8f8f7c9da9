"""calnet: Bayesian calibration of networks of coupled simulation models."""

from importlib.metadata import PackageNotFoundError, version

from calnet import _jax  # noqa: F401  (64-bit JAX before any calnet module uses jax)

try:
    __version__ = version("calnet")
except PackageNotFoundError:  # a source tree on sys.path that was never installed
    __version__ = "0+unknown"
