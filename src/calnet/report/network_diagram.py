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

BOX_W, COL_GAP, ROW_GAP, LINE_H = 3.4, 2.2, 0.6, 0.32
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


def _box_lines(model: Mapping[str, Any]) -> list[tuple[str, str, bool]]:
    """(text, colour, bold) lines of a model's box."""
    measurable = model.get("measurable") or ()
    outputs = list(model.get("outputs") or ())
    measured = set(outputs) if measurable is True else set(measurable or ())
    lines = [(str(model["name"]), "k", True)]
    inputs = ", ".join(str(i) for i in model.get("inputs") or ()) or "-"
    lines += [(t, "0.25", False) for t in textwrap.wrap(f"in: {inputs}", 34)]
    for out in outputs:
        if out in measured:
            lines.append((f"out: {out}  [measured]", MEASURED_COLOR, True))
        else:
            lines.append((f"out: {out}", "0.25", False))
    return lines


def _layout(models: Sequence[Mapping[str, Any]], links: Sequence[Sequence[Any]],
            lines: Mapping[str, list[tuple[str, str, bool]]],
            ) -> tuple[dict[str, tuple[float, float, float]], float, float]:
    """Box positions ``{name: (x_left, y_bottom, height)}``, total width and height."""
    names = [str(m["name"]) for m in models]
    depth = topological_depth(names, links)
    columns: dict[int, list[str]] = {}
    for n in names:
        columns.setdefault(depth[n], []).append(n)
    heights = {n: LINE_H * len(lines[n]) + 0.3 for n in names}
    col_h = {c: sum(heights[n] for n in ns) + ROW_GAP * (len(ns) - 1)
             for c, ns in columns.items()}
    total_h = max(col_h.values(), default=1.0)
    boxes: dict[str, tuple[float, float, float]] = {}
    for c, ns in columns.items():
        y = (total_h + col_h[c]) / 2  # centre each column vertically
        for n in ns:
            y -= heights[n]
            boxes[n] = (c * (BOX_W + COL_GAP), y, heights[n])
            y -= ROW_GAP
    n_cols = max(columns, default=0) + 1
    return boxes, n_cols * BOX_W + (n_cols - 1) * COL_GAP, total_h


def _arrows(boxes: Mapping[str, tuple[float, float, float]],
            links: Sequence[Sequence[Any]]) -> list[tuple[Any, ...]]:
    """``(start, end, rad, label_xy, label)`` per linked pair (labels merged).

    Links between adjacent columns run straight from the right edge of the source to the
    left edge of the target; links that skip columns arc over the boxes, top to top.
    """
    merged: dict[tuple[str, str], list[str]] = {}
    for src, dst, *label in links:
        merged.setdefault((src, dst), []).extend(str(x) for x in label if x)
    out = []
    for (src, dst), labels in merged.items():
        (xs, ys, hs), (xd, yd, hd) = boxes[src], boxes[dst]
        if xd - xs > BOX_W + COL_GAP + 1e-9:
            start, end, rad = (xs + 0.75 * BOX_W, ys + hs), (xd + 0.25 * BOX_W, yd + hd), -0.3
        else:
            start, end, rad = (xs + BOX_W, ys + hs / 2), (xd, yd + hd / 2), 0.0
        dx, dy = end[0] - start[0], end[1] - start[1]
        # midpoint of matplotlib's arc3 quadratic Bezier: chord midpoint + rad/2 * (dy, -dx)
        mid = ((start[0] + end[0]) / 2 + rad * dy / 2, (start[1] + end[1]) / 2 - rad * dx / 2)
        out.append((start, end, rad, mid, "\n".join(textwrap.wrap(", ".join(labels), 18))))
    return out


def network_diagram(models: Sequence[Mapping[str, Any]], links: Sequence[Sequence[Any]],
                    path: str | Path, *, title: str | None = None) -> Path:
    """Draw a model network as layered boxes and labelled arrows.

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
    arrows = _arrows(boxes, links)
    top = max([total_h] + [lab[1] + 0.3 for *_, lab, _ in arrows])
    fig = Figure(figsize=(max(3.0, 0.9 * width + 0.6), max(1.6, 0.9 * top + 0.8)))
    ax = fig.add_axes((0.02, 0.02, 0.96, 0.88 if title else 0.96))
    ax.set_xlim(-0.2, width + 0.2)
    ax.set_ylim(-0.2, top + 0.2)
    ax.set_aspect("equal")  # arc3 curvature is isotropic, so labels sit on the arcs
    ax.set_axis_off()
    for n, (x0, y0, h) in boxes.items():
        edge = MEASURED_COLOR if any(c == MEASURED_COLOR for _, c, _ in lines[n]) else "0.2"
        ax.add_patch(FancyBboxPatch((x0, y0), BOX_W, h, fc="#f3f6fa", ec=edge, lw=1.6,
                                    boxstyle="round,pad=0.02,rounding_size=0.15"))
        for i, (text, color, bold) in enumerate(lines[n]):
            ax.text(x0 + 0.15, y0 + h - 0.15 - (i + 0.5) * LINE_H, text, color=color,
                    fontsize=9 if i == 0 else 8, fontweight="bold" if bold else "normal",
                    va="center", ha="left")
    for start, end, rad, label_xy, text in arrows:
        ax.annotate("", xy=end, xytext=start,
                    arrowprops=dict(arrowstyle="-|>", color="0.2", lw=1.4, shrinkA=2,
                                    shrinkB=2, mutation_scale=14,
                                    connectionstyle=f"arc3,rad={rad}"))
        if text:
            ax.text(*label_xy, text, fontsize=8, ha="center", va="center",
                    bbox=dict(boxstyle="round,pad=0.2", fc="white", ec="0.7", lw=0.6))
    if title:
        fig.suptitle(title)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110, format="png")
    return path
