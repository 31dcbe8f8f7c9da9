"""Prediction through the chain without data: Monte Carlo through the linked GPs against
Gauss-Hermite quadrature, and posteriors without parameters."""

from __future__ import annotations

import numpy as np
import pytest

from calnet.calibration.calibrate_network import calibrate
from calnet.emulation import predict_output
from calnet.errors import CalibrationWarning, CalnetError
from calnet.spec import Input, Link, Model, Network, Output, SimulatorRef
from calnet.surrogates.fit import fit_gp
from calnet.surrogates.fit_network import OutputSurrogate, Surrogates

SIM = SimulatorRef(kind="python", target="toy:f")


def _two_model_chain() -> tuple[Network, Surrogates]:
    """a: x -> u = sin(2x) from 4 runs (a GP with real uncertainty between them);
    b: u -> y = u^2 + u from 8 runs; nothing observed, b.y requested."""
    net = Network(
        models=[Model(name="a", simulator=SIM, inputs=[Input(name="x", lower=0, upper=1)],
                      outputs=[Output(name="u")]),
                Model(name="b", simulator=SIM, inputs=[Input(name="u", lower=-0.2, upper=1.2)],
                      outputs=[Output(name="y")])],
        links=[Link(**{"from": "a.u", "to": "b.u"})], settings={"predict": ["b.y"]})
    xa = np.linspace(0, 1, 4)[:, None]
    ub = np.linspace(-0.2, 1.2, 8)[:, None]
    gp_a = fit_gp(xa, np.sin(2 * xa[:, 0]), lower=[0.0], upper=[1.0], seed=0)
    gp_b = fit_gp(ub, ub[:, 0] ** 2 + ub[:, 0], lower=[-0.2], upper=[1.2], seed=0)
    sur = Surrogates({"a.u": OutputSurrogate("a", "u", gp_a, None, 4, 0),
                      "b.y": OutputSurrogate("b", "y", gp_b, None, 8, 0)})
    return net, sur


def _observed_chain() -> tuple[Network, Surrogates]:
    """:func:`_two_model_chain` with b.y observed by data set ``d`` (known noise sd 0.05,
    no discrepancy)."""
    net, sur = _two_model_chain()
    raw = net.model_dump(by_alias=True)
    raw["models"][1]["outputs"][0]["measurable"] = True
    raw["data"] = [{"name": "d", "path": "d.csv", "observes": "b.y",
                    "columns": {"x": "x", "y": "y"}, "noise": {"sd": 0.05},
                    "discrepancy": "none"}]
    return Network(**raw), sur


def _quadrature(sur: Surrogates, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean and variance of b.y at x: u ~ N(m_a, v_a), y | u ~ N(m_b(u), v_b(u))."""
    t, w = np.polynomial.hermite.hermgauss(80)
    m_a, v_a = (np.asarray(a) for a in sur["a.u"].gp.predict(x[:, None]))
    u = m_a[:, None] + np.sqrt(2 * v_a)[:, None] * t[None]  # (n, 80)
    m_b, v_b = (np.asarray(a).reshape(u.shape) for a in sur["b.y"].gp.predict(u.reshape(-1, 1)))
    w = w / np.sqrt(np.pi)
    mean = m_b @ w
    return mean, (v_b + m_b**2) @ w - mean**2


def test_monte_carlo_through_the_chain_matches_quadrature():
    net, sur = _two_model_chain()
    post = calibrate(net, sur)  # no data sets: an empty posterior, nothing sampled
    assert post.n_draws == 0 and not post.calibrated and post.theta == {}
    x = np.array([0.1, 0.2, 0.5, 0.8, 0.95])
    n = 20000
    pred = predict_output(net, sur, post, "b.y", x[:, None], n_samples=n, seed=3)
    mean, var = _quadrature(sur, x)
    assert np.all(var > 1e-3)  # the upstream GP's uncertainty matters at these points
    assert np.allclose(mean, np.sin(2 * x) ** 2 + np.sin(2 * x), atol=0.15)  # GPs are sane
    # Monte Carlo error of a mean: sd / sqrt(n); of a variance: about var sqrt(2 / n)
    # (a bit more for the heavier-tailed mixture; 5 standard errors)
    assert np.all(np.abs(pred.mean - mean) < 4 * np.sqrt(var / n)), (pred.mean, mean)
    assert np.allclose(pred.samples.var(axis=0), var, rtol=5 * np.sqrt(2 / n) * 1.5)
    assert np.all((pred.lower < mean) & (mean < pred.upper))
    assert set(pred.budget) == {"emulator a.u", "emulator b.y"}  # no parameters
    assert pred.dataset is None and pred.observes == "b.y" and pred.input_keys == ("a.x",)


def test_same_seed_same_prediction_and_bad_requests():
    net, sur = _two_model_chain()
    post = calibrate(net, sur)
    x = np.array([[0.3], [0.6]])
    one, two = (predict_output(net, sur, post, "b.y", x, n_samples=500, seed=5) for _ in "ab")
    assert np.array_equal(one.samples, two.samples)
    other = predict_output(net, sur, post, "b.y", x, n_samples=500, seed=6)
    assert not np.array_equal(one.samples, other.samples)
    with pytest.raises(CalnetError, match=r"'b.z' is not an output of the network"):
        predict_output(net, sur, post, "b.z", x)
    without = Surrogates({"a.u": sur.items["a.u"]})  # b.y's surrogate not fitted
    with pytest.raises(CalnetError, match=r"no surrogate for 'b.y'; list it under "
                                          r"settings.predict"):
        predict_output(net, without, post, "b.y", x)
    with pytest.raises(CalnetError, match=r"expected 1 process inputs \['a.x'\] as "
                                          r"columns, got 2"):
        predict_output(net, sur, post, "b.y", np.ones((2, 2)))


def test_data_without_parameters_or_anything_to_sample_predicts():
    """Known noise, no discrepancy, no parameters: nothing is sampled (0 draws), and the
    data set's prediction is the GP chain plus the noise (no IndexError)."""
    from calnet.predict import predict
    from calnet.spec import ExperimentalData

    net, sur = _observed_chain()
    x = np.array([[0.2], [0.5], [0.9]])
    y = np.sin(2 * x[:, 0]) ** 2 + np.sin(2 * x[:, 0])
    data = {"d": ExperimentalData("d", "b.y", ("a.x",), x, y, np.zeros(3, bool),
                                  ("1", "2", "3"), np.full(3, 0.05))}
    with pytest.warns(CalibrationWarning, match="the surrogate, not the data, sets"):
        post = calibrate(net, sur, data=data)  # 4 runs of a against sd 0.05: it does
    assert post.n_draws == 0 and post.calibrated and post.hyper == {"d": {}}
    pred = predict(net, sur, post, "d", x, n_samples=400, seed=0)
    mean, var = _quadrature(sur, x[:, 0])
    sd = np.sqrt(var + 0.05**2)
    # 200 rows (the default n_draws, from 0 draws), each with its own upstream draw
    assert np.all(np.abs(pred.mean - mean) < 4 * sd / np.sqrt(200))
    assert np.all(pred.lower < mean) and np.all(mean < pred.upper)


def test_predict_from_python_checks_its_settings_and_names(monkeypatch):
    """The Python ``predict`` says what the command line says: a setting that is not a
    finite number or a data set the network does not have is a one-line UsageError (not
    a plausible number, not a bare KeyError); a setting outside the bounds is warned of."""
    import warnings

    from calnet.errors import UsageError
    from calnet.predict import predict
    from calnet.spec import ExperimentalData

    net, sur = _observed_chain()
    x = np.array([[0.2], [0.5], [0.9]])
    data = {"d": ExperimentalData("d", "b.y", ("a.x",), x, np.sin(2 * x[:, 0]),
                                  np.zeros(3, bool), ("1", "2", "3"), np.full(3, 0.05))}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CalibrationWarning)
        post = calibrate(net, sur, data=data)
    for bad in (np.nan, np.inf):
        with pytest.raises(UsageError, match=r"predict: a.x = (nan|inf) at point 2 is not a "
                                             r"finite number \(1 point\(s\)\)"):
            predict(net, sur, post, "d", np.array([[0.5], [bad]]))
    with pytest.raises(UsageError, match=r"^no data set named 'b.y'; the network's data "
                                         r"sets: \['d'\] \('b.y' names a model's output: "
                                         r"calnet.emulation.predict_output predicts one\)$"):
        predict(net, sur, post, "b.y", x)
    with pytest.raises(KeyError):  # and still a KeyError for code that looks names up
        net.dataset("nope")
    with pytest.warns(UserWarning, match=r"predict: a.x lies outside its bounds \[0, 1\] "
                                         r"at 1 of 2 point\(s\) \(point 2: 1.5\)"):
        predict(net, sur, post, "d", np.array([[0.5], [1.5]]))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # inside the bounds: nothing to say
        two = predict(net, sur, post, "d", x)
    # one process input: a 1-D array is that many points
    flat = predict(net, sur, post, "d", x[:, 0])
    np.testing.assert_array_equal(flat.mean, two.mean)
    with pytest.raises(UsageError, match=r"predict: no settings given \(x has 0 rows\)"):
        predict(net, sur, post, "d", np.zeros((0, 1)))
    with pytest.raises(UsageError, match=r"expected 1 process inputs \['a.x'\] as columns, "
                                         r"got 2 column\(s\)"):
        predict(net, sur, post, "d", np.zeros((3, 2)))
    # the same from predict_output (an output through the chain), and its names
    with pytest.raises(UsageError, match=r"predict b.y: a.x = nan at point 1"):
        predict_output(net, sur, post, "b.y", np.array([[np.nan]]))
    with pytest.warns(UserWarning) as caught:
        predict_output(net, sur, post, "b.y", np.array([[3.0]]))
    said = [str(w.message) for w in caught]
    assert any(m.startswith("predict b.y: a.x lies outside its bounds") for m in said), said
    # and the linked inputs that leave their bounds, as the command line says them
    # (calnet.predict.link_notes, tested with the command)
    import calnet.predict

    note = "point 1: b.u = 1.3 (from a.u) lies outside its bounds [-0.2, 1.2]"
    monkeypatch.setattr(calnet.predict, "link_notes", lambda *a: [note])
    with pytest.warns(UserWarning, match=r"^predict b.y: point 1: b.u = 1.3 \(from a.u\)"):
        predict_output(net, sur, post, "b.y", x)
    with pytest.warns(UserWarning, match=r"^predict: point 1: b.u = 1.3 \(from a.u\)"):
        predict(net, sur, post, "d", x)
    with pytest.raises(UsageError, match=r"no model named 'q'; the network's models: "
                                         r"\['a', 'b'\]"):
        predict_output(net, sur, post, "q.y", x)
    with pytest.raises(UsageError, match=r"'b.w' is not an output of the network; 'b' has "
                                         r"\['y'\]"):
        predict_output(net, sur, post, "b.w", x)


def test_a_linear_output_into_a_log_scale_input_is_warned_of_twice():
    """An output modelled on its own scale feeding an input on the log scale: calnet check
    (load_spec) warns of it, and a prediction whose upstream draws go <= 0 there says
    which points came out not a number instead of passing the NaN on silently."""
    import warnings

    from calnet.errors import SpecWarning
    from calnet.spec.load import check_log_links

    net = Network(
        models=[Model(name="a", simulator=SIM, inputs=[Input(name="x", lower=0, upper=1)],
                      outputs=[Output(name="u")]),
                Model(name="b", simulator=SIM,
                      inputs=[Input(name="u", lower=0.05, upper=1.2, scale="log")],
                      outputs=[Output(name="y")])],
        links=[Link(**{"from": "a.u", "to": "b.u"})], settings={"predict": ["b.y"]})
    with pytest.warns(SpecWarning, match=r"links\[0\]: b.u is on the log scale but a.u is "
                                         r"modelled on its own.*declare 'transform: log' "
                                         r"on a.u"):
        check_log_links(net)
    xa = np.linspace(0, 1, 4)[:, None]
    ub = np.linspace(0.05, 1.2, 8)[:, None]
    gp_a = fit_gp(xa, np.sin(2 * xa[:, 0]), lower=[0.0], upper=[1.0], seed=0)
    gp_b = fit_gp(np.log(ub), np.log(ub[:, 0]), lower=[np.log(0.05)], upper=[np.log(1.2)],
                  seed=0)
    sur = Surrogates({"a.u": OutputSurrogate("a", "u", gp_a, None, 4, 0),
                      "b.y": OutputSurrogate("b", "y", gp_b, None, 8, 0)})
    post = calibrate(net, sur)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        pred = predict_output(net, sur, post, "b.y", np.array([[0.0], [0.5]]))
    said = [str(w.message) for w in caught]
    assert not np.isfinite(pred.mean[0]) and np.isfinite(pred.mean[1])  # u = sin 0 = 0
    assert any(m.startswith("b.y: 1 of 2 point(s) have no finite prediction (point(s) [1])")
               for m in said), said
