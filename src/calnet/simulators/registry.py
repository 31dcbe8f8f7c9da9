"""Registry of the built-in simulators, imported lazily (the thermal one pulls in pyamg)."""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from types import ModuleType
from typing import Any

from calnet.errors import CalnetError
from calnet.simulators.base import SimResult

_BUILTINS = {
    "melt_pool": "calnet.simulators.melt_pool",
    "phase_field": "calnet.simulators.phase_field",
    "solidification": "calnet.simulators.solidification",
}


@dataclass(frozen=True)
class BuiltinInfo:
    """What a built-in simulator declares about itself."""

    name: str
    version: str
    inputs: tuple[str, ...]
    parameters: tuple[str, ...]
    outputs: tuple[str, ...]
    units: Mapping[str, str]
    bounds: Mapping[str, tuple[float, float]]
    simulate: Callable[..., SimResult]

    def defaults(self) -> dict[str, float]:
        """Middle of the bounds of every input and parameter."""
        return {k: 0.5 * (lo + hi) for k, (lo, hi) in self.bounds.items()}


def builtin_names() -> list[str]:
    return sorted(_BUILTINS)


def _module(name: str) -> ModuleType:
    if name not in _BUILTINS:
        raise CalnetError(f"unknown built-in simulator '{name}'; choose one of "
                          f"{builtin_names()}")
    try:
        return importlib.import_module(_BUILTINS[name])
    except ImportError as err:
        raise CalnetError(f"built-in simulator '{name}' cannot be imported ({err}); "
                          "reinstall calnet with its dependencies") from err


def builtin_info(name: str) -> BuiltinInfo:
    """Metadata and entry point of the built-in simulator ``name``."""
    mod = _module(name)

    def get(attr: str) -> Any:
        try:
            return getattr(mod, attr)
        except AttributeError:
            raise CalnetError(f"built-in simulator '{name}' is incomplete: its module "
                              f"{mod.__name__} lacks {attr}") from None

    return BuiltinInfo(name=name, version=get("VERSION"), inputs=tuple(get("INPUTS")),
                       parameters=tuple(get("PARAMETERS")), outputs=tuple(get("OUTPUTS")),
                       units=dict(get("UNITS")), bounds=dict(get("BOUNDS")),
                       simulate=get("simulate"))
