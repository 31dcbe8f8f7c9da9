"""How many of a campaign's runs did not finish ``ok``, and where they lie.

``calnet campaign`` and ``calnet run`` warn, at their end, about a model whose share of
runs not ``ok`` is above :data:`FAILED_SHARE_LIMIT`: its surrogate is trained on the
rest only, so a region where the simulator fails is a region the surrogate does not
know. The warning says how many, of which status, and which input or parameter ranges
separate them from the ``ok`` runs.

Examples
--------
>>> rows = [{"status": "ok", "inputs": {"x": 0.1 * i}} for i in range(5)]
>>> rows += [{"status": "failed", "inputs": {"x": 0.6 + 0.1 * i}} for i in range(3)]
>>> for part in failure_note("M1", rows, ["x"]).split("; "):
...     print(part)
M1: 3 of 8 runs (38 %) did not finish ok (failed 3)
they lie at x in [0.6, 0.8], the ok runs at x in [0, 0.4] (the surrogate extrapolates there)
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from calnet.spec.models import Model

FAILED_SHARE_LIMIT = 0.10
"""A model's campaign with a larger share of finished runs not ``ok`` is warned about."""


def failure_note(model: str, rows: Iterable[Mapping[str, Any]], columns: Sequence[str], *,
                 limit: float = FAILED_SHARE_LIMIT) -> str | None:
    """One line on the runs of ``model`` that did not finish ``ok``, when their share of
    the finished runs is above ``limit``; None otherwise.

    Parameters
    ----------
    model : str
    rows : iterable of mappings
        The store's runs, each with ``status`` (None while unfinished) and ``inputs``
        (name -> value), as :meth:`calnet.campaign.store.RunStore.rows` gives them.
    columns : sequence of str
        The design's columns (inputs, then parameters) to look for a separating range.
    limit : float
        Share (0 to 1) of the finished runs above which a line is written.
    """
    done = [r for r in rows if r["status"] is not None]
    bad = [r for r in done if r["status"] != "ok"]
    if not done or len(bad) <= limit * len(done):
        return None
    counts = ", ".join(f"{k} {n}" for k, n in sorted(Counter(r["status"] for r in bad).items()))
    share = f"{100 * len(bad) / len(done):.0f} %"
    text = f"{model}: {len(bad)} of {len(done)} runs ({share}) did not finish ok ({counts})"

    ok = [r for r in done if r["status"] == "ok"]
    where = _separating(bad, ok, columns) if ok else []
    if where:
        text += ("; they lie at " + ", ".join(w[0] for w in where) + ", the ok runs at "
                 + ", ".join(w[1] for w in where) + " (the surrogate extrapolates there)")
    elif ok:
        text += "; no single input or parameter range separates them from the ok runs"
    return text


def store_failure_note(store: str | Path, model: Model, *,
                       limit: float = FAILED_SHARE_LIMIT) -> str | None:
    """:func:`failure_note` of the runs of ``model`` in the store ``store`` (read only),
    over the model's inputs and parameters."""
    from calnet.campaign.design import design_columns
    from calnet.campaign.store import RunStore

    with RunStore(Path(store), readonly=True) as db:
        rows = db.rows()
    return failure_note(model.name, rows, design_columns(model), limit=limit)


def common_failures(store: str | Path, most: int = 2) -> list[str]:
    """The ``most`` commonest messages of the runs in ``store`` that did not finish ok,
    each as ``"N runs: status: message"``, commonest first."""
    from collections import Counter

    from calnet.campaign.store import RunStore

    with RunStore(Path(store), readonly=True) as db:
        rows = db.rows()
    counts = Counter(f"{r['status']}: {r.get('message') or 'no message'}" for r in rows
                     if r["status"] not in ("ok", "pending", None))
    return [f"{n} run{'s' if n > 1 else ''}: {text}" for text, n in counts.most_common(most)]


def _separating(bad: list, ok: list, columns: Sequence[str]) -> list[tuple[str, str]]:
    """``(range of the bad runs, range of the ok runs)`` for each column whose two
    ranges do not overlap."""
    out = []
    for c in columns:
        b = [r["inputs"][c] for r in bad if c in r["inputs"]]
        g = [r["inputs"][c] for r in ok if c in r["inputs"]]
        if b and g and (min(b) > max(g) or max(b) < min(g)):
            out.append((f"{c} {_span(b)}", f"{c} {_span(g)}"))
    return out


def _span(values: list[float]) -> str:
    lo, hi = min(values), max(values)
    return f"= {lo:.3g}" if lo == hi else f"in [{lo:.3g}, {hi:.3g}]"
