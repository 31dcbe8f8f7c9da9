"""The default noise and discrepancy priors keep the output's units where the
observations have no spread to scale them with (one point, or all equal)."""

from __future__ import annotations

import re
import warnings

import numpy as np
import pytest
from network_helpers import fitted_network, on_path, write_csv

from calnet.calibration.calibrate_network import calibrate
from calnet.errors import CalibrationWarning
from calnet.spec import read_all
from calnet.spec.models import SamplerSettings

SAMPLER = SamplerSettings(chains=4, warmup=500, draws=1000)


def _network(root, unit: float, ys: list[float], extra: str = ""):
    """y = unit * (a x + 0.5) with a on [0, 4] in units ``unit`` times the base unit,
    observed at ``ys`` (x = 0.5, or spread over [0.2, 0.8]); default priors unless
    ``extra`` (data set YAML)."""
    root.mkdir()
    module = f"scaled_{str(unit).replace('.', '_')}_{len(ys)}_{abs(hash(extra))}"
    (root / f"{module}.py").write_text(
        f"def f(inputs):\n    return {{'y': {unit} * (inputs['a'] * inputs['x'] + 0.5)}}\n")
    write_csv(root / "d.csv", x=np.linspace(0.2, 0.8, len(ys)) if len(ys) > 1 else [0.5],
              y=[unit * y for y in ys])
    (root / "network.yaml").write_text(
        "name: scaled\nmodels:\n"
        f"  m: {{simulator: 'python:{module}:f', inputs: {{x: {{lower: 0, upper: 1}}}},\n"
        "      parameters: {a: {lower: 0, upper: 4, prior: {dist: uniform}}},\n"
        "      outputs: {y: {measurable: true}}, campaign: {runs: 20}}\n"
        f"data:\n  d: {{path: d.csv, observes: m.y{extra}}}\n"
        "settings: {seed: 3}\n")
    with on_path(root):
        return fitted_network(root)


def _posterior_a(network, surrogates):
    data = {k: v.train for k, v in read_all(network).items()}
    post = calibrate(network, surrogates, data=data, sampler=SAMPLER, seed=5)
    a = post.theta["m"][:, 0]
    return float(np.mean(a)), float(np.std(a))


@pytest.mark.parametrize("ys", [[1.5], [1.5, 1.5, 1.5]], ids=["one point", "equal points"])
def test_default_priors_do_not_depend_on_the_output_unit_without_spread(tmp_path, ys):
    """The same information in units 1000 times smaller gives the same posterior of a:
    the default priors take the simulated output's sd when the observations have none,
    and say so."""
    out, said = {}, {}
    for unit in (1.0, 1000.0):
        net, sur = _network(tmp_path / f"u{unit:g}", unit, ys)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            out[unit] = _posterior_a(net, sur)
        said[unit] = [str(w.message) for w in caught if "no spread" in str(w.message)]
        assert len(said[unit]) == 1, [str(w.message) for w in caught]
        assert re.search(r"no spread to scale the default noise and discrepancy priors "
                         r"with; they take the sd of m\.y over its simulation runs \(\S+\) "
                         r"instead; declare noise\.prior and discrepancy\.sd_prior to set "
                         r"them", said[unit][0]), said[unit][0]
    # two samplers whose chains differ by round-off, 4 x 1000 draws each: the sd ratio
    # carries their Monte Carlo error; priors scaled by the data's units gave 0.04
    (m1, s1), (m2, s2) = out[1.0], out[1000.0]
    assert abs(s2 / s1 - 1) < 0.15, out
    assert abs(m2 - m1) < 0.2 * s1, out


def test_declared_priors_or_a_known_noise_need_no_spread(tmp_path):
    """No warning where no default prior needs the observations' sd."""
    net, sur = _network(tmp_path / "known", 1.0, [1.5],
                        extra=", noise: {sd: 0.1}, discrepancy: none")
    with warnings.catch_warnings():
        warnings.filterwarnings("error", message=".*no spread.*", category=CalibrationWarning)
        warnings.filterwarnings("ignore", message=".*data point.*", category=CalibrationWarning)
        warnings.filterwarnings("ignore", message=".*(R-hat|ESS|divergent).*",
                                category=CalibrationWarning)
        _posterior_a(net, sur)


def test_the_summary_says_where_the_default_priors_take_their_scale(tmp_path):
    """The posterior summary's words on the priors name the scale actually used."""
    from calnet.calibration.summary import data_set_summary

    net, sur = _network(tmp_path / "summary", 1.0, [1.5])
    data = {k: v.train for k, v in read_all(net).items()}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CalibrationWarning)
        post = calibrate(net, sur, data=data, sampler=SAMPLER, seed=5)
    text = data_set_summary(net, post)["d"]["priors"]
    assert text.count("scale: the simulation runs' sd: the observations have no spread") == 2
