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
