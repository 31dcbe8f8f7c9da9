"""A reference study's published results beside a run's: ``reference.json`` in the
spec's folder (the case study ships ``examples/ninb/reference.json``); the report shows
the comparison only where that file exists.

The file holds, all optional: ``note`` (the section's paragraph), ``dataset`` and its
``label`` (the data set whose errors are compared), ``test`` (``mape`` % and ``rmse`` at its
test points), ``baselines_test_mape`` (``{baseline: MAPE %}``), ``dominant_input`` (the input
with the largest total-effect index, as the study names it) and ``modes``
(``{model: {parameter: posterior mode}}``).

Examples
--------
>>> from pathlib import Path
>>> read_reference(Path("no/such/folder")) is None
True
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from calnet.errors import SpecError
from calnet.report.html import fmt
from calnet.results import RunResults

FILE = "reference.json"


def read_reference(folder: str | Path) -> dict[str, Any] | None:
    """``folder/reference.json`` as a dict; None where there is none."""
    path = Path(folder) / FILE
    if not path.is_file():
        return None
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as err:
        raise SpecError(f"{path}: not valid JSON ({err}); fix the file or remove it") from None
    if not isinstance(doc, dict):
        raise SpecError(f"{path}: expected a JSON object of published values, got "
                        f"{type(doc).__name__}")
    return doc


def reference_rows(results: RunResults, units: Mapping[str, str]) -> list[list[str]]:
    """Rows ``[quantity, reference, calnet]`` of ``results.reference`` beside the run's
    values (``units``: ``{data set: unit of its observed output}``); empty without a
    reference."""
    ref = results.reference
    if not ref:
        return []
    rows = []
    name = ref.get("dataset")
    label = ref.get("label", name)
    v = results.validation.get(name)
    if v is not None and v.test is not None and "test" in ref:
        rows.append([f"{label} test MAPE %", fmt(ref["test"]["mape"]), fmt(v.test["mape"])])
        rows.append([f"{label} test SE_pred = RMSE ({units.get(name, '')})",
                     fmt(ref["test"]["rmse"]), fmt(v.test["rmse"])])
        names = {"training_mean": "training-mean", "power_law": "power-law"}
        for base, mape in ref.get("baselines_test_mape", {}).items():
            ours = (v.baselines_test or {}).get(base)
            if ours:
                rows.append([f"{label} test MAPE %, {names.get(base, base)} baseline",
                             fmt(mape), fmt(ours["mape"])])
    sens = results.sensitivity.get(name)
    if sens is not None and "dominant_input" in ref:
        ind = sens.indices
        top = ind.names[max(range(len(ind.ST)), key=lambda j: ind.ST[j])]
        rows.append(["dominant input (total effect)", ref["dominant_input"], top])
    models = results.calibration.models
    for model, modes in ref.get("modes", {}).items():
        params = models.get(model, {}).get("parameters", {})
        for param, value in modes.items():
            if param in params:
                rows.append([f"mode {model}.{param}", fmt(value), fmt(params[param]["mode"])])
    return rows
