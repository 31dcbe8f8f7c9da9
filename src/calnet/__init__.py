"""calnet: Bayesian calibration of networks of coupled simulation models."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("calnet")
except PackageNotFoundError:  # a source tree on sys.path that was never installed
    __version__ = "0+unknown"
