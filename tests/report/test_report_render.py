"""The report as a browser shows it: headless Chromium loads a report with real figures
and a headline; every image decodes, the console stays silent, the headline box is on
the first screen. Skipped where Chromium is not installed."""

import shutil
from pathlib import Path

import numpy as np
import pytest
from report_inputs import BOUND, results

from calnet.report import Section, Table, write_report
from calnet.report import figures as F
from calnet.report.headline import headline
from calnet.report.html import PNG_SIGNATURE
from calnet.report.screenshot import CHROMIUM, check_page

pytestmark = pytest.mark.skipif(
    not Path(CHROMIUM).exists() and shutil.which("chromium") is None,
    reason=f"Chromium not installed ({CHROMIUM}); `apt-get install -y chromium` runs the "
           "report render checks")


def _check(path, **kw):
    exe = CHROMIUM if Path(CHROMIUM).exists() else shutil.which("chromium")
    result = check_page(path, chromium=exe, **kw)
    assert result is not None, "Chromium is installed but did not load the page (stderr)"
    return result


@pytest.fixture(scope="module")
def small_report(tmp_path_factory):
    """A report with the figures of a three-model run (diagram, settings, posteriors)."""
    tmp = tmp_path_factory.mktemp("render")
    rng = np.random.default_rng(0)
    models = [dict(name="thermal", inputs=["P", "v"], outputs=["W", "G"], measurable=["W"]),
              dict(name="micro", inputs=["G", "S"], outputs=["lam"], measurable=True),
              dict(name="hardness", inputs=["lam"], outputs=["H"], measurable=True)]
    links = [("thermal", "micro", "G->G"), ("micro", "hardness", "lam->lam")]
    P, v = rng.uniform(80, 250, 20), rng.uniform(0.2, 2.0, 20)
    panels = [dict(name=n, unit="1", lower=0.0, upper=1.0, prior_pdf_x=np.linspace(0, 1, 9),
                   prior_pdf_y=np.ones(9), posterior_samples=rng.beta(2, 5, 500), mode=0.2)
              for n in ("a", "b")]
    figs = [(F.network_diagram(models, links, tmp / "net.png"), "The model network."),
            (F.data_grid(None, None, {"width": (P, v, P > 200)}, tmp / "data.png"),
             "Experimental settings."),
            (F.prior_posterior_grid(panels, tmp / "post.png"), "Prior vs posterior.")]
    box = headline(results([BOUND]), units={"width": "um"}, warnings_section=2)
    sections = [Section("Network and data", tables=[Table("t", ["a"], [[1.5]])], figures=figs),
                Section("Warnings", paragraphs=[BOUND])]
    return write_report(tmp / "out", title="calnet report: render", sections=sections,
                        headline=box)


@pytest.mark.slow
def test_report_renders_cleanly_with_the_headline_first(small_report):
    page = _check(small_report, ids=["headline", "s1"])
    assert page.images == 3
    assert page.broken_images == ()
    assert page.console == ()
    assert page.tops["headline"] is not None and page.tops["headline"] < 300
    assert page.tops["headline"] < page.tops["s1"]


@pytest.mark.slow
def test_check_page_sees_broken_images_console_errors_and_missing_ids(tmp_path):
    """The check can fail: a PNG cut after its signature does not decode, a script's
    console.error and an uncaught exception are reported, an absent id has no top."""
    broken = tmp_path / "cut.png"
    broken.write_bytes(PNG_SIGNATURE + b"\0" * 64)
    path = write_report(tmp_path, title="t", sections=[Section("s",
                                                               figures=[(broken, "cut")])])
    page = _check(path, ids=["headline"])
    assert page.images == 1 and page.broken_images == ("cut",)
    assert page.tops == {"headline": None} and not page.ok
    noisy = tmp_path / "noisy.html"
    noisy.write_text("<!DOCTYPE html><html><head></head><body><p>x</p><script>"
                     "console.error('boom'); undefinedFunction();</script></body></html>")
    page = _check(noisy)
    assert "error: boom" in page.console
    assert any("undefinedFunction" in c for c in page.console)
