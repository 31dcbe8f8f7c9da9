"""Drawing of a model network (a DAG) with matplotlib only: boxes in layers, arrows.

Models are placed in columns by topological depth (a model's depth is one more than the
deepest model feeding it) and stacked within a column. Measured outputs are highlighted
in each box, and boxes of models with measured outputs get a coloured edge.
"""

from __future__ import annotations

import textwrap
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from calnet.errors import SpecError

# sizes in inches (the drawing's data units), fonts in points; at the report's 110 dpi a
# figure up to MAX_WIDTH wide is shown unscaled, so 10 pt text reads as 10 pt text
TITLE_PT, LINE_PT, LABEL_PT = 11.0, 10.0, 9.0
PAD, ROW_GAP, MIN_GAP, MARGIN = 0.14, 0.35, 0.8, 0.12
LINE_SPACING = 1.5
MAX_WIDTH = 9.2
MEASURED_COLOR = "#d62728"


def topological_depth(names: Sequence[str], links: Sequence[Sequence[Any]]) -> dict[str, int]:
    """Depth of each model: 0 for sources, else 1 + the largest depth among its feeders.

    Parameters
    ----------
    names : list of str
        Model names.
    links : list of (src, dst, label)
        Directed couplings between models.

    Returns
    -------
    dict
        ``{name: depth}``.

    Raises
    ------
    SpecError
        A link names an unknown model, or the links contain a cycle.
    """
    parents: dict[str, set[str]] = {n: set() for n in names}
    for src, dst, *_ in links:
        for end in (src, dst):
            if end not in parents:
                raise SpecError(f"link {src!r} -> {dst!r} names unknown model {end!r}; "
                                f"models are {list(names)}")
        parents[dst].add(src)
    depth: dict[str, int] = {}
    while len(depth) < len(names):
        ready = [n for n in names if n not in depth and parents[n] <= depth.keys()]
        if not ready:
            left = sorted(set(names) - depth.keys())
            raise SpecError(f"model links form a cycle among {left}; a network must be a DAG")
        for n in ready:
            depth[n] = 1 + max((depth[p] for p in parents[n]), default=-1)
    return depth


def _text_size(text: str, size: float, bold: bool = False) -> tuple[float, float]:
    """Width and height of one line of ``text`` in inches at ``size`` points."""
    from matplotlib.font_manager import FontProperties
    from matplotlib.textpath import TextPath

    prop = FontProperties(weight="bold" if bold else "normal")
    ext = TextPath((0, 0), text, size=size, prop=prop).get_extents()
    return 1.05 * ext.width / 72, size / 72


def _box_lines(model: Mapping[str, Any]) -> list[tuple[str, str, bool]]:
    """(text, colour, bold) lines of a model's box."""
    measurable = model.get("measurable") or ()
    outputs = list(model.get("outputs") or ())
    measured = set(outputs) if measurable is True else set(measurable or ())
    lines = [(str(model["name"]), "k", True)]
    inputs = ", ".join(str(i) for i in model.get("inputs") or ()) or "-"
    lines += [(t, "0.25", False) for t in textwrap.wrap(f"in: {inputs}", 30)]
    for out in outputs:
        if out in measured:
            lines.append((f"out: {out}  [measured]", MEASURED_COLOR, True))
        else:
            lines.append((f"out: {out}", "0.25", False))
    return lines


def _line_height(index: int) -> float:
    return LINE_SPACING * (TITLE_PT if index == 0 else LINE_PT) / 72


def _box_size(lines: Sequence[tuple[str, str, bool]]) -> tuple[float, float]:
    """Width and height (inches) of a box that holds ``lines`` with a margin of PAD."""
    widths = [_text_size(t, TITLE_PT if i == 0 else LINE_PT, bold)[0]
              for i, (t, _, bold) in enumerate(lines)]
    return (max(widths) + 2 * PAD,
            sum(_line_height(i) for i in range(len(lines))) + 2 * PAD)


def _merged_labels(links: Sequence[Sequence[Any]]) -> dict[tuple[str, str], str]:
    """One wrapped label per linked pair of models: ``{(src, dst): "G->G, v->S"}``."""
    merged: dict[tuple[str, str], list[str]] = {}
    for src, dst, *label in links:
        merged.setdefault((str(src), str(dst)), []).extend(str(x) for x in label if x)
    return {k: "\n".join(textwrap.wrap(", ".join(v), 18)) for k, v in merged.items()}


def _label_size(text: str) -> tuple[float, float]:
    """Width and height (inches) of an arrow label with its rounded frame."""
    if not text:
        return 0.0, 0.0
    rows = text.split("\n")
    width = max(_text_size(r, LABEL_PT)[0] for r in rows)
    return width + 0.16, len(rows) * 1.25 * LABEL_PT / 72 + 0.12


def _layout(models: Sequence[Mapping[str, Any]], links: Sequence[Sequence[Any]],
            lines: Mapping[str, list[tuple[str, str, bool]]],
            ) -> tuple[dict[str, tuple[float, float, float, float]], float, float]:
    """Box positions ``{name: (x_left, y_bottom, width, height)}`` in inches, and the total
    width and height.

    Each column is as wide as its widest box; the gap after a column is wide enough for
    the labels of the arrows that cross it.
    """
    names = [str(m["name"]) for m in models]
    depth = topological_depth(names, links)
    columns: dict[int, list[str]] = {}
    for n in names:
        columns.setdefault(depth[n], []).append(n)
    size = {n: _box_size(lines[n]) for n in names}
    n_cols = max(columns, default=0) + 1
    col_w = [max((size[n][0] for n in columns.get(c, ())), default=0.0) for c in range(n_cols)]
    gaps = [MIN_GAP] * max(n_cols - 1, 0)
    for (src, dst), text in _merged_labels(links).items():
        if depth[dst] == depth[src] + 1:
            gaps[depth[src]] = max(gaps[depth[src]], _label_size(text)[0] + 0.5)
    col_x = [sum(col_w[:c]) + sum(gaps[:c]) for c in range(n_cols)]
    col_h = {c: sum(size[n][1] for n in ns) + ROW_GAP * (len(ns) - 1)
             for c, ns in columns.items()}
    total_h = max(col_h.values(), default=1.0)
    boxes: dict[str, tuple[float, float, float, float]] = {}
    for c, ns in columns.items():
        y = (total_h + col_h[c]) / 2  # centre each column vertically
        for n in ns:
            w, h = size[n]
            y -= h
            boxes[n] = (col_x[c] + (col_w[c] - w) / 2, y, w, h)
            y -= ROW_GAP
    return boxes, sum(col_w) + sum(gaps), total_h


def _arrows(boxes: Mapping[str, tuple[float, float, float, float]],
            links: Sequence[Sequence[Any]], depth: Mapping[str, int]) -> list[tuple[Any, ...]]:
    """``(start, end, rad, label_xy, label)`` per linked pair (labels merged).

    Links between adjacent columns run straight from the right edge of the source to the
    left edge of the target; links that skip columns arc over the boxes, top to top.
    """
    out = []
    for (src, dst), label in _merged_labels(links).items():
        (xs, ys, ws, hs), (xd, yd, wd, hd) = boxes[src], boxes[dst]
        if depth[dst] > depth[src] + 1:
            start, end, rad = (xs + 0.75 * ws, ys + hs), (xd + 0.25 * wd, yd + hd), -0.3
        else:
            start, end, rad = (xs + ws, ys + hs / 2), (xd, yd + hd / 2), 0.0
        dx, dy = end[0] - start[0], end[1] - start[1]
        # midpoint of matplotlib's arc3 quadratic Bezier: chord midpoint + rad/2 * (dy, -dx)
        mid = ((start[0] + end[0]) / 2 + rad * dy / 2, (start[1] + end[1]) / 2 - rad * dx / 2)
        out.append((start, end, rad, mid, label))
    return out


def network_diagram(models: Sequence[Mapping[str, Any]], links: Sequence[Sequence[Any]],
                    path: str | Path, *, title: str | None = None) -> Path:
    """Draw a model network as layered boxes and labelled arrows.

    Boxes are sized to their text; the figure is drawn at one inch per data unit, so its
    fonts (10 pt in boxes, 9 pt on arrows) keep their size in the report for networks up
    to ``MAX_WIDTH`` inches wide (about four models in a chain).

    Parameters
    ----------
    models : list of dict
        Each ``{"name": str, "inputs": list of str, "outputs": list of str,
        "measurable": list of output names (or True for all)}``.
    links : list of (src, dst, label)
        Couplings: ``src`` feeds ``dst``; ``label`` names the coupled quantities.
        Several links between the same pair are merged into one arrow.
    path : str or Path
        Destination PNG.
    title : str, optional
        Figure title.

    Returns
    -------
    Path
    """
    from matplotlib.figure import Figure
    from matplotlib.patches import FancyBboxPatch

    lines = {str(m["name"]): _box_lines(m) for m in models}
    boxes, width, total_h = _layout(models, links, lines)
    arrows = _arrows(boxes, links, topological_depth(list(lines), links))
    top = max([total_h] + [xy[1] + _label_size(lab)[1] / 2 for *_, xy, lab in arrows])
    title_h = 0.4 if title else 0.0
    fig_w, fig_h = width + 2 * MARGIN, top + 2 * MARGIN
    fig = Figure(figsize=(fig_w, fig_h + title_h))
    ax = fig.add_axes((0.0, 0.0, 1.0, fig_h / (fig_h + title_h)))
    ax.set_xlim(-MARGIN, width + MARGIN)
    ax.set_ylim(-MARGIN, top + MARGIN)
    ax.set_axis_off()
    for n, (x0, y0, w, h) in boxes.items():
        edge = MEASURED_COLOR if any(c == MEASURED_COLOR for _, c, _ in lines[n]) else "0.2"
        ax.add_patch(FancyBboxPatch((x0, y0), w, h, fc="#f3f6fa", ec=edge, lw=1.6,
                                    boxstyle="round,pad=0,rounding_size=0.1", gid=f"box {n}"))
        y = y0 + h - PAD
        for i, (text, color, bold) in enumerate(lines[n]):
            y -= _line_height(i)
            ax.text(x0 + PAD, y + _line_height(i) / 2, text, color=color,
                    fontsize=TITLE_PT if i == 0 else LINE_PT,
                    fontweight="bold" if bold else "normal", va="center", ha="left",
                    gid=f"box {n}")
    for start, end, rad, label_xy, text in arrows:
        ax.annotate("", xy=end, xytext=start,
                    arrowprops=dict(arrowstyle="-|>", color="0.2", lw=1.4, shrinkA=2,
                                    shrinkB=2, mutation_scale=14,
                                    connectionstyle=f"arc3,rad={rad}"))
        if text:
            ax.text(*label_xy, text, fontsize=LABEL_PT, ha="center", va="center",
                    linespacing=1.25, gid="link label",
                    bbox=dict(boxstyle="round,pad=0.2", fc="white", ec="0.7", lw=0.6))
    if title:
        fig.suptitle(title, fontsize=TITLE_PT + 1)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110, format="png")
    return path
