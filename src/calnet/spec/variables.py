"""Variables of a model: control inputs, calibration parameters and outputs, with priors.

These are frozen pydantic models: the YAML spec parses into them and the Python API
builds them directly.
"""

from __future__ import annotations

import math
import types
import typing
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationInfo, field_validator, model_validator

NAME_PATTERN = r"^[A-Za-z_][A-Za-z0-9_]*$"
Name = Annotated[str, Field(pattern=NAME_PATTERN)]


def _numeric(annotation: Any) -> bool:
    """Whether a field's annotation admits a number but not a boolean."""
    args = typing.get_args(annotation) if isinstance(
        annotation, types.UnionType) or typing.get_origin(annotation) is typing.Union else ()
    kinds = set(args) if args else {annotation}
    return bool(kinds & {float, int}) and bool not in kinds


class Frozen(BaseModel):
    """Base of every spec object: immutable, unknown keys rejected, no boolean where a
    number is expected (YAML reads ``true`` as 1.0 otherwise)."""

    model_config = ConfigDict(frozen=True, extra="forbid", populate_by_name=True)

    @model_validator(mode="before")
    @classmethod
    def _no_bool_numbers(cls, data: Any) -> Any:
        if isinstance(data, dict):
            for name, field in cls.model_fields.items():
                value = data.get(name, data.get(field.alias) if field.alias else None)
                if isinstance(value, bool) and _numeric(field.annotation):
                    raise ValueError(f"{name} must be a number, got {str(value).lower()}; "
                                     "write a number such as 1.0, not true/false")
        return data


# ---------------------------------------------------------------- priors (method.md section 3)
class _SpecPrior(Frozen):
    """Base of the prior models: every number is finite."""

    @field_validator("a", "b", "mu", "sigma", mode="before", check_fields=False)
    @classmethod
    def _finite_number(cls, value: object, info: ValidationInfo) -> object:
        try:
            number = float(value)
        except (TypeError, ValueError):
            return value  # pydantic reports the non-number
        if not math.isfinite(number):
            raise ValueError(f"{info.field_name} must be a finite number, got {value}")
        return value


class BetaPrior(_SpecPrior):
    """Beta(a, b) scaled to the parameter's [lower, upper] (reference: a = b = 1.1).

    ``a`` and ``b`` are unitless shapes (> 0).
    """

    dist: Literal["beta"] = "beta"
    a: float = Field(1.1, gt=0)
    b: float = Field(1.1, gt=0)


class UniformPrior(_SpecPrior):
    """Uniform on the parameter's [lower, upper]."""

    dist: Literal["uniform"] = "uniform"


class NormalPrior(_SpecPrior):
    """Normal(mu, sigma) truncated to the parameter's bounds (mu, sigma in its units)."""

    dist: Literal["normal"] = "normal"
    mu: float
    sigma: float = Field(gt=0)


class TruncNormalPrior(_SpecPrior):
    """Normal(mu, sigma) truncated to the parameter's bounds (mu, sigma in its units).

    The same prior as ``dist: normal``, under the explicit name.
    """

    dist: Literal["truncnormal"] = "truncnormal"
    mu: float
    sigma: float = Field(gt=0)


class LogNormalPrior(_SpecPrior):
    """LogNormal(mu, sigma): ``log x ~ Normal(mu, sigma)`` (reference: mu 0, sigma 0.5).

    ``mu`` and ``sigma`` are the mean and sd of ``log x``. On a parameter, ``x`` is the
    parameter in its units, truncated to its bounds (lower >= 0); as a discrepancy length
    scale, ``x`` is the length scale on unit-cube inputs; as a noise or discrepancy scale
    prior, ``x`` is the sd, in the output's units (log units for ``transform: log``).
    """

    dist: Literal["lognormal"] = "lognormal"
    mu: float = 0.0
    sigma: float = Field(0.5, gt=0)


class GammaPrior(_SpecPrior):
    """Gamma(a, b) with shape ``a`` > 0 and rate ``b`` > 0: ``b^a x^(a-1) e^(-b x) / G(a)``.

    The mean is ``a / b``; ``b`` is in the inverse units of ``x``. On a parameter, ``x`` is
    the parameter in its units, truncated to its bounds (lower >= 0); as a noise or
    discrepancy scale prior, ``x`` is the sd, in the output's units (log units for
    ``transform: log``).
    """

    dist: Literal["gamma"] = "gamma"
    a: float = Field(gt=0)
    b: float = Field(gt=0)


class HalfNormalPrior(_SpecPrior):
    """HalfNormal(sigma): ``|z| sigma`` with ``z ~ Normal(0, 1)``, on ``x >= 0``.

    ``sigma`` > 0 is in the units of ``x``. On a parameter, ``x`` is the parameter in its
    units, truncated to its bounds (lower >= 0); as a noise or discrepancy scale prior,
    ``x`` is the sd, in the output's units (log units for ``transform: log``).
    """

    dist: Literal["halfnormal"] = "halfnormal"
    sigma: float = Field(gt=0)


class InverseGammaPrior(_SpecPrior):
    """InverseGamma(a, b) on a variance, in the output's units squared.

    Density ``b^a x^(-a-1) e^(-b / x) / G(a)`` of the variance ``x``; ``b`` is in its units.
    """

    dist: Literal["invgamma"] = "invgamma"
    a: float = Field(2.0, gt=0)
    b: float = Field(1.0, gt=0)


ParameterPrior = Annotated[
    BetaPrior | UniformPrior | NormalPrior | TruncNormalPrior | LogNormalPrior | GammaPrior
    | HalfNormalPrior,
    Field(discriminator="dist"),
]
ScalePrior = Annotated[
    HalfNormalPrior | LogNormalPrior | GammaPrior | InverseGammaPrior,
    Field(discriminator="dist"),
]


# ---------------------------------------------------------------- variables
def unit_text(value):
    """A unit as the spec may write it: ``unit: 1`` (YAML reads a number) is ``"1"``."""
    if isinstance(value, int | float) and not isinstance(value, bool):
        return f"{value:g}"
    return value


class Bounded(Frozen):
    """A named real variable with a unit and finite bounds ``lower < upper``."""

    name: Name
    unit: str = "1"
    lower: float
    upper: float
    description: str = ""

    _unit = field_validator("unit", mode="before")(lambda cls, value: unit_text(value))

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
    """A calibration parameter ``theta`` with its prior (default scaled Beta(1.1, 1.1)).

    ``shared: true`` makes one parameter of every model that declares the same name with
    ``shared: true`` (the same unit, bounds and prior in each): it is calibrated once, with
    the data of all those models in joint mode.
    """

    prior: ParameterPrior = Field(default_factory=BetaPrior)
    shared: bool = False

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

    def prior_shares(self) -> tuple[float, float, float]:
        """Shares of the untruncated prior's mass below, within and above the bounds.

        ``beta`` and ``uniform`` are defined on the bounds: ``(0, 1, 0)``. The others are
        truncated to the bounds, so a small middle share means the bounds cut the prior
        to a tail of itself.
        """
        p = self.prior
        if p.dist in ("beta", "uniform"):
            return 0.0, 1.0, 0.0
        # only here, lazily: scipy.stats takes most of a second to import, and a spec of
        # beta and uniform priors (the default) loads without it
        from scipy import stats

        law = {"normal": lambda: stats.norm(p.mu, p.sigma),
               "truncnormal": lambda: stats.norm(p.mu, p.sigma),
               "lognormal": lambda: stats.lognorm(p.sigma, scale=math.exp(p.mu)),
               "gamma": lambda: stats.gamma(p.a, scale=1.0 / p.b),
               "halfnormal": lambda: stats.halfnorm(scale=p.sigma)}.get(p.dist)
        if law is None:
            return 0.0, 1.0, 0.0
        dist = law()
        below, above = float(dist.cdf(self.lower)), float(dist.sf(self.upper))
        # the difference on the side of the smaller tail keeps a tiny share exact
        within = (float(dist.cdf(self.upper)) - below if below < 0.5
                  else float(dist.sf(self.lower)) - above)
        return below, max(within, 0.0), above

    def prior_text(self) -> str:
        """The prior as written in a spec: ``normal(mu=10, sigma=0.5)``."""
        return prior_text(self.prior)


def prior_text(prior) -> str:
    """A prior as written in a spec: ``halfnormal(sigma=0.5)``."""
    fields = ", ".join(f"{k}={v:g}" for k, v in prior.model_dump().items() if k != "dist")
    return f"{prior.dist}({fields})"


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

    _unit = field_validator("unit", mode="before")(lambda cls, value: unit_text(value))
