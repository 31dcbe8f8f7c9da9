"""metrics.json: strict JSON, sorted keys, numpy converted, NaN/inf -> null."""

import json
from dataclasses import dataclass

import numpy as np
import pytest

from calnet.report import to_jsonable, write_metrics


@dataclass(frozen=True)
class _Result:
    value: np.ndarray

    def to_dict(self):
        return {"value": self.value}


@dataclass(frozen=True)
class _Plain:
    a: float
    b: tuple


def test_round_trip_and_nan_to_null(tmp_path):
    metrics = {"z": np.float32(1.5), "a": np.arange(3), "nan": float("nan"),
               "inf": np.array([np.inf, -np.inf, 2.0]), "nested": {"b": [np.int64(4), None]},
               "res": _Result(np.array([[1.0, np.nan]])), "plain": _Plain(0.5, (1, 2)),
               "flag": np.bool_(True), 3: "int key", "path": tmp_path / "x"}
    path = write_metrics(tmp_path / "m" / "metrics.json", metrics)
    text = path.read_text()
    assert "NaN" not in text and "Infinity" not in text
    loaded = json.loads(text, parse_constant=lambda c: pytest.fail(f"non-strict {c}"))
    assert loaded["z"] == 1.5 and loaded["a"] == [0, 1, 2] and loaded["nan"] is None
    assert loaded["inf"] == [None, None, 2.0] and loaded["nested"] == {"b": [4, None]}
    assert loaded["res"] == {"value": [[1.0, None]]} and loaded["plain"] == {"a": 0.5,
                                                                          "b": [1, 2]}
    assert loaded["flag"] is True and loaded["3"] == "int key"
    assert list(loaded) == sorted(loaded)
    assert text.startswith('{\n  "3"')
    assert json.loads(json.dumps(to_jsonable(metrics), allow_nan=False)) == loaded


def test_jax_arrays_convert():
    import jax.numpy as jnp

    assert to_jsonable({"x": jnp.array([1.0, 2.0]), "s": jnp.float32(3.0)}) == {
        "x": [1.0, 2.0], "s": 3.0}


def test_unknown_type_is_named():
    with pytest.raises(TypeError, match="object"):
        to_jsonable({"x": object()})


def test_run_info_holds_what_varies_between_runs(tmp_path):
    from calnet.report import write_run_info
    from calnet.report.metrics import run_environment

    env = run_environment()
    assert env["versions"]["calnet"] and env["versions"]["jax"] and env["host"]
    path = write_run_info(tmp_path / "run_info.json", {"timings_s": {"total": 1.5}, **env})
    loaded = json.loads(path.read_text())
    assert loaded["timings_s"] == {"total": 1.5} and list(loaded) == sorted(loaded)
    assert [p.name for p in tmp_path.iterdir()] == ["run_info.json"]  # no temporary left
