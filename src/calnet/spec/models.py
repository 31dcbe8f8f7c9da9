"""Models, simulator references, links, data sets and settings of a network spec."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import Field, PositiveInt, field_validator, model_validator

from calnet.spec.variables import (
    Frozen,
    Input,
    LogNormalPrior,
    Name,
    Output,
    Parameter,
    ScalePrior,
    prior_text,
)

SIMULATOR_KINDS = ("builtin", "python", "command", "umbridge")


class SimulatorRef(Frozen):
    """Where a model's runs come from.

    Shorthand strings are accepted in YAML: ``builtin:melt_pool``,
    ``python:package.module:function``, ``umbridge:http://host:port/model_name``.

    Attributes
    ----------
    kind : {"builtin", "python", "command", "umbridge"}
    name : str
        Built-in simulator name (``melt_pool``, ``solidification``).
    target : str
        ``module:function`` of a Python callable taking a dict and returning a dict.
    argv : tuple of str
        Argument template of an external command (never run through a shell).
        ``{input_json}``, ``{output_json}``, ``{workdir}`` and ``{<variable>}`` are
        substituted per run.
    input_mode, output_mode
        How a command receives its inputs (``json-file`` or ``args``) and returns outputs
        (``json-file`` or ``stdout``: the last line of standard output that is a JSON
        object).
    url, model
        UM-Bridge server address and model name.
    timeout : float, optional
        Seconds after which a run is recorded as ``timeout``.
    options : dict
        Keyword options passed to a built-in simulator or Python callable.
    """

    kind: Literal["builtin", "python", "command", "umbridge"]
    name: str = ""
    target: str = ""
    argv: tuple[str, ...] = ()
    input_mode: Literal["json-file", "args"] = "json-file"
    output_mode: Literal["json-file", "stdout"] = "json-file"
    url: str = ""
    model: str = "forward"
    timeout: float | None = Field(None, gt=0)
    options: dict[str, Any] = Field(default_factory=dict)

    @model_validator(mode="before")
    @classmethod
    def _shorthand(cls, value: Any) -> Any:
        if not isinstance(value, str):
            return value
        kind, sep, rest = value.partition(":")
        if not sep or kind not in SIMULATOR_KINDS or kind == "command":
            raise ValueError(
                f"cannot read simulator '{value}'; write builtin:NAME, python:module:function, "
                "umbridge:URL/MODEL, or a mapping with kind: command and argv: [...]"
            )
        if kind == "builtin":
            return {"kind": kind, "name": rest}
        if kind == "python":
            return {"kind": kind, "target": rest}
        url, _, model = rest.rstrip("/").rpartition("/")
        return {"kind": kind, "url": url, "model": model}

    @model_validator(mode="after")
    def _complete(self) -> SimulatorRef:
        need = {"builtin": "name", "python": "target", "command": "argv", "umbridge": "url"}
        if not getattr(self, need[self.kind]):
            raise ValueError(f"a '{self.kind}' simulator needs '{need[self.kind]}'")
        if self.kind == "python" and ":" not in self.target:
            raise ValueError(f"python target '{self.target}' must look like 'module:function'")
        return self


DESIGN_KINDS = ("lhs", "sobol", "halton", "chain")


class CampaignSettings(Frozen):
    """Simulation campaign of one model (method.md section 2, docs/campaigns.md).

    ``design`` is ``lhs``, ``sobol``, ``halton``, ``chain`` or a ``.csv``/``.parquet`` file
    of points (relative to the spec); unset, it is ``chain`` for a model with linked
    inputs and ``lhs`` otherwise (a store keeps the design that made it). ``import``
    names a ``.csv``/``.parquet`` table of finished runs to load into the store. ``runs``
    is the size of the simulated design; with ``import`` and no ``runs`` nothing is
    simulated.
    """

    runs: PositiveInt = 100
    timeout: float | None = Field(None, gt=0, description="seconds per run")
    design: str | None = Field(None, description="lhs, sobol, halton, chain or a points file")
    import_: str | None = Field(None, alias="import", description="a table of finished runs")

    @field_validator("design", "import_")
    @classmethod
    def _kind_or_table(cls, value: str | None, info: Any) -> str | None:
        if value is None:
            return None
        is_table = value.lower().endswith((".csv", ".parquet"))
        if info.field_name == "design" and value not in DESIGN_KINDS and not is_table:
            raise ValueError(f"unknown design '{value}'; use one of {', '.join(DESIGN_KINDS)} "
                             "or a .csv/.parquet file of points")
        if info.field_name == "import_" and not is_table:
            raise ValueError(f"cannot import '{value}'; name a .csv or .parquet file of runs")
        return value


class SurrogateSettings(Frozen):
    """GP surrogate fitting (method.md section 2)."""

    cv_folds: int = Field(10, ge=2)
    restarts: int = Field(5, ge=1)
    #: the GP's mean function: "constant", "linear" or "quadratic" (a trend in the
    #: inputs, its coefficients' uncertainty in the variance) or "auto" (the one of
    #: highest leave-one-out predictive density among those with at least 5 runs per
    #: coefficient; calnet.surrogates.fit_gp)
    mean: Literal["constant", "linear", "quadratic", "auto"] = "auto"


class Model(Frozen):
    """One node of the network: control inputs ``x``, parameters ``theta``, outputs ``y``."""

    name: Name
    simulator: SimulatorRef
    inputs: tuple[Input, ...] = Field(min_length=1)
    parameters: tuple[Parameter, ...] = ()
    outputs: tuple[Output, ...] = Field(min_length=1)
    campaign: CampaignSettings | None = None
    surrogate: SurrogateSettings | None = None
    description: str = ""

    @field_validator("inputs", "parameters", "outputs", mode="before")
    @classmethod
    def _named_mapping(cls, value: Any) -> Any:
        return named_mapping_to_list(value)

    @model_validator(mode="after")
    def _unique_names(self) -> Model:
        seen: dict[str, str] = {}
        for group in ("inputs", "parameters", "outputs"):
            for var in getattr(self, group):
                if var.name in seen:
                    raise ValueError(
                        f"duplicate variable name '{var.name}' (in {seen[var.name]} and "
                        f"{group}); rename one of them"
                    )
                seen[var.name] = group
        return self

    # ------------------------------------------------------------ look-ups
    @property
    def input_names(self) -> tuple[str, ...]:
        return tuple(v.name for v in self.inputs)

    @property
    def parameter_names(self) -> tuple[str, ...]:
        return tuple(v.name for v in self.parameters)

    @property
    def output_names(self) -> tuple[str, ...]:
        return tuple(v.name for v in self.outputs)

    def variable(self, name: str) -> Input | Parameter | Output:
        """Return the input, parameter or output called ``name`` (KeyError otherwise)."""
        for var in (*self.inputs, *self.parameters, *self.outputs):
            if var.name == name:
                return var
        raise KeyError(name)

    def output(self, name: str) -> Output:
        for var in self.outputs:
            if var.name == name:
                return var
        raise KeyError(name)


class Link(Frozen):
    """``source`` (``model.output`` or ``model.input`` for an identity link) feeds ``target``
    (``model.input``)."""

    source: str = Field(alias="from")
    target: str = Field(alias="to")

    @field_validator("source", "target")
    @classmethod
    def _qualified(cls, value: str) -> str:
        parts = value.split(".")
        if len(parts) != 2 or not all(parts):
            raise ValueError(f"'{value}' must be written 'model.variable'")
        return value

    @property
    def source_model(self) -> str:
        return self.source.split(".")[0]

    @property
    def source_var(self) -> str:
        return self.source.split(".")[1]

    @property
    def target_model(self) -> str:
        return self.target.split(".")[0]

    @property
    def target_var(self) -> str:
        return self.target.split(".")[1]


class Split(Frozen):
    """Which rows of a data set are for calibration and which are held out."""

    column: str
    train: str = "train"
    test: str = "test"


DEFAULT_SCALE = "the observations' sd"
"""The scale of the default noise and discrepancy priors, in words (where the
observations have none, :func:`calnet.calibration.terms.data_scale` takes another)."""


class NoiseSettings(Frozen):
    """Measurement noise of one data set (method.md section 3), in the output's units.

    Give one of: ``sd`` (a known standard deviation), ``sd_column`` (a CSV column of known
    per-point standard deviations) or ``prior`` (a prior on the unknown noise sd: dist
    ``halfnormal``, ``lognormal`` or ``gamma``; or ``invgamma`` on the variance). With
    none of them the noise sd gets the default prior, a half-normal whose scale is the
    sd of the observations. For an output with ``transform: log`` the known sds are
    converted to the log scale as ``sd / y``, and a ``prior`` is on the sd of ``ln y``.
    ``noise: reference`` is the reference study's InverseGamma(2, 1) on the noise variance
    relative to the observations' variance.
    """

    sd: float | None = Field(None, gt=0, allow_inf_nan=False)
    sd_column: str | None = None
    prior: ScalePrior | None = None
    reference: bool = False

    @model_validator(mode="before")
    @classmethod
    def _shorthand(cls, value: Any) -> Any:
        if value == "reference":
            return {"reference": True}
        if isinstance(value, str):
            raise ValueError(f"cannot read noise '{value}'; write {{sd: 0.1}}, "
                             "{sd_column: COLUMN}, {prior: {dist: halfnormal, sigma: ...}} "
                             "or reference")
        return value

    @model_validator(mode="after")
    def _one_kind(self) -> NoiseSettings:
        given = [k for k in ("sd", "sd_column", "prior") if getattr(self, k) is not None]
        given += ["reference"] if self.reference else []
        if len(given) > 1:
            raise ValueError(f"give one of sd, sd_column, prior or reference, not {given}")
        return self

    @property
    def known(self) -> bool:
        return self.sd is not None or self.sd_column is not None

    def text(self, unit: str = "", log: bool = False, scale: str = DEFAULT_SCALE) -> str:
        """In words: ``noise sd 5 um (known)``, ``noise sd sampled, prior ...``; ``unit``
        is the output's, ``log`` whether it has ``transform: log``, ``scale`` what the
        default prior's scale is."""
        unit = "" if unit in ("", "1") else f" {unit}"
        to_log = "; taken to the log scale as sd / y" if log else ""
        if self.sd is not None:
            return f"noise sd {self.sd:g}{unit} (known{to_log})"
        if self.sd_column:
            return (f"noise sd from column '{self.sd_column}'{unit and ' in' + unit} "
                    f"(known{to_log})")
        if self.reference:
            return "noise variance sampled, the reference study's InverseGamma(2, 1) prior"
        if self.prior is not None:
            on = "variance" if self.prior.dist == "invgamma" else "sd"
            return f"noise {on} sampled, prior {prior_text(self.prior)}"
        return f"noise sd sampled, prior half-normal (scale: {scale})"


class DiscrepancySettings(Frozen):
    """The KOH discrepancy of one data set (method.md section 3).

    ``sd_prior`` is a prior on the discrepancy's standard deviation in the output's units
    (on the log scale for ``transform: log``; default: a half-normal whose scale is the
    sd of the observations), ``length_scale_prior`` on its length scales over the unit
    cube of the model's inputs. ``orthogonal`` (default true) keeps the discrepancy from
    mimicking the model's own parameters (docs/method.md). ``discrepancy: none`` drops
    the term; ``discrepancy: reference`` is the reference study's KOH: InverseGamma(2, 1)
    on the variance relative to the observations' variance, not orthogonal.
    """

    sd_prior: ScalePrior | None = None
    length_scale_prior: LogNormalPrior = Field(default_factory=LogNormalPrior)
    orthogonal: bool = True
    enabled: bool = True
    reference: bool = False

    @model_validator(mode="before")
    @classmethod
    def _shorthand(cls, value: Any) -> Any:
        if value in ("none", None, False):
            return {"enabled": False}
        if value == "reference":
            return {"reference": True, "orthogonal": False}
        if isinstance(value, str):
            raise ValueError(f"cannot read discrepancy '{value}'; write none, reference or "
                             "{sd_prior: {...}, length_scale_prior: {...}}")
        return value

    @model_validator(mode="after")
    def _consistent(self) -> DiscrepancySettings:
        if self.reference and self.sd_prior is not None:
            raise ValueError("give either reference or sd_prior, not both")
        return self

    def text(self, scale: str = DEFAULT_SCALE) -> str:
        """In words: ``no discrepancy``, ``discrepancy orthogonal to ...``; ``scale`` what
        the default prior's scale is."""
        if not self.enabled:
            return "no discrepancy"
        if self.reference:
            return "discrepancy: the reference study's (InverseGamma(2, 1), not orthogonal)"
        sd = (f"prior {prior_text(self.sd_prior)}" if self.sd_prior is not None
              else f"prior half-normal (scale: {scale})")
        ell = ("" if self.length_scale_prior == LogNormalPrior()
               else f", length scales prior {prior_text(self.length_scale_prior)}")
        return (f"discrepancy {'orthogonal to' if self.orthogonal else 'free to mimic'} the "
                f"model's parameters, sd {sd}{ell}")


class Dataset(Frozen):
    """Experimental data observing one measurable output.

    ``columns`` maps variables to CSV columns: the observed output and every free
    (unlinked) input of the observed model and of its ancestors. Keys are
    ``model.variable`` or a bare variable name when that name is unambiguous. Without
    ``columns`` each of them is read from the column of its own (bare) name.
    """

    name: Name
    path: str
    observes: str
    columns: dict[str, str] | None = None
    split: Split | None = None
    strict: bool | None = None
    noise: NoiseSettings = Field(default_factory=NoiseSettings)
    discrepancy: DiscrepancySettings = Field(default_factory=DiscrepancySettings)
    description: str = ""

    @field_validator("split", mode="before")
    @classmethod
    def _split_shorthand(cls, value: Any) -> Any:
        return {"column": value} if isinstance(value, str) else value

    @field_validator("observes")
    @classmethod
    def _qualified(cls, value: str) -> str:
        return Link._qualified(value)

    @property
    def observed_model(self) -> str:
        return self.observes.split(".")[0]

    @property
    def observed_output(self) -> str:
        return self.observes.split(".")[1]


class SamplerSettings(Frozen):
    """NUTS settings (reference: 1000 burn-in draws, thinning 10)."""

    chains: int = Field(4, ge=1)
    warmup: int = Field(1000, ge=10)
    draws: int = Field(1000, ge=10)
    thin: int = Field(1, ge=1)
    target_accept: float = Field(0.9, gt=0, lt=1)
    dense_mass: bool = Field(
        False, description="adapt a dense inverse mass matrix (one covariance of all the "
        "sampled variables) instead of a diagonal one: fewer gradient evaluations per "
        "effective draw where the posterior's variables are correlated; its warm-up "
        "estimates dim^2 / 2 covariances, so keep warm-up well above the number of "
        "sampled variables")
    chain_method: Literal["auto", "sequential", "parallel", "vectorized"] = Field(
        "auto", description="how chains share the CPU (auto: parallel over XLA host "
        "devices when there are several)")


class CalibrationSettings(Frozen):
    """How the network is calibrated (method.md section 4).

    ``plug`` (segmented mode): ``mode`` fixes the upstream parameters at their posterior
    mode; ``posterior`` gives the cut posterior (upstream parameters from their own
    posterior, downstream ones conditional on them), by linear response around the
    upstream posterior mean (docs/method.md). ``emulator_variance`` adds the surrogates'
    predictive variance to the likelihood (the observed output's, and to first order the
    linked outputs' along the chain).
    """

    mode: Literal["segmented", "joint"] = "segmented"
    plug: Literal["mode", "posterior"] = "posterior"
    emulator_variance: bool = True


class Criterion(Frozen):
    """A specification an output must meet (for the process map): lower <= y <= upper."""

    lower: float | None = None
    upper: float | None = None

    @model_validator(mode="after")
    def _some_bound(self) -> Criterion:
        if self.lower is None and self.upper is None:
            raise ValueError("a criterion needs 'lower', 'upper' or both")
        if self.lower is not None and self.upper is not None and self.lower >= self.upper:
            raise ValueError(f"lower ({self.lower:g}) must be smaller than upper "
                             f"({self.upper:g})")
        return self


class Settings(Frozen):
    """Network-wide settings; every field has a documented default.

    ``criteria`` maps a data set name to the range its output should meet; the report's
    process map shows the probability of meeting it over the process inputs.
    ``compare`` lists variants of the spec's discrepancy calibrated beside it and
    compared with it by PSIS leave-one-out (``no_discrepancy``, ``non_orthogonal``,
    ``reference``; :func:`calnet.validation.compare_variants`). ``predict`` lists outputs
    (``model.output``) to emulate and predict through the chain whether or not a data set
    observes them: each gets a surrogate, ``calnet predict -d model.output`` predicts it
    and ``calnet run`` reports it over its process inputs.
    """

    seed: int = Field(0, ge=0)
    strict: bool = False
    campaign: CampaignSettings = Field(default_factory=CampaignSettings)
    surrogate: SurrogateSettings = Field(default_factory=SurrogateSettings)
    sampler: SamplerSettings = Field(default_factory=SamplerSettings)
    calibration: CalibrationSettings = Field(default_factory=CalibrationSettings)
    criteria: dict[str, Criterion] = Field(default_factory=dict)
    compare: tuple[Literal["no_discrepancy", "non_orthogonal", "reference"], ...] = Field(
        (), description="model variants calibrated beside the spec and compared by PSIS-LOO")
    predict: tuple[str, ...] = Field(
        (), description="outputs (model.output) predicted through the chain, observed or not")

    @field_validator("predict", "compare", mode="before")
    @classmethod
    def _one_as_list(cls, value: Any) -> Any:
        """``predict: M.y`` is ``predict: [M.y]`` (and the same for ``compare``)."""
        return [value] if isinstance(value, str) else value

    @field_validator("compare")
    @classmethod
    def _each_variant_once(cls, value: tuple[str, ...]) -> tuple[str, ...]:
        if len(set(value)) < len(value):
            raise ValueError(f"{list(value)} names a variant twice; list each once")
        return value

    @field_validator("predict")
    @classmethod
    def _qualified_outputs(cls, value: tuple[str, ...]) -> tuple[str, ...]:
        for item in value:
            Link._qualified(item)
        if len(set(value)) < len(value):
            raise ValueError(f"{list(value)} names an output twice; list each once")
        return value


def named_mapping_to_list(value: Any) -> Any:
    """Accept ``{name: {...}}`` as well as ``[{name: ..., ...}]`` for named items."""
    if isinstance(value, dict):
        items = []
        for key, body in value.items():
            body = {} if body is None else body
            if isinstance(body, dict):
                if "name" in body and body["name"] != key:
                    raise ValueError(f"item '{key}' has a different name '{body['name']}'")
                items.append({**body, "name": key})
            else:
                items.append(body)
        return items
    return value


__all__ = [
    "DEFAULT_SCALE", "CalibrationSettings", "CampaignSettings", "Criterion", "Dataset",
    "DiscrepancySettings", "Link", "Model", "Name", "NoiseSettings", "SamplerSettings",
    "Settings", "SimulatorRef", "Split", "SurrogateSettings",
]
