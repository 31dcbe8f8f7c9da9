"""Noise, discrepancy and shared-parameter declarations: what loads, and one-line errors
for their misuse."""

from __future__ import annotations

import numpy as np
import pytest

from calnet.errors import SpecError
from calnet.spec import load_spec, read_all


def _error(path) -> str:
    with pytest.raises(SpecError) as info:
        load_spec(path)
    message = str(info.value)
    assert "\n" not in message
    return message


def test_known_noise_and_no_discrepancy_load(base_spec, write_spec):
    base_spec["data"]["width"].update(noise={"sd": 2.5}, discrepancy="none")
    base_spec["data"]["spacing"].update(noise={"prior": {"dist": "halfnormal", "sigma": 0.1}},
                                        discrepancy={"sd_prior": {"dist": "lognormal",
                                                                  "mu": -2, "sigma": 1},
                                                     "orthogonal": False})
    network = load_spec(write_spec(base_spec))
    width = network.dataset("width")
    assert width.noise.known and not width.discrepancy.enabled
    spacing = network.dataset("spacing")
    assert spacing.noise.prior.sigma == 0.1 and not spacing.discrepancy.orthogonal
    data = read_all(network)
    np.testing.assert_array_equal(data["width"].noise_sd, [2.5, 2.5, 2.5])
    assert data["spacing"].noise_sd is None


def test_noise_sd_column(base_spec, write_spec):
    base_spec["data"]["width"]["noise"] = {"sd_column": "err"}
    csv = ("id,power,speed,width,err,split\n1,100,0.5,90,1.5,train\n2,150,1.0,80,2.0,train\n"
           "3,200,1.5,85,2.5,test\n")
    data = read_all(load_spec(write_spec(base_spec, width=csv)))
    np.testing.assert_array_equal(data["width"].noise_sd, [1.5, 2.0, 2.5])
    np.testing.assert_array_equal(data["width"].train.noise_sd, [1.5, 2.0])


@pytest.mark.parametrize("noise,needle", [
    ({"sd": -0.1}, "greater than 0"),
    ({"sd": float("nan")}, "finite"),
    ({"sd": 0.1, "sd_column": "err"}, "give one of sd, sd_column, prior or reference"),
    ({"prior": {"dist": "halfnormal", "sigma": -1}}, "greater than 0"),
    ({"prior": {"dist": "beta", "a": 1, "b": 1}}, "dist"),
    ("loud", "cannot read noise 'loud'"),
])
def test_bad_noise_is_one_line(base_spec, write_spec, noise, needle):
    base_spec["data"]["width"]["noise"] = noise
    message = _error(write_spec(base_spec))
    assert "data.width.noise" in message and needle in message, message


def test_a_missing_sd_column_names_it(base_spec, write_spec):
    base_spec["data"]["width"]["noise"] = {"sd_column": "err"}
    message = _error(write_spec(base_spec))
    assert "noise sd column 'err' is not in the CSV" in message


def test_a_non_positive_sd_in_the_column_names_the_line(base_spec, write_spec):
    base_spec["data"]["width"]["noise"] = {"sd_column": "err"}
    csv = ("id,power,speed,width,err,split\n1,100,0.5,90,1.5,train\n2,150,1.0,80,0,train\n"
           "3,200,1.5,85,2.5,test\n")
    message = _error(write_spec(base_spec, width=csv))
    assert "value(s) <= 0 on line(s) [3]" in message


def test_bad_discrepancy_is_one_line(base_spec, write_spec):
    base_spec["data"]["width"]["discrepancy"] = "off"
    assert "cannot read discrepancy 'off'" in _error(write_spec(base_spec))


def test_the_same_parameter_name_in_two_models_must_be_shared(base_spec, write_spec):
    base_spec["models"]["micro"]["parameters"]["k"] = {"unit": "W/(m K)", "lower": 10,
                                                       "upper": 30}
    message = _error(write_spec(base_spec))
    assert "parameter 'k' is declared in ['heat', 'micro']" in message
    assert "shared: true" in message


def test_shared_parameters_must_agree(base_spec, write_spec):
    base_spec["models"]["heat"]["parameters"]["k"]["shared"] = True
    base_spec["models"]["micro"]["parameters"]["k"] = {"unit": "W/(m K)", "lower": 10,
                                                       "upper": 40, "shared": True}
    message = _error(write_spec(base_spec))
    assert ("models.micro.parameters.k: shared parameter 'k' has upper=40.0 here but upper=30.0 "
            "in 'heat'") in message, message


def test_shared_parameters_load(base_spec, write_spec):
    base_spec["models"]["heat"]["parameters"]["k"]["shared"] = True
    base_spec["models"]["micro"]["parameters"]["k"] = dict(
        base_spec["models"]["heat"]["parameters"]["k"])
    network = load_spec(write_spec(base_spec))
    assert network.param_key("heat", "k") == network.param_key("micro", "k") == "k"
    assert network.param_key("micro", "s") == "micro.s"
