"""Cross-validation metrics on cases with known answers, and the parity plot."""

import numpy as np
import pytest

from calnet.surrogates import cross_validate, cv_metrics, kfold_indices, parity_plot


def test_coverage_and_metrics_on_hand_made_numbers():
    y = np.array([1.0, 2.0, 4.0, -5.0])
    yhat = np.array([1.1, 2.0, 3.0, -5.5])
    lo = np.array([0.9, 2.5, 4.0, -6.0])  # in, out (below lo), on the edge (in), in
    hi = np.array([1.2, 3.0, 5.0, -4.5])
    m = cv_metrics(y, yhat, lo, hi)
    assert m["coverage95"] == 0.75
    assert m["mape"] is None  # outputs of both signs: a percentage error means nothing
    assert m["rmse"] == pytest.approx(np.sqrt((0.01 + 0 + 1 + 0.25) / 4))
    y, yhat = np.array([1.0, 2.0, 4.0, 5.0]), np.array([1.1, 2.0, 3.0, 5.5])
    m = cv_metrics(y, yhat, y - 1, y + 1)
    assert m["mape"] == pytest.approx(100 * (0.1 / 1 + 0 + 1 / 4 + 0.5 / 5) / 4)


def test_mape_is_left_out_where_an_output_reaches_zero():
    y = np.array([0.0, 1.0, 2.0, 3.0])  # a divide by zero: no warning, no infinity
    m = cv_metrics(y, y + 0.1, y - 1, y + 1)
    assert m["mape"] is None and m["rmse"] == pytest.approx(0.1)


def test_folds_are_seeded_shuffled_and_balanced():
    f = kfold_indices(17, 5, seed=0)
    assert sorted(np.bincount(f).tolist()) == [3, 3, 3, 4, 4]
    np.testing.assert_array_equal(f, kfold_indices(17, 5, seed=0))
    assert not np.array_equal(f, kfold_indices(17, 5, seed=1))
    assert not np.array_equal(f, np.sort(f))


@pytest.fixture(scope="module")
def linear_cv():
    # A linear function of (P, v) in physical units: a GP with long length scales
    # reproduces it to ~1e-5 relative, so out-of-fold MAPE is far below 0.1 %, while the
    # outputs (100 .. 400) make a MAPE bug (e.g. a missing *100 or |y| in the wrong place)
    # visible. 36 points, 6 folds: every fold trains on 30 points.
    rng = np.random.default_rng(4)
    lo, hi = np.array([80.0, 0.05]), np.array([250.0, 2.0])
    x = lo + rng.random((36, 2)) * (hi - lo)
    y = 20.0 + 1.5 * x[:, 0] - 30.0 * x[:, 1]
    return cross_validate(x, y, k=6, lower=lo, upper=hi, n_restarts=1, name="W"), x, y


def test_cv_on_a_linear_function(linear_cv):
    cv, _, y = linear_cv
    assert cv.n == 36 and cv.k == 6 and cv.name == "W"
    np.testing.assert_array_equal(cv.y, y)
    assert np.bincount(cv.fold).tolist() == [6] * 6
    assert 0 < cv.mape < 0.1
    resid = cv.y - cv.mean
    assert cv.mape == pytest.approx(100 * np.mean(np.abs(resid) / np.abs(y)))
    assert cv.rmse == pytest.approx(np.sqrt(np.mean(resid**2)))
    inside = (cv.lower95 <= y) & (y <= cv.upper95)
    assert cv.coverage95 == pytest.approx(inside.mean())
    np.testing.assert_allclose(cv.upper95 - cv.mean, 1.959963984540054 * np.sqrt(cv.var))
    assert cv.metrics()["mape"] == cv.mape


def test_cv_log_transform_intervals_are_lognormal():
    rng = np.random.default_rng(5)
    x = rng.random((36, 2))
    y = np.exp(1.0 + 2.0 * x[:, 0] - x[:, 1])  # log-linear
    cv = cross_validate(x, y, k=6, lower=[0, 0], upper=[1, 1], transform="log",
                        n_restarts=1, seed=2)
    sd = np.sqrt(cv.var_modelled)
    np.testing.assert_allclose(cv.lower95, np.exp(cv.mean_modelled - 1.959963984540054 * sd))
    np.testing.assert_allclose(cv.mean, np.exp(cv.mean_modelled + cv.var_modelled / 2))
    assert cv.mape < 0.5


def test_parity_plot_writes_a_png(linear_cv, tmp_path):
    cv, _, _ = linear_cv
    path = parity_plot(cv, tmp_path / "figs" / "W.png", title="W parity", units="um")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_the_parity_plot_of_a_log_gp_over_decades_has_log_axes(tmp_path, monkeypatch):
    from matplotlib.figure import Figure

    saved = []
    save = Figure.savefig
    monkeypatch.setattr(Figure, "savefig", lambda fig, *a, **k: saved.append(fig)
                        or save(fig, *a, **k))
    rng = np.random.default_rng(5)
    x = rng.random((30, 1))
    cv = cross_validate(x, np.exp(5.0 * x[:, 0]), k=5, lower=[0], upper=[1],
                        transform="log", n_restarts=1, seed=2)
    parity_plot(cv, tmp_path / "log.png", units="MPa")
    ax = saved[-1].axes[0]
    assert (ax.get_xscale(), ax.get_yscale()) == ("log", "log")
    assert ax.get_title().endswith("5-fold CV, GP on ln") and "(MPa)" in ax.get_xlabel()


@pytest.mark.parametrize("mean,transform", [("constant", None), ("linear", "log"),
                                            ("quadratic", None)])
def test_each_fold_is_the_fit_on_its_training_points(mean, transform):
    # the folds run on the full arrays with the held-out points decoupled (one compiled
    # program for every fold); each must predict as fit_gp on the fold's own points does
    from calnet.surrogates import fit_gp

    rng = np.random.default_rng(4)
    x = rng.uniform(0.0, 2.0, (45, 2))
    y = np.exp(0.4 * x[:, 0] + np.sin(2 * x[:, 1])) + 0.01 * rng.normal(size=45)
    kw = dict(lower=[0.0, 0.0], upper=[2.0, 2.0], transform=transform, n_restarts=1, seed=5,
              mean=mean)
    cv = cross_validate(x, y, k=4, **kw)
    for i in range(4):
        test = cv.fold == i
        gp = fit_gp(x[~test], y[~test], **kw)
        m, v = (np.asarray(a) for a in gp.predict(x[test], include_nugget=True))
        np.testing.assert_allclose(cv.mean_modelled[test], m, rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(cv.var_modelled[test], v, rtol=1e-3)
