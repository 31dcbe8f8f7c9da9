"""Variables of a model: control inputs, calibration parameters and outputs, with priors.

These are frozen pydantic models: the YAML spec parses into them and the Python API
builds them directly.
"""

from __future__ import annotations

import math
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

NAME_PATTERN = r"^[A-Za-z_][A-Za-z0-9_]*$"
Name = Annotated[str, Field(pattern=NAME_PATTERN)]


class Frozen(BaseModel):
    """Base of every spec object: immutable, unknown keys rejected."""

    model_config = ConfigDict(frozen=True, extra="forbid", populate_by_name=True)


# ---------------------------------------------------------------- priors (method.md section 3)
class BetaPrior(Frozen):
    """Beta(a, b) scaled to the parameter's [lower, upper] (reference: a = b = 1.1)."""

    dist: Literal["beta"] = "beta"
    a: float = Field(1.1, gt=0)
    b: float = Field(1.1, gt=0)


class UniformPrior(Frozen):
    """Uniform on the parameter's [lower, upper]."""

    dist: Literal["uniform"] = "uniform"


class NormalPrior(Frozen):
    """Normal(mu, sigma) truncated to the parameter's bounds (mu, sigma in its units)."""

    dist: Literal["normal"] = "normal"
    mu: float
    sigma: float = Field(gt=0)


class LogNormalPrior(Frozen):
    """LogNormal(mu, sigma): sigma is the sd of the log (reference: mu 0, sigma 0.5)."""

    dist: Literal["lognormal"] = "lognormal"
    mu: float = 0.0
    sigma: float = Field(0.5, gt=0)


class InverseGammaPrior(Frozen):
    """InverseGamma(a, b) on a variance (reference: a 2, b 1, on standardised outputs)."""

    dist: Literal["invgamma"] = "invgamma"
    a: float = Field(2.0, gt=0)
    b: float = Field(1.0, gt=0)


ParameterPrior = Annotated[BetaPrior | UniformPrior | NormalPrior, Field(discriminator="dist")]


# ---------------------------------------------------------------- variables
class Bounded(Frozen):
    """A named real variable with a unit and finite bounds ``lower < upper``."""

    name: Name
    unit: str = "1"
    lower: float
    upper: float
    description: str = ""

    @field_validator("lower", "upper")
    @classmethod
    def _finite(cls, value: float) -> float:
        if not math.isfinite(value):
            raise ValueError("bounds must be finite numbers")
        return value

    @model_validator(mode="after")
    def _ordered(self) -> Bounded:
        if not self.lower < self.upper:
            raise ValueError(
                f"lower ({self.lower:g}) must be smaller than upper ({self.upper:g}); "
                "swap them or widen the range"
            )
        return self

    @property
    def width(self) -> float:
        return self.upper - self.lower

    @property
    def middle(self) -> float:
        return 0.5 * (self.lower + self.upper)


class Input(Bounded):
    """A control input: set by the experimenter or produced upstream through a link.

    ``scale: log`` (for inputs spanning orders of magnitude, e.g. a thermal gradient)
    makes the campaign design and the surrogate work in ``ln x``; bounds must be positive.
    """

    scale: Literal["linear", "log"] = "linear"

    @model_validator(mode="after")
    def _positive_for_log(self) -> Input:
        if self.scale == "log" and self.lower <= 0:
            raise ValueError(f"scale: log needs a positive lower bound, got {self.lower:g}; "
                             "raise the bound or use scale: linear")
        return self


class Parameter(Bounded):
    """A calibration parameter ``theta`` with its prior (default scaled Beta(1.1, 1.1))."""

    prior: ParameterPrior = Field(default_factory=BetaPrior)

    @model_validator(mode="after")
    def _prior_has_mass(self) -> Parameter:
        p = self.prior
        if p.dist == "normal":  # truncated to the bounds: it needs mass there
            gap = max(self.lower - p.mu, p.mu - self.upper, 0.0) / p.sigma
            if gap > 30:
                raise ValueError(f"prior normal(mu={p.mu:g}, sigma={p.sigma:g}) lies "
                                 f"{gap:.3g} sigma outside [{self.lower:g}, {self.upper:g}] "
                                 "and has no mass there; move mu into the bounds or widen "
                                 "sigma")
        return self


class Output(Frozen):
    """A model output; ``measurable`` outputs may be observed by a data set.

    ``transform: log`` makes its surrogate model ``ln y`` (for outputs spanning orders of
    magnitude, e.g. the thermal gradient ``G0``).
    """

    name: Name
    unit: str = "1"
    measurable: bool = False
    transform: Literal["log"] | None = None
    description: str = ""
