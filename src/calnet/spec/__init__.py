"""The network spec: variables, models, links, data sets, settings; YAML in and out."""

from calnet.spec.data import ExperimentalData, read_all, read_dataset
from calnet.spec.load import load_spec, parse_spec, resolve_spec_path
from calnet.spec.models import (
    CalibrationSettings,
    CampaignSettings,
    Dataset,
    DiscrepancySettings,
    Link,
    Model,
    SamplerSettings,
    Settings,
    SimulatorRef,
    Split,
    SurrogateSettings,
)
from calnet.spec.network import Network
from calnet.spec.variables import (
    BetaPrior,
    Input,
    InverseGammaPrior,
    LogNormalPrior,
    NormalPrior,
    Output,
    Parameter,
    UniformPrior,
)

__all__ = [
    "BetaPrior", "CalibrationSettings", "CampaignSettings", "Dataset", "DiscrepancySettings",
    "ExperimentalData", "Input", "InverseGammaPrior", "Link", "LogNormalPrior", "Model",
    "Network", "NormalPrior", "Output", "Parameter", "SamplerSettings", "Settings",
    "SimulatorRef", "Split", "SurrogateSettings", "UniformPrior", "load_spec", "parse_spec",
    "read_all", "read_dataset", "resolve_spec_path",
]
