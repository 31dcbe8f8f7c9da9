"""The surrogates' cross-validation run after their fits (what ``calnet run`` does beside
the calibration) gives what the fits with cross-validation give, and can be stopped
between folds."""

from __future__ import annotations

import numpy as np
import pytest

from calnet.campaign import run_campaign
from calnet.errors import SurrogateError
from calnet.spec import load_spec
from calnet.surrogates import fit_network as sn


def _network(folder, monkeypatch, module: str, body: str, runs: int, cv_folds: int):
    """A model ``m`` (input x, parameter a, output y) whose simulator ``module:f`` (a name
    of its own: modules stay imported) returns ``{'y': body}``; its campaign run."""
    (folder / f"{module}.py").write_text(
        f"import math\ndef f(inputs):\n    return {{'y': {body}}}\n")
    (folder / "d.csv").write_text("x,y\n0.5,1.5\n0.2,1.1\n")
    (folder / "network.yaml").write_text(
        f"models:\n  m: {{simulator: 'python:{module}:f', inputs: {{x: {{lower: 0, upper: 1}}}},"
        "\n      parameters: {a: {lower: 0, upper: 2}},\n"
        "      outputs: {y: {measurable: true}},\n"
        f"      campaign: {{runs: {runs}}}, surrogate: {{cv_folds: {cv_folds}, restarts: 1}}}}\n"
        "data:\n  d: {path: d.csv, observes: m.y, columns: {x: x, y: y}}\n")
    monkeypatch.syspath_prepend(str(folder))
    net = load_spec(folder)
    run_campaign(net, "m", executor="in-process", progress=False)
    return net


def test_cross_validation_after_the_fits_matches_the_fits_with_it(tmp_path, monkeypatch):
    net = _network(tmp_path, monkeypatch, "later_sin",
                   "math.sin(3 * inputs['x']) + inputs['a'] * inputs['x']", 16, 4)
    together = sn.fit_surrogates(net, seed=3)
    fitted = sn.fit_surrogates(net, seed=3, cv=False)
    assert fitted.items["m.y"].cv is None
    later = sn.cross_validate_surrogates(net, fitted, seed=3)
    a, b = together.items["m.y"].cv, later.items["m.y"].cv
    assert b is not None and b.k == 4
    np.testing.assert_array_equal(a.fold, b.fold)
    np.testing.assert_allclose(b.mean, a.mean, rtol=1e-9)
    np.testing.assert_allclose(b.var, a.var, rtol=1e-9)
    numbers = {k: v for k, v in a.metrics().items() if isinstance(v, float)}
    assert numbers and {k: b.metrics()[k] for k in numbers} == pytest.approx(numbers,
                                                                             rel=1e-9)
    assert later.items["m.y"].gp is fitted.items["m.y"].gp  # the fits are kept as they are


def test_an_interrupt_between_folds_stops_the_cross_validation(tmp_path, monkeypatch):
    net = _network(tmp_path, monkeypatch, "later_lin", "1 + inputs['x'] * inputs['a']",
                   12, 6)
    fitted = sn.fit_surrogates(net, seed=1, cv=False)
    folds = []

    def before_fold():
        folds.append(1)
        if len(folds) == 3:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        sn.cross_validate_surrogates(net, fitted, seed=1, before_fold=before_fold)
    assert len(folds) == 3  # no fold started after it


def test_too_few_runs_for_the_folds_is_said_before_any_fit(tmp_path, monkeypatch):
    """4 runs in 4 folds leave 3 training points, fewer than the d + 2 = 4 that a GP on
    x and a needs: said by the check that ``calnet run`` makes before its fits."""
    net = _network(tmp_path, monkeypatch, "later_few", "1 + inputs['x'] * inputs['a']",
                   4, 4)
    with pytest.raises(SurrogateError, match=r"'m.y': 4-fold CV on 4 points leaves 3 "
                                             r"training points, need d \+ 2 = 4"):
        sn.check_cross_validation(net)
    with pytest.raises(SurrogateError, match="4-fold CV on 4 points"):
        sn.fit_surrogates(net)  # as the fits with their cross-validation say
