"""The surrogates' cross-validation run after their fits (what ``calnet run`` does beside
the calibration) gives what the fits with cross-validation give, and can be stopped
between folds."""

from __future__ import annotations

import numpy as np
import pytest
from network_helpers import one_model_campaign

from calnet.errors import SurrogateError
from calnet.surrogates import fit_network as sn


def _network(folder, monkeypatch, module: str, body: str, runs: int, cv_folds: int):
    """Model ``m`` (input x, parameter a, output y = ``body``), its campaign run."""
    return one_model_campaign(folder, monkeypatch, module, body,
                              f"parameters: {{a: {{lower: 0, upper: 2}}}}, campaign: "
                              f"{{runs: {runs}}}, surrogate: {{cv_folds: {cv_folds}, "
                              "restarts: 1}")


def test_cross_validation_after_the_fits_matches_the_fits_with_it(tmp_path, monkeypatch):
    net = _network(tmp_path, monkeypatch, "later_cubic",
                   "inputs['x'] ** 3 - inputs['x'] + inputs['a'] * inputs['x']", 16, 4)
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


def test_a_trend_with_too_few_runs_per_fold_is_said_before_any_fit(tmp_path, monkeypatch):
    """An explicit quadratic mean in (x, a) has 6 coefficients and needs 8 runs: 9 runs are
    enough for the full fit, but 3 folds leave 6 training runs each; the check says so
    before anything is fitted, naming the mean function."""
    net = one_model_campaign(tmp_path, monkeypatch, "later_quad",
                             "1 + inputs['x'] * inputs['a']",
                             "parameters: {a: {lower: 0, upper: 2}}, campaign: {runs: 9}, "
                             "surrogate: {cv_folds: 3, restarts: 1, mean: quadratic}")
    with pytest.raises(SurrogateError, match=r"'m.y': its quadratic mean has 6 coefficients, "
                       r"so each cross-validation fold needs at least 8 training runs, but "
                       r"3-fold CV on 9 runs leaves 6; run more simulations"):
        sn.check_cross_validation(net)
    with pytest.raises(SurrogateError, match="its quadratic mean has 6 coefficients"):
        sn.fit_surrogates(net)  # said before the full fit, not by a fold
    fitted = sn.fit_surrogates(net, cv=False)  # the full fit has its 9 >= 8 runs
    assert fitted.items["m.y"].gp.mean == "quadratic"
