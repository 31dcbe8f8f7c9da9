"""Exceptions and warnings raised by calnet.

Every error a user can trigger with bad input is a :class:`CalnetError` whose message is
one line naming what was wrong and how to fix it; the CLI prints it without a traceback.
"""

from __future__ import annotations

import re
from collections import Counter


class CalnetError(Exception):
    """Base class of calnet's user-facing errors."""


class SpecError(CalnetError):
    """A network spec (YAML or Python) is malformed or inconsistent.

    Parameters
    ----------
    message : str
        What is wrong and how to fix it.
    file : str, optional
        The spec or data file concerned.
    field : str, optional
        Dotted path of the offending field (``models.melt_pool.parameters.K_S.lower``).
    more : list of str, optional
        Further problems of the same spec, one line each (``field: message``).
    """

    def __init__(self, message: str, *, file: str | None = None, field: str | None = None,
                 more: list[str] | None = None):
        self.file = file
        self.field = field
        self.reason = message
        self.more = list(more or [])
        where = ": ".join(p for p in (file, field) if p)
        super().__init__(f"{where}: {message}" if where else message)


class UsageError(CalnetError):
    """A bad value of a command's option or a function's argument (``--at P=abc``, a data
    set or model name the network does not have): one line naming it; the CLI exits
    with code 2, as for its own usage errors."""


class UnknownName(UsageError, KeyError):
    """A model or data set name the network does not have, given to a function
    (``network.dataset("nope")``): a :class:`UsageError` with one line naming the known
    ones, and a ``KeyError`` for code that looks names up."""

    def __str__(self) -> str:  # KeyError's would quote the message
        return str(self.args[0]) if self.args else ""


class CampaignError(CalnetError):
    """A simulation campaign cannot be run or resumed."""


class UnknownModel(CampaignError, UsageError):
    """A model name the network does not have (``--model M9``)."""


class SurrogateError(CalnetError):
    """A surrogate cannot be fitted or loaded."""


class CalibrationError(CalnetError):
    """A calibration cannot be set up or run."""


class SpecWarning(UserWarning):
    """A spec is usable but suspicious (e.g. data outside the input bounds)."""


class CalibrationWarning(UserWarning):
    """Sampler diagnostics are poor (R-hat, ESS, divergences) or data are scarce."""


class CampaignWarning(UserWarning):
    """A campaign store that is usable but not what the installed simulator would make."""


class SurrogateWarning(UserWarning):
    """A surrogate was fitted with caveats (runs excluded, nugget raised)."""


class SensitivityError(CalnetError):
    """A sensitivity analysis cannot be run (bad bounds, non-finite or constant output)."""


_NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")


def alike(texts: list[str]) -> list[tuple[str, int]]:
    """``(example, count)`` per kind of message, commonest first: messages that differ
    only in their numbers (iterations, residuals, the input at which a run failed, a
    chain's index) are one kind, shown by its first message."""
    kinds = [_NUMBER.sub("#", t) for t in texts]
    return [(texts[kinds.index(k)], n) for k, n in Counter(kinds).most_common()]
