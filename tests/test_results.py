"""metrics.json is assembled in one place, RunResults.to_metrics, from the stages' result
objects: each entry is there exactly when its stage produced something."""

from types import SimpleNamespace

import numpy as np

from calnet.results import (
    CalibrationResult,
    CampaignSummary,
    DatasetValidation,
    RunResults,
    VariantScore,
)


class _Dict(SimpleNamespace):
    """A stage result that writes itself with to_dict()."""

    def to_dict(self):
        return {"value": self.value}


def _run(**kw):
    sur = SimpleNamespace(summary=lambda: {"M.y": {"n_runs": 20}})
    cal = kw.pop("calibration", CalibrationResult("joint", "-", True, {"M": {}}, 1.01, 400,
                                                  sampler={"chains": 4}, notes=("n",)))
    return RunResults("net", True, {"M": CampaignSummary(22, 2, {"ok": 20, "failed": 2})},
                      sur, cal, **kw)


def test_a_calibrated_run_writes_every_stage():
    valid = DatasetValidation(train={"n": 3}, pit=np.array([0.1, 0.5, 0.9]), loo={"k": 1},
                              variance_shares={"noise": 1.0}, test={"n": 1},
                              baselines_test={"training_mean": {"n": 1}})
    score = VariantScore(-3.0, 1.5, 0.0, 0.0, 1.0, 0.4, 600)
    explored = {"d": SimpleNamespace(to_dict=lambda: {"indices": 1},
                                     map=_Dict(value=2)),
                "e": SimpleNamespace(to_dict=lambda: {"indices": 3}, map=None)}
    m = _run(predictions={"d": _Dict(value=4)}, validation={"d": valid},
             sensitivity=explored, predicted_outputs={"M.y": _Dict(value=5)},
             comparison={"d": {"spec": score}}, warnings=("a", "b")).to_metrics()
    assert list(m) == ["network", "quick", "campaigns", "surrogates", "validation",
                       "comparison", "calibration", "predictions", "predicted_outputs",
                       "warnings", "sensitivity", "maps"]
    assert m["campaigns"] == {"M": {"n_total": 22, "n_excluded": 2,
                                    "status_counts": {"ok": 20, "failed": 2}}}
    assert m["validation"]["d"] == {"train": {"n": 3}, "pit": [0.1, 0.5, 0.9],
                                    "test": {"n": 1}, "loo": {"k": 1},
                                    "variance_shares": {"noise": 1.0},
                                    "baselines_test": {"training_mean": {"n": 1}}}
    assert m["comparison"]["d"]["spec"]["draws"] == 600
    assert m["calibration"] == {"mode": "joint", "plug": "-", "sampler": {"chains": 4},
                                "models": {"M": {}}, "datasets": {}, "notes": ["n"], "info": [],
                                "surrogate_check": {}}
    assert m["maps"] == {"d": {"value": 2}}  # only the explorations with a map
    assert m["warnings"] == ["a", "b"]


def test_an_emulation_only_run_writes_no_calibration_comparison_or_predicted_outputs():
    none = CalibrationResult("none", "-", False, {}, 1.01, 400)
    m = _run(calibration=none).to_metrics()
    assert "calibration" not in m and "comparison" not in m
    assert "predicted_outputs" not in m
    assert m["validation"] == {} and m["maps"] == {} and m["predictions"] == {}
    assert "test" not in DatasetValidation({"n": 2}, np.zeros(2), {}, {}).to_dict()
