"""``calnet run`` cross-validates the surrogates in a thread beside the calibration: the
surrogates stage ends after the fits, the calibration stage collects the cross-validation
(and its parity plots), and a run that stops earlier starts no further fold."""

from __future__ import annotations

import threading
from pathlib import Path
from types import SimpleNamespace

import pytest

import calnet.calibration.calibrate_network as calibrate_network
import calnet.pipeline as pipeline
from calnet.spec import load_spec
from calnet.surrogates.fit_network import Surrogates

#: what the stubbed calibration returns: a posterior with no set-up notes
POSTERIOR = SimpleNamespace(info=())

NINB = Path(__file__).resolve().parents[1] / "examples" / "ninb"


@pytest.fixture
def context(tmp_path, monkeypatch):
    network = load_spec(NINB)
    network = network.model_copy(update={"settings": network.settings.model_copy(
        update={"compare": ()})})  # no variants
    ctx = pipeline._Context(network, tmp_path, quick=True, fresh=False, loo_max=0)
    fitted = Surrogates({})
    monkeypatch.setattr(pipeline, "check_cross_validation", lambda *a, **k: None)

    def fit(network, *, cv, **kwargs):
        assert cv is False  # the fits alone
        return fitted

    monkeypatch.setattr(pipeline, "fit_surrogates", fit)
    monkeypatch.setattr(pipeline, "parity_plots",
                        lambda network, sur, folder: {"m.y": folder / "cv_m.y.png"})
    monkeypatch.setattr(pipeline, "record_calibration", lambda *a, **k: "recorded")
    monkeypatch.setattr(calibrate_network, "calibrate", lambda *a, **k: POSTERIOR)
    return ctx, fitted


def test_the_calibration_collects_the_cross_validation_run_beside_it(context, monkeypatch):
    ctx, fitted = context
    go, with_cv = threading.Event(), Surrogates({})

    def cross_validate(network, sur, **kwargs):
        assert sur is fitted and go.wait(30)
        return with_cv

    monkeypatch.setattr(pipeline, "cross_validate_surrogates", cross_validate)
    notes = []
    with ctx.held:
        ctx.surrogates(notes.append)  # returns while the cross-validation runs
        assert ctx.sur is fitted and not ctx.cv_pending.done()
        assert (ctx.out / "surrogates" / "surrogates.json").is_file()
        go.set()
        ctx.calibration(notes.append)
        assert ctx.sur is with_cv and ctx.cv_pending is None
        assert ctx.figures == {"cv m.y": ctx.out / "figures" / "cv_m.y.png"}
    assert any("cross-validation goes on beside the calibration" in n for n in notes)


def test_a_run_stopped_before_the_calibration_ends_starts_no_further_fold(context,
                                                                          monkeypatch):
    ctx, _ = context
    folds, started = [], threading.Event()

    def cross_validate(network, sur, *, before_fold, **kwargs):
        for _ in range(100):
            before_fold()
            folds.append(1)
            started.set()
            threading.Event().wait(0.05)
        return sur

    monkeypatch.setattr(pipeline, "cross_validate_surrogates", cross_validate)
    with pytest.raises(KeyboardInterrupt), ctx.held:
        ctx.surrogates(lambda text: None)
        assert started.wait(30)
        raise KeyboardInterrupt  # Ctrl-C in the calibration
    n = len(folds)
    assert ctx.cv_pending is None and 0 < n < 100  # drained on the way out
    threading.Event().wait(0.2)
    assert len(folds) == n


def test_a_rerun_stopped_early_leaves_no_earlier_report(tmp_path, monkeypatch):
    """A rerun into a finished run's folder that stops in its first stage leaves neither
    the earlier report nor its metrics to be read as its own, and says it did not finish."""
    from calnet.errors import CalnetError
    from calnet.files import INCOMPLETE

    for name in pipeline.PREVIOUS_RESULTS:
        (tmp_path / name).write_text("{}")
    (tmp_path / "keep.txt").write_text("a user's file")

    def stop(self, note):
        raise CalnetError("stopped")

    monkeypatch.setattr(pipeline._Context, "campaign", stop)
    with pytest.raises(CalnetError, match="stopped"):
        pipeline.run_pipeline(NINB, out=tmp_path, quick=True)
    assert not [n for n in pipeline.PREVIOUS_RESULTS if (tmp_path / n).exists()]
    assert (tmp_path / INCOMPLETE).is_file() and (tmp_path / "keep.txt").is_file()


@pytest.mark.parametrize(("n_ok", "said"), [
    (1, "M.y: 1 of the 3 runs of 'M' finished ok with a finite value, and a surrogate needs "
        "at least 3 (its inputs and parameters, 1, plus 2); fix the simulator and run the "
        "others again (calnet campaign SPEC --model M --retry-failed), or run more "
        "simulations: calnet campaign SPEC --model M --runs N (N > 3)"),
    (2, "M.y: 2 of the 3 runs of 'M' finished ok"),
    (3, "output 'M.y': 3-fold CV on 3 points leaves 2 training points, need d + 2 = 3; run "
        "more simulations (calnet campaign SPEC --model M --runs N)"),
])
def test_a_model_with_too_few_ok_runs_for_a_surrogate_says_which_and_what_to_run(
        tmp_path, n_ok, said):
    """``calnet run`` on a model whose design has too few runs that finished ok: one line
    naming the model and the command that runs more."""
    from typer.testing import CliRunner

    from calnet.cli import app

    module = f"few_ok_sims_{n_ok}"
    (tmp_path / f"{module}.py").write_text(
        "def f(inputs):\n    if inputs['x'] > 0.5:\n        raise ValueError('diverged')\n"
        "    return {'y': inputs['x']}\n")
    (tmp_path / "points.csv").write_text(
        "x\n" + "".join(f"{0.1 * (i + 1)}\n" for i in range(n_ok))
        + "".join(f"{0.9 - 0.1 * i}\n" for i in range(3 - n_ok)))
    (tmp_path / "network.yaml").write_text(
        f"models:\n  M:\n    simulator: python:{module}:f\n"
        "    inputs: {x: {lower: 0, upper: 1}}\n    outputs: {y: {}}\n"
        "    campaign: {design: points.csv}\nsettings: {seed: 0, predict: [M.y]}\n")
    result = CliRunner().invoke(app, ["run", str(tmp_path), "--out", str(tmp_path / "out")],
                                terminal_width=400)
    assert result.exit_code == 1, result.output
    errors = [line for line in result.output.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and errors[0].startswith(f"error: {said}"), result.output
