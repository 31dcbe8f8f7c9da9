"""The variants of ``settings.compare`` start compiling once the spec's sampler is compiled,
run beside the later stages until the validation collects them, and are not run after a
failed calibration of the spec's model."""

from __future__ import annotations

import threading
from pathlib import Path
from types import SimpleNamespace

import pytest

import calnet.calibration.calibrate_network as calibrate_network
import calnet.pipeline as pipeline
import calnet.validation as validation
from calnet.errors import CalibrationError, CalibrationWarning
from calnet.spec import load_spec

#: what the stubbed calibration returns: a posterior with no set-up notes
POSTERIOR = SimpleNamespace(info=())

NINB = Path(__file__).resolve().parents[1] / "examples" / "ninb"


@pytest.fixture
def context(tmp_path):
    network = load_spec(NINB)
    assert network.settings.compare  # the case study compares no_discrepancy
    ctx = pipeline._Context(network, tmp_path, quick=True, fresh=False, loo_max=0)
    ctx.sur = None
    return ctx


def test_variants_wait_for_the_spec_sampler_to_compile(context, monkeypatch):
    events = []
    variants_done = threading.Event()

    def spec(network, sur, *, compiled, **kwargs):
        events.append("spec compiling")
        assert not variants_done.wait(0.5)  # nothing of the variants runs meanwhile
        compiled()
        assert variants_done.wait(30)  # and they run beside the spec's chains
        events.append("spec sampled")
        return POSTERIOR

    def variants(network, sur, train, names, **kwargs):
        events.append("variants")
        variants_done.set()
        return {name: ("net", "post") for name in names}

    monkeypatch.setattr(calibrate_network, "calibrate", spec)
    monkeypatch.setattr(validation, "calibrate_variants", variants)
    monkeypatch.setattr(pipeline, "record_calibration", lambda *a, **k: "recorded")
    with context.held:
        context.calibration(lambda text: None)
        assert set(context.collect_variants()) == set(context.network.settings.compare)
    assert events == ["spec compiling", "variants", "spec sampled"]


def test_the_variants_run_beside_the_stages_after_the_calibration(context, monkeypatch):
    """The calibration stage ends without waiting for the variants; the validation
    stage's collect_variants does."""
    go = threading.Event()

    def spec(network, sur, *, compiled, **kwargs):
        compiled()
        return POSTERIOR

    def variants(network, sur, train, names, **kwargs):
        assert go.wait(30)
        return {name: ("net", "post") for name in names}

    monkeypatch.setattr(calibrate_network, "calibrate", spec)
    monkeypatch.setattr(validation, "calibrate_variants", variants)
    monkeypatch.setattr(pipeline, "record_calibration", lambda *a, **k: "recorded")
    with context.held:
        context.calibration(lambda text: None)  # returns while the variants still run
        assert context.variants == {} and not context.pending.done()
        go.set()
        assert set(context.collect_variants()) == set(context.network.settings.compare)


def test_a_failed_spec_calibration_does_not_run_the_variants(context, monkeypatch):
    ran = []

    def spec(network, sur, **kwargs):
        raise CalibrationError("the log-density is not finite at the initial points")

    monkeypatch.setattr(calibrate_network, "calibrate", spec)
    monkeypatch.setattr(validation, "calibrate_variants", lambda *a, **k: ran.append(1))
    with pytest.raises(CalibrationError, match="not finite"), context.held:
        context.calibration(lambda text: None)
    context.pending.result(timeout=30)
    assert ran == []


def test_a_run_stopped_early_says_it_waits_for_the_variants_in_flight(context, monkeypatch):
    """Ctrl-C after the calibration stage: the variants' chains cannot be interrupted, so
    the run says that it waits for them, and does, before it ends."""
    started, finished = threading.Event(), threading.Event()

    def spec(network, sur, *, compiled, **kwargs):
        compiled()
        return POSTERIOR

    def variants(network, sur, train, names, **kwargs):
        started.set()
        threading.Event().wait(0.5)  # chains in flight
        finished.set()
        return {}

    monkeypatch.setattr(calibrate_network, "calibrate", spec)
    monkeypatch.setattr(validation, "calibrate_variants", variants)
    monkeypatch.setattr(pipeline, "record_calibration", lambda *a, **k: "recorded")
    notes, hit = [], threading.Event()

    def note(text):  # run_pipeline's: raises once Ctrl-C has arrived
        if hit.is_set():
            raise KeyboardInterrupt
        notes.append(text)

    context.say = notes.append  # and the lines that do not check
    with pytest.raises(KeyboardInterrupt), context.held:
        context.calibration(note)
        assert started.wait(30)
        hit.set()
        raise KeyboardInterrupt
    assert finished.is_set()
    assert any("stopping once the calibration of no_discrepancy in flight ends" in n
               for n in notes), notes


def test_a_ctrl_c_that_python_drops_still_stops_the_run(python_sigint):
    """A KeyboardInterrupt raised inside a garbage-collection callback is dropped by
    Python; the latch keeps it, and the run's next step raises it."""
    import os
    import signal
    import time

    from calnet.interrupts import latch

    with latch() as interrupted:
        interrupted()  # nothing yet
        try:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(1)
        except KeyboardInterrupt:
            pass  # dropped, as Python drops it in a gc callback
        with pytest.raises(KeyboardInterrupt):
            interrupted()
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_a_variant_that_changes_nothing_is_not_calibrated(context, monkeypatch):
    # the case study's discrepancy is the reference study's, not orthogonal already
    settings = context.network.settings.model_copy(
        update={"compare": ("non_orthogonal", "no_discrepancy")})
    context.network = context.network.model_copy(update={"settings": settings})
    asked = []

    def spec(network, sur, *, compiled, **kwargs):
        compiled()
        return POSTERIOR

    def variants(network, sur, train, names, **kwargs):
        asked.extend(names)
        return {name: ("net", "post") for name in names}

    monkeypatch.setattr(calibrate_network, "calibrate", spec)
    monkeypatch.setattr(validation, "calibrate_variants", variants)
    monkeypatch.setattr(pipeline, "record_calibration", lambda *a, **k: "recorded")
    with pytest.warns(CalibrationWarning, match="settings.compare: non_orthogonal changes "
                      "nothing in this spec"), context.held:
        context.calibration(lambda text: None)
        assert set(context.collect_variants()) == {"no_discrepancy"}
    assert asked == ["no_discrepancy"]


def test_the_campaign_stage_passes_on_the_campaigns_notes(tmp_path):
    """What `calnet campaign` prints as notes (here: where the simulator's output went)
    reaches the end of `calnet run` as a warning."""
    import sys
    import warnings

    import yaml

    sys.path.insert(0, str(Path(__file__).parent / "campaign"))
    try:
        from campaign_helpers import toy_spec
    finally:
        sys.path.pop(0)
    spec = toy_spec(tmp_path, "python:toy_sims:chatty", runs=3, timeout=30.0)
    doc = yaml.safe_load(spec.read_text())
    doc["models"]["toy"]["outputs"]["y"] = {"measurable": True}
    doc["data"] = {"d": {"path": "d.csv", "observes": "toy.y"}}
    spec.write_text(yaml.safe_dump(doc, sort_keys=False))
    (tmp_path / "d.csv").write_text("x,y\n0.2,0.5\n0.6,0.9\n")
    (tmp_path / "toy_sims.py").write_text(
        (Path(__file__).parent / "campaign" / "toy_sims.py").read_text())
    sys.path.insert(0, str(tmp_path))
    try:
        ctx = pipeline._Context(load_spec(spec), tmp_path / "out", quick=True, fresh=False,
                                loo_max=0)
        with warnings.catch_warnings(record=True) as seen:
            warnings.simplefilter("always")
            ctx.campaign(lambda text: None)
    finally:
        sys.path.remove(str(tmp_path))
    said = [str(w.message) for w in seen]
    assert any(m.startswith("toy: what the simulator printed is in ") for m in said), said


def test_variants_of_a_spec_without_a_discrepancy_change_nothing():
    """Without a discrepancy, non_orthogonal is the spec's model too (it was run and
    compared under its name, a copy of no_discrepancy); reference still adds one."""
    from calnet.spec.models import DiscrepancySettings

    network = load_spec(NINB)
    off = DiscrepancySettings(enabled=False)
    none = network.model_copy(update={"data": tuple(
        ds.model_copy(update={"discrepancy": off}) for ds in network.data)})
    assert validation.same_as_spec(none, VARIANTS) == ("no_discrepancy", "non_orthogonal")
    default = network.model_copy(update={"data": tuple(
        ds.model_copy(update={"discrepancy": DiscrepancySettings()}) for ds in network.data)})
    assert validation.same_as_spec(default, VARIANTS) == ()


VARIANTS = ("no_discrepancy", "non_orthogonal", "reference")
