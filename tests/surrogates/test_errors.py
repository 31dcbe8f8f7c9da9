"""Each user-facing surrogate error: one line, names the output, says the fix."""

import numpy as np
import pytest
from network_helpers import one_model_campaign

from calnet.errors import CalnetError, SurrogateError, SurrogateWarning
from calnet.surrogates import cross_validate, fit_gp, load_gp

LO, HI = np.zeros(3), np.ones(3)


def _data(n=12, seed=0):
    x = np.random.default_rng(seed).random((n, 3))
    return x, 1.0 + x[:, 0] + np.sin(3 * x[:, 1])


def _raises(match, *args, fn=fit_gp, **kwargs):
    kwargs.setdefault("lower", LO)
    kwargs.setdefault("upper", HI)
    with pytest.raises(SurrogateError, match=match) as info:
        fn(*args, **kwargs)
    assert "\n" not in str(info.value) and isinstance(info.value, CalnetError)
    return str(info.value)


def test_too_few_points_for_the_dimension():
    x, y = _data(n=4)
    msg = _raises(r"output 'W': 4 training points for 3 inputs, need at least d \+ 2 = 5",
                  x, y, name="W")
    assert "larger campaign" in msg


def test_too_few_points_for_the_folds():
    x, y = _data(n=8)
    _raises(r"8 training points .* need at least 10 for 10-fold CV", x, y, k=10,
            fn=cross_validate, name="W")
    _raises(r"2-fold CV on 8 points leaves 4 training points, need d \+ 2 = 5", x, y, k=2,
            fn=cross_validate, name="W")
    _raises(r"k must be an integer >= 2", x, y, k=1, fn=cross_validate)


def test_constant_output():
    x, _ = _data()
    _raises(r"output 'lambda' is constant \(value 3.5 at all 12 points\).*remove what "
            r"needs its surrogate", x, np.full(12, 3.5), name="lambda")


def test_non_finite_values_are_counted():
    x, y = _data()
    x[2, 1] = np.nan
    y[5] = np.inf
    y[7] = np.nan
    _raises(r"output 'G0': 3 of 12 training points have non-finite .*drop failed runs",
            x, y, name="G0")


def test_log_transform_needs_positive_outputs():
    x, y = _data()
    y[:2] = [0.0, -1.0]
    _raises(r"transform='log' needs positive outputs, got 2 values <= 0", x, y,
            transform="log")
    _raises(r"transform must be None or 'log', got 'sqrt'", x, y + 5, transform="sqrt")


def test_shapes_and_bounds():
    x, y = _data()
    _raises(r"X must have shape \(n, d\), got \(12,\)", x[:, 0], y)
    _raises(r"y must have shape \(12,\)", x, y[:5])
    _raises(r"lower and upper must have shape \(3,\)", x, y, lower=[0, 0])
    _raises(r"upper > lower", x, y, upper=[1, 0, 1])


def test_cholesky_failure_after_nugget_retries():
    # Exact duplicate inputs with different outputs and a nugget pinned near zero: K is
    # singular, and 10x, 100x, 1000x of 1e-30 is still far below rounding error (~1e-16).
    x, y = _data(n=10)
    x = np.vstack([x, x, x])
    y = np.concatenate([y, y + 0.1, y - 0.1])
    msg = _raises(r"not positive definite even with nugget 1e-27; remove duplicate", x, y,
                  nugget_bounds=(1e-30, 1e-30), n_restarts=0, name="W")
    assert msg.startswith("output 'W'")


def test_nugget_is_raised_with_a_warning_when_that_suffices(monkeypatch):
    import calnet.surrogates.fit as fit_module

    real = fit_module.condition
    calls = []

    def flaky(*args, nugget, **kwargs):  # pretend K fails to factorise below nugget 1e-3
        calls.append(nugget)
        gp = real(*args, nugget=nugget, **kwargs)
        return gp if nugget >= 1e-3 else type(gp)(**{**gp.__dict__, "alpha": gp.alpha * np.nan})

    monkeypatch.setattr(fit_module, "condition", flaky)
    x, y = _data()
    with pytest.warns(SurrogateWarning, match="nugget raised to"):
        gp = fit_gp(x, y, lower=LO, upper=HI, nugget_bounds=(1e-4, 1e-4), n_restarts=0)
    np.testing.assert_allclose(calls, [1e-4, 1e-3])
    assert float(gp.nugget) == pytest.approx(1e-3) and np.isfinite(float(gp.nlml))


def test_load_errors(tmp_path):
    with pytest.raises(SurrogateError, match="surrogate file not found"):
        load_gp(tmp_path / "missing.npz")
    (tmp_path / "bad.npz").write_bytes(b"")
    (tmp_path / "bad.json").write_text('{"format": "other"}')
    with pytest.raises(SurrogateError, match="not a calnet.FittedGP sidecar of version 1 or 2"):
        load_gp(tmp_path / "bad.npz")


def test_a_campaign_without_an_ok_run_says_how_to_run_it_again(tmp_path, monkeypatch):
    from calnet.surrogates.fit_network import fit_surrogates

    net = one_model_campaign(tmp_path, monkeypatch, "nan_sims", "float('nan')",
                              "campaign: {runs: 3}")
    with pytest.raises(SurrogateError, match="m.y: all 3 runs failed") as info:
        fit_surrogates(net, cv=False)
    assert "--retry-failed" in str(info.value) and "\n" not in str(info.value)


def test_caps_never_raise_the_spec_settings(tmp_path, monkeypatch):
    """``restarts``/``cv_folds`` (``calnet run --quick``) cap the spec's settings; a spec
    that asks for less work keeps its own numbers."""
    from calnet.surrogates import fit_network as sn

    net = one_model_campaign(tmp_path, monkeypatch, "lin_sims", "1 + inputs['x']",
                              "campaign: {runs: 12}, surrogate: {cv_folds: 3, restarts: 1}")
    seen = []
    fit = sn.fit_gp

    def spy(*a, **kw):
        seen.append(kw["n_restarts"])
        return fit(*a, **kw)

    monkeypatch.setattr(sn, "fit_gp", spy)
    sur = sn.fit_surrogates(net, restarts=2, cv_folds=5)
    assert seen == [1] and sur.items["m.y"].cv.fold.max() == 2  # k = 3, not 5
    seen.clear()
    sur = sn.fit_surrogates(net, restarts=2, cv_folds=2)
    assert seen == [1] and sur.items["m.y"].cv.fold.max() == 1  # a lower cap applies
