"""The small protocol every simulator speaks: inputs dict -> :class:`SimResult`.

Built-in simulators, Python callables, external commands and UM-Bridge servers are all
adapted to this shape by :mod:`calnet.campaign.runners`.
"""

from __future__ import annotations

import math
import numbers
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields
from typing import Any, Literal, Protocol

Status = Literal["ok", "failed", "timeout", "nonconverged"]
STATUSES: tuple[str, ...] = ("ok", "failed", "timeout", "nonconverged")


@dataclass(frozen=True)
class SimResult:
    """Outcome of one simulator run.

    Attributes
    ----------
    outputs : dict of str to float
        Output values in the model's declared units. May be empty or hold NaN when
        ``status`` is not ``"ok"``.
    status : {"ok", "failed", "timeout", "nonconverged"}
        ``"ok"`` only when every output is finite and the simulator trusts its answer.
    message : str
        Why a run is not ``"ok"`` (empty otherwise).
    diagnostics : dict
        Free-form numbers (iterations, residual, mesh size, ...), JSON-serialisable.
    """

    outputs: dict[str, float]
    status: Status = "ok"
    message: str = ""
    diagnostics: dict[str, Any] = field(default_factory=dict)

    def checked(self, expected: tuple[str, ...] = ()) -> SimResult:
        """Return a copy marked ``failed`` if an expected output (every output, when
        ``expected`` is empty) is missing, no number (saying what it is) or not finite.

        The other outputs, which the model does not declare, are kept when they are
        numbers (as floats, NaN for one too large for a float) and dropped otherwise."""
        if self.status != "ok":
            return self
        declared = expected or tuple(self.outputs)
        wrong = not_numbers({k: self.outputs[k] for k in declared if k in self.outputs})
        if wrong:
            return SimResult(self.outputs, "failed", wrong, self.diagnostics)
        missing = [k for k in declared if k not in self.outputs]
        if missing:
            got = f"it returned {sorted(self.outputs)}" if self.outputs else "it returned none"
            return SimResult(self.outputs, "failed", f"missing outputs {missing} ({got}); "
                             "return each declared output by its name", self.diagnostics)
        bad = [k for k in declared if not is_finite_number(self.outputs[k])]
        if bad:
            return SimResult(self.outputs, "failed", _not_finite(
                {k: self.outputs[k] for k in bad}), self.diagnostics)
        kept = {k: v for k, v in self.outputs.items()
                if k in declared or (isinstance(v, numbers.Real) and not isinstance(v, bool))}
        if len(kept) == len(self.outputs) and all(type(v) is float for v in kept.values()):
            return self
        # NumPy scalars (float32, int64, ...) are numbers: store them as Python floats
        return SimResult({k: as_float(v) for k, v in kept.items()}, self.status,
                         self.message, self.diagnostics)


def is_finite_number(value: Any) -> bool:
    """Whether ``value`` is a real number (NumPy scalars too) that is finite as a float
    (an integer too large for a float is not)."""
    if not isinstance(value, numbers.Real):
        return False
    try:
        return math.isfinite(float(value))
    except OverflowError:
        return False


def as_float(value: Any) -> float:
    """``float(value)``; NaN for a value that is no number or too large for a float."""
    try:
        return float(value)
    except (TypeError, ValueError, OverflowError):
        return math.nan


def _not_finite(values: Mapping[str, Any]) -> str:
    """``"non-finite outputs: 'y' = nan"``; an integer too large for a float is named as
    such (``"output 'y' is an integer of about 1e400, too large for a float ..."``)."""
    nonfinite, huge = [], []
    for k, v in values.items():
        try:
            nonfinite.append(f"'{k}' = {float(v)!r}" if isinstance(v, numbers.Real)
                             else f"'{k}' = {v!r}")  # None
        except OverflowError:
            size = (f"an integer of about 1e{int(math.log10(abs(int(v))))}"
                    if isinstance(v, numbers.Integral) else _brief(v))
            huge.append(f"output '{k}' is {size}, too large for a float (at most "
                        f"{sys.float_info.max:.3g})")
    return "; ".join([*(["non-finite outputs: " + ", ".join(nonfinite)] if nonfinite else []),
                      *huge])


def not_numbers(values: Mapping[str, Any], where: str = "") -> str:
    """What is wrong with the values that are no number ("output 'y' is str '1.5',
    expected a number"), "" when each is one. Any real number counts (NumPy scalars too);
    None is left to the finiteness check, as NaN."""
    return "; ".join(f"output '{k}'{where} is {_brief(v)}, expected a number"
                     for k, v in values.items()
                     if v is not None and not isinstance(v, numbers.Real))


class InputValueError(ValueError):
    """An input or parameter value a built-in model cannot take (not finite, not
    positive); ``simulate`` turns it into a failed run."""


def check_input_names(name: str, inputs: Mapping[str, Any], required: Sequence[str],
                      optional: Sequence[str], units: Mapping[str, str]) -> None:
    """Refuse a key that is neither a control input nor a parameter (a typo would
    otherwise fall back to a default silently) and a missing control input.

    Parameters
    ----------
    name : str
        The simulator, for the message.
    inputs : mapping of str to value
        What the simulator was called with.
    required, optional : sequence of str
        Its control inputs (all needed) and its parameters (each may be left out).
    units : mapping of str to str
        Units of the control inputs, named in the message.

    Raises
    ------
    ValueError
        ``"NAME: unknown inputs [...]; ..."`` or ``"NAME: missing control inputs [...]; ..."``.
    """
    unknown = sorted(set(inputs) - set(required) - set(optional))
    if unknown:
        raise ValueError(f"{name}: unknown inputs {unknown}; expected {list(required)} and "
                         f"optionally {list(optional)}")
    missing = [k for k in required if k not in inputs]
    if missing:
        needed = ", ".join(f"{k} ({units[k]})" if k in units else k for k in required)
        raise ValueError(f"{name}: missing control inputs {missing}; pass {needed}, got "
                         f"{sorted(inputs)}")


def _brief(value: Any) -> str:
    """``str '1.5'``, ``list [1.0, 2.0]``, ``ndarray of shape (1,)``."""
    kind = type(value).__name__
    if hasattr(value, "shape") and not isinstance(value, (str, bytes)):
        return f"{kind} of shape {tuple(value.shape)}"
    text = repr(value)
    return f"{kind} {text if len(text) <= 40 else text[:37] + '...'}"


class Simulator(Protocol):
    """Anything that maps one input dict (control inputs and parameters) to a result."""

    name: str
    version: str

    def __call__(self, inputs: Mapping[str, float]) -> SimResult: ...


_KINDS = {"int": (numbers.Integral, "an integer"), "float": (numbers.Real, "a number"),
          "str": (str, "a string"), "bool": (bool, "true or false")}


def check_option_types(cls: type, options: Mapping[str, Any], simulator: str) -> None:
    """Raise ``ValueError`` naming the first option of ``options`` whose value is not of
    the type its field of the dataclass ``cls`` declares (``int``, ``float``, ``str``,
    ``bool``, optionally ``| None``): ``nx=10.5`` or ``resolution="abc"`` would otherwise
    be truncated or fail deep inside the run. Booleans are not numbers here."""
    declared = {f.name: str(f.type) for f in fields(cls)}
    for name, value in options.items():
        kinds = [k.strip() for k in declared.get(name, "").split("|")]
        if value is None and "None" in kinds:
            continue
        known = [k for k in kinds if k in _KINDS]
        if not known:
            continue  # a field of another type: the options class checks it
        ok = any(isinstance(value, _KINDS[k][0]) and not (isinstance(value, bool)
                                                           and k != "bool")
                 for k in known)
        if not ok:
            want = " or ".join(_KINDS[k][1] for k in known)
            raise ValueError(f"{simulator} option {name}: expected {want}, got {value!r}")
