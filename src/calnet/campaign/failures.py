"""How many of a campaign's runs did not finish ``ok``, and where they lie.

``calnet campaign`` and ``calnet run`` warn, at their end, about a model whose share of
runs not ``ok`` is above :data:`FAILED_SHARE_LIMIT`: its surrogate is trained on the
rest only, so a region where the simulator fails is a region the surrogate does not
know. The warning says how many, of which status, and which input or parameter ranges
separate them from the ``ok`` runs: one range of each column that holds them all apart,
or, for failures with more than one cause, up to three one-sided ranges beyond every ok
run that together hold most of them.

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

from calnet.errors import alike

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
    return _where(model, done, bad, columns) + _memory_hint(bad)


def _memory_hint(bad: list) -> str:
    """What to do about the runs of ``bad`` that ran out of memory ("" when none did):
    they are worth running again, unlike a region where the simulator fails."""
    n = sum("MemoryError" in (r.get("message") or "") for r in bad)
    if not n:
        return ""
    return (f"; {n} of them ran out of memory (MemoryError: a leak, or too many --workers, "
            "rather than their inputs): free memory, then run them again with --retry-failed")


def _where(model: str, done: list, bad: list, columns: Sequence[str]) -> str:
    """:func:`failure_note`'s line without its hint on memory."""
    counts = ", ".join(f"{k} {n}" for k, n in sorted(Counter(r["status"] for r in bad).items()))
    share = f"{100 * len(bad) / len(done):.0f} %"
    text = f"{model}: {len(bad)} of {len(done)} runs ({share}) did not finish ok ({counts})"

    ok = [r for r in done if r["status"] == "ok"]
    if not ok:
        return text
    where = _separating(bad, ok, columns)
    if where:
        return (text + "; they lie at " + ", ".join(w[0] for w in where) + ", the ok runs at "
                + ", ".join(w[1] for w in where) + " (the surrogate extrapolates there)")
    regions, others = _regions(bad, ok, columns)
    if not regions:
        return text + "; no input or parameter range separates them from the ok runs"
    parts = [f"{c} {'>' if up else '<'} {edge:.3g} ({len(idx)} run{'s' if len(idx) > 1 else ''})"
             for c, up, edge, idx in regions]
    text += ("; they lie where " + " or ".join(parts) + ", beyond every ok run (the surrogate "
             "extrapolates there)")
    if others:
        text += f"; the other {others} lie{'s' if others == 1 else ''} among the ok runs"
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
    each as ``"N runs: status: message"``, commonest first (:func:`calnet.errors.alike`)."""
    bad = _not_ok(_rows(store))
    texts = [f"{r['status']}: {m}" for r, m in zip(bad, _messages(bad), strict=True)]
    return [f"{n} run{'s' if n > 1 else ''}: {text}" for text, n in alike(texts)[:most]]


def commonest_failure(store: str | Path) -> str | None:
    """:func:`commonest_outcome` of the runs in ``store``."""
    return commonest_outcome(_rows(store))


def commonest_outcome(rows: Iterable[Mapping[str, Any]]) -> str | None:
    """The commonest outcome of the runs that did not finish ok, with the commonest
    message among them (:func:`calnet.errors.alike`): ``"nonconverged (11 runs), e.g. Newton did not
    converge: ..."``; None where every run is ok."""
    bad = _not_ok(rows)
    if not bad:
        return None
    status, n = Counter(r["status"] for r in bad).most_common(1)[0]
    example = alike(_messages([r for r in bad if r["status"] == status]))[0][0]
    return f"{status} ({n} run{'s' if n > 1 else ''}), e.g. {example}"


def _rows(store: str | Path) -> list[dict[str, Any]]:
    from calnet.campaign.store import RunStore

    with RunStore(Path(store), readonly=True) as db:
        return db.rows()


def _not_ok(rows: Iterable[Mapping[str, Any]]) -> list[Mapping[str, Any]]:
    return [r for r in rows if r["status"] not in ("ok", "pending", None)]


def _messages(rows: Iterable[Mapping[str, Any]]) -> list[str]:
    """The runs' messages without the place of their logs (each run names its own)."""
    from calnet.campaign.logs import without_where

    return [without_where(r.get("message") or "no message") for r in rows]


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


def _regions(bad: list, ok: list, columns: Sequence[str], most: int = 3,
             least: int = 2) -> tuple[list[tuple[str, bool, float, set[int]]], int]:
    """Failures with more than one cause: up to ``most`` one-sided ranges, each beyond
    every ok run of one column (``x`` above the largest or below the smallest ok
    value), chosen greedily to hold the most runs not ok, each at least ``least`` of
    them; kept only when together they hold at least half of them. Returns
    ``[(column, above, the ok runs' edge, indices of the runs it holds)]`` and how many
    runs not ok they leave out."""
    candidates = []
    for c in columns:
        g = [r["inputs"][c] for r in ok if c in r["inputs"]]
        if not g:
            continue
        for up, edge in ((True, max(g)), (False, min(g))):
            held = {i for i, r in enumerate(bad) if c in r["inputs"]
                    and (r["inputs"][c] > edge if up else r["inputs"][c] < edge)}
            if held:
                candidates.append((c, up, edge, held))
    chosen: list[tuple[str, bool, float, set[int]]] = []
    left = set(range(len(bad)))
    while candidates and len(chosen) < most:
        best = max(candidates, key=lambda t: len(t[3] & left))
        if len(best[3] & left) < least:
            break
        chosen.append((best[0], best[1], best[2], best[3] & left))
        left -= best[3]
    if 2 * (len(bad) - len(left)) < len(bad):
        return [], len(bad)
    return chosen, len(left)


def _span(values: list[float]) -> str:
    lo, hi = min(values), max(values)
    return f"= {lo:.3g}" if lo == hi else f"in [{lo:.3g}, {hi:.3g}]"
