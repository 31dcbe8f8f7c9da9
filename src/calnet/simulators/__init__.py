"""Built-in physics simulators and the simulator protocol."""

from calnet.simulators.base import STATUSES, SimResult, Simulator

__all__ = ["STATUSES", "SimResult", "Simulator"]
