"""The HTML report is self-contained, escapes user text and shows every title and cell."""

import re

import numpy as np
import pytest

from calnet.report import Section, Table, fmt, write_report

PNG_1x1 = bytes.fromhex(
    "89504e470d0a1a0a0000000d49484452000000010000000108060000001f15c489"
    "0000000d49444154789c6360000002000154a24f5d0000000049454e44ae426082")


@pytest.fixture
def report(tmp_path):
    fig = tmp_path / "fig.png"
    fig.write_bytes(PNG_1x1)
    sections = [
        Section("Network <script>alert(1)</script>",
                paragraphs=["Two models & <b>one</b> link"],
                figures=[(fig, "network <i>diagram</i>")]),
        Section("Posterior",
                tables=[Table("Modes & means", ["parameter", "mode"],
                              [["K_S", 68.0412], ["sigma", 1.11e-7], ["<x>", np.float32(2.5)],
                               ["n", np.int64(11)], ["bad", float("nan")], ["none", None]])],
                figures=[(tmp_path / "missing.png", "absent")]),
    ]
    path = write_report(tmp_path / "out", title="calnet <report>", sections=sections,
                        subtitle="ninb", footer="v0")
    return path, path.read_text(encoding="utf-8")


def test_report_is_self_contained(report):
    path, html = report
    assert path.name == "report.html"
    assert not re.search(r"""(src|href)\s*=\s*["']?\s*(https?:)?//""", html, re.I)
    assert "http://" not in html and "https://" not in html
    imgs = re.findall(r"<img[^>]*>", html)
    assert len(imgs) == 1
    assert all('src="data:image/png;base64,' in tag for tag in imgs)
    assert "<link" not in html and "<script" not in html.lower()


def test_user_text_is_escaped(report):
    _, html = report
    assert "&lt;script&gt;alert(1)&lt;/script&gt;" in html
    assert "&lt;b&gt;one&lt;/b&gt;" in html and "Two models &amp;" in html
    assert "calnet &lt;report&gt;" in html and "network &lt;i&gt;diagram&lt;/i&gt;" in html


def test_titles_and_cells_present(report):
    _, html = report
    for text in ("Posterior", "Modes &amp; means", "K_S", "68.04", "1.11e-7", "&lt;x&gt;",
                 "2.5", ">11<", ">nan<", "Figure not available: missing.png"):
        assert text in html, text


@pytest.mark.parametrize("value, text", [
    (68.0412, "68.04"), (1361.47, "1361"), (0.34, "0.34"), (0.023, "0.023"),
    (1.11e-7, "1.11e-7"), (123456.0, "1.235e5"), (-5.7, "-5.7"), (0.0, "0"), (3, "3"),
    (np.int64(7), "7"), (np.float64(9107.01), "9107"), (True, "yes"), (np.bool_(False), "no"),
    (float("nan"), "nan"), (float("inf"), "\u221e"), (None, "\u2013"), ("text", "text")])
def test_fmt(value, text):
    assert fmt(value) == text


def test_sections_are_immutable():
    s = Section("a", paragraphs=["p"])
    with pytest.raises(AttributeError):
        s.title = "b"
    assert s.paragraphs == ("p",)


def test_campaign_statuses_read_as_counts():
    from calnet.report.build import _statuses

    assert _statuses({"failed": 5, "ok": 225, "timeout": 2}) == "225 ok, 5 failed, 2 timeout"
    assert _statuses({}) == ""


def test_map_axes_are_the_data_sets_inputs(tmp_path):
    """The (2-input) data and map figures are labelled with the network's own inputs, not
    with the case study's laser power and scan speed."""
    from calnet.report.build import _axis_labels
    from calnet.spec import load_spec

    (tmp_path / "network.yaml").write_text(
        "name: generic\nmodels:\n  A:\n    simulator: python:sims:f\n"
        "    inputs: {x1: {lower: 0, upper: 1}, T: {unit: K, lower: 300, upper: 400}}\n"
        "    outputs: {y: {measurable: true}}\n")
    network = load_spec(tmp_path, read_data=False)
    assert _axis_labels(network, ("A.x1", "A.T")) == ["x1", "T (K)"]
