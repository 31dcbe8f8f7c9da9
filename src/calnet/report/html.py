"""A self-contained HTML report: inline CSS, figures embedded as base64 PNG, no requests.

The report is a title, an optional :class:`Headline` (a box at the top: what a reader
needs in a minute) and a list of :class:`Section` objects, each holding paragraphs,
:class:`Table` objects and figures (PNG paths with captions). All text is HTML-escaped,
so user-provided names (model, parameter and data-set names) are shown verbatim and can
never inject markup. Numbers in tables are formatted by :func:`fmt`.

Examples
--------
>>> import tempfile
>>> sec = Section("Posterior", paragraphs=["Modes of M1."],
...               tables=[Table("Modes", ["parameter", "mode"], [["K_S", 68.04]])])
>>> write_report(tempfile.mkdtemp(), title="calnet", sections=[sec]).name
'report.html'
"""

from __future__ import annotations

import base64
import math
import numbers
from collections.abc import Sequence
from dataclasses import dataclass, field
from html import escape
from pathlib import Path
from typing import Any

import numpy as np

from calnet.files import replacing

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"

CSS = """
body { font-family: -apple-system, "Segoe UI", Helvetica, Arial, sans-serif; margin: 0;
       color: #1b1f24; background: #fafbfc; line-height: 1.5; }
main { max-width: 1080px; margin: 0 auto; padding: 1.5em 2em 4em; background: #fff; }
h1 { font-size: 1.7em; margin: 0.2em 0 0.1em; }
h2 { font-size: 1.3em; border-bottom: 2px solid #d0d7de; padding-bottom: 0.2em;
     margin-top: 2em; }
nav ol { columns: 2; font-size: 0.95em; }
nav a, nav a:visited { color: #0b57a4; text-decoration: none; }
.subtitle { color: #57606a; margin-top: 0; }
table { border-collapse: collapse; margin: 1em 0; font-size: 0.9em; }
caption { caption-side: top; text-align: left; font-weight: 600; padding-bottom: 0.3em; }
th, td { border: 1px solid #d0d7de; padding: 0.25em 0.6em; }
th { background: #f3f6fa; text-align: left; }
td.num { text-align: right; font-variant-numeric: tabular-nums; }
tbody tr:nth-child(even) { background: #f8f9fb; }
figure { margin: 1.2em 0; }
figure img { max-width: 100%; height: auto; border: 1px solid #eaeef2; }
figcaption { color: #57606a; font-size: 0.9em; }
.missing { color: #b42318; font-style: italic; }
.headline { border: 2px solid #0b57a4; border-radius: 6px; background: #f5f9fe;
            padding: 0.2em 1.2em 0.6em; margin: 1em 0 1.5em; line-height: 1.35; }
.headline h2 { margin: 0.4em 0 0.2em; border-bottom: none; }
.headline .tables { display: flex; flex-wrap: wrap; column-gap: 2em; align-items: flex-start; }
.headline table { margin: 0.4em 0; font-size: 0.85em; }
.headline p { margin: 0.4em 0; }
.headline ul { margin: 0.3em 0; padding-left: 1.5em; }
.headline li.warn { color: #8a4b00; }
.headline li.warn::marker { content: "\\26A0\\FE0E  "; }
.headline .ok { color: #1a7f37; }
footer { color: #8c959f; font-size: 0.8em; margin-top: 3em; }
"""


@dataclass(frozen=True)
class Table:
    """A table: caption, header cells and rows of cells (strings or numbers)."""

    caption: str
    header: Sequence[str]
    rows: Sequence[Sequence[Any]]

    def __post_init__(self) -> None:
        object.__setattr__(self, "header", tuple(self.header))
        object.__setattr__(self, "rows", tuple(tuple(r) for r in self.rows))


@dataclass(frozen=True)
class Section:
    """A report section.

    Attributes
    ----------
    title : str
        Section heading.
    paragraphs : sequence of str
        Plain-text paragraphs (escaped; no markup).
    tables : sequence of Table
        Tables, shown after the paragraphs.
    figures : sequence of (path, caption)
        PNG files to embed, with captions, shown after the tables.
    """

    title: str
    paragraphs: Sequence[str] = field(default_factory=tuple)
    tables: Sequence[Table] = field(default_factory=tuple)
    figures: Sequence[tuple[str | Path, str]] = field(default_factory=tuple)

    def __post_init__(self) -> None:
        object.__setattr__(self, "paragraphs", tuple(self.paragraphs))
        object.__setattr__(self, "tables", tuple(self.tables))
        object.__setattr__(self, "figures", tuple((Path(p), str(c)) for p, c in self.figures))


@dataclass(frozen=True)
class Headline:
    """The box at the top of the report.

    Attributes
    ----------
    tables : sequence of Table
        Shown side by side where the page is wide enough.
    lines : sequence of str
        Plain-text lines under the tables (e.g. the sampler's diagnostics).
    warnings : sequence of str
        The warnings that matter, one bullet each; none gives a line "No warnings".
    more : str, optional
        A closing line (e.g. where the rest of the warnings are).
    title : str
        The box's heading.
    """

    tables: Sequence[Table] = field(default_factory=tuple)
    lines: Sequence[str] = field(default_factory=tuple)
    warnings: Sequence[str] = field(default_factory=tuple)
    more: str | None = None
    title: str = "At a glance"

    def __post_init__(self) -> None:
        for name in ("tables", "lines", "warnings"):
            object.__setattr__(self, name, tuple(getattr(self, name)))


def fmt(x: Any, digits: int = 4) -> str:
    """Format a table cell: numbers to ``digits`` significant digits, others with ``str``.

    Plain decimals for magnitudes in [1e-3, 1e5), scientific notation outside; trailing
    zeros are dropped; ``None`` shows as an en dash and NaN as ``nan``.

    Examples
    --------
    >>> [fmt(v) for v in (68.0412, 1361.47, 0.34, 1.11e-7, 123456.0, 3, float("nan"))]
    ['68.04', '1361', '0.34', '1.11e-7', '1.235e5', '3', 'nan']
    """
    if x is None:
        return "\u2013"
    if isinstance(x, (bool, np.bool_)):
        return "yes" if x else "no"
    if isinstance(x, numbers.Integral):
        return str(int(x))
    if not isinstance(x, numbers.Real):
        return str(x)
    x = float(x)
    if math.isnan(x):
        return "nan"
    if math.isinf(x):
        return "\u221e" if x > 0 else "-\u221e"
    if x == 0.0:
        return "0"
    exponent = math.floor(math.log10(abs(x)))
    if -3 <= exponent < 5:
        text = f"{x:.{max(digits - 1 - exponent, 0)}f}"
        return text.rstrip("0").rstrip(".") if "." in text else text
    mantissa, exp = f"{x:.{digits - 1}e}".split("e")
    mantissa = mantissa.rstrip("0").rstrip(".") if "." in mantissa else mantissa
    return f"{mantissa}e{int(exp)}"


def _table_html(table: Table) -> str:
    head = "".join(f"<th>{escape(str(h))}</th>" for h in table.header)
    body = []
    for row in table.rows:
        cells = []
        for cell in row:
            is_num = isinstance(cell, numbers.Number) and not isinstance(cell, (bool, np.bool_))
            attr = ' class="num"' if is_num else ""
            cells.append(f"<td{attr}>{escape(fmt(cell))}</td>")
        body.append(f"<tr>{''.join(cells)}</tr>")
    return (f"<table>\n<caption>{escape(table.caption)}</caption>\n"
            f"<thead><tr>{head}</tr></thead>\n<tbody>\n" + "\n".join(body)
            + "\n</tbody>\n</table>")


def _figure_html(path: Path, caption: str) -> str:
    cap = escape(caption)
    try:
        data = path.read_bytes()
    except OSError:
        data = b""
    if not data.startswith(PNG_SIGNATURE):
        return (f'<figure><p class="missing">Figure not available: '
                f"{escape(path.name)}</p><figcaption>{cap}</figcaption></figure>")
    b64 = base64.b64encode(data).decode("ascii")
    return (f'<figure><img src="data:image/png;base64,{b64}" alt="{cap}">'
            f"<figcaption>{cap}</figcaption></figure>")


def _section_html(index: int, section: Section) -> str:
    parts = [f'<section id="s{index}">', f"<h2>{index}. {escape(section.title)}</h2>"]
    parts += [f"<p>{escape(p)}</p>" for p in section.paragraphs]
    parts += [_table_html(t) for t in section.tables]
    parts += [_figure_html(p, c) for p, c in section.figures]
    parts.append("</section>")
    return "\n".join(parts)


def _headline_html(box: Headline) -> str:
    parts = ['<section class="headline" id="headline">', f"<h2>{escape(box.title)}</h2>"]
    if box.tables:
        parts += ['<div class="tables">'] + [_table_html(t) for t in box.tables] + ["</div>"]
    parts += [f"<p>{escape(line)}</p>" for line in box.lines]
    if box.warnings:
        parts += ["<ul>"] + [f'<li class="warn">{escape(w)}</li>' for w in box.warnings]
        parts.append("</ul>")
    else:
        parts.append('<p class="ok">No warnings.</p>')
    if box.more:
        parts.append(f"<p>{escape(box.more)}</p>")
    parts.append("</section>")
    return "\n".join(parts)


def render_report(*, title: str, sections: Sequence[Section], subtitle: str | None = None,
                  footer: str | None = None, headline: Headline | None = None) -> str:
    """The report as one HTML string (see :func:`write_report`)."""
    toc = "\n".join(f'<li><a href="#s{i}">{escape(s.title)}</a></li>'
                    for i, s in enumerate(sections, start=1))
    body = "\n".join(_section_html(i, s) for i, s in enumerate(sections, start=1))
    sub = f'<p class="subtitle">{escape(subtitle)}</p>' if subtitle else ""
    foot = f"<footer>{escape(footer)}</footer>" if footer else ""
    head = _headline_html(headline) if headline is not None else ""
    return (f'<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
            f'<meta name="viewport" content="width=device-width, initial-scale=1">\n'
            f"<title>{escape(title)}</title>\n<style>{CSS}</style>\n</head>\n<body>\n<main>\n"
            f"<h1>{escape(title)}</h1>\n{sub}\n{head}\n<nav><ol>\n{toc}\n</ol></nav>\n{body}\n{foot}\n"
            f"</main>\n</body>\n</html>\n")


def write_report(out_dir: str | Path, *, title: str, sections: Sequence[Section],
                 subtitle: str | None = None, footer: str | None = None,
                 headline: Headline | None = None) -> Path:
    """Write ``out_dir/report.html``, a single self-contained file.

    Parameters
    ----------
    out_dir : str or Path
        Output folder (created if needed).
    title : str
        Report title.
    sections : list of Section
        The sections, in order; a numbered table of contents links to them.
    subtitle, footer : str, optional
        A line under the title (e.g. the network and data) and a footer (e.g. versions).
    headline : Headline, optional
        A box between the title and the table of contents.

    Returns
    -------
    Path
        The written ``report.html``. Figures whose files are missing or not PNG appear as
        a visible "Figure not available" note instead of failing the report.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "report.html"
    text = render_report(title=title, sections=sections, subtitle=subtitle, footer=footer,
                         headline=headline)
    with replacing(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return path
