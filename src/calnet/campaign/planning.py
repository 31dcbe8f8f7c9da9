"""Which design a campaign plans, how large, and the points it adds to a store.

``campaign.design`` picks the design (docs/campaigns.md): ``lhs``, ``sobol``, ``halton``,
``chain`` or a file of points. Unset, a store keeps the design that made it, and a new
store gets ``chain`` when the model has linked inputs, ``lhs`` otherwise. Points already
planned are never moved: a larger design adds points (greedy maximin, or the design
file's next rows), so a resumed campaign repeats nothing.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calnet.campaign.chain_design import chain_points
from calnet.campaign.design import (
    Design,
    augment,
    design_columns,
    latin_hypercube,
    log_columns,
    model_box,
    qmc_design,
    to_unit,
)
from calnet.campaign.importing import read_points
from calnet.campaign.store import RunStore, input_hash
from calnet.errors import CampaignError, SpecError
from calnet.spec.models import DESIGN_KINDS, CampaignSettings, Model
from calnet.spec.network import Network

DESCRIPTIONS = {
    "lhs": "scipy.stats.qmc.LatinHypercube(optimization='random-cd')",
    "sobol": "scipy.stats.qmc.Sobol(scramble=True), first runs points",
    "halton": "scipy.stats.qmc.Halton(scramble=True)",
    "chain": "linked inputs where the parents' GP means land (10 % margin, greedy maximin), "
             "other inputs and parameters by LatinHypercube",
}


@dataclass(frozen=True)
class DesignChoice:
    """The design of one model's campaign.

    Attributes
    ----------
    kind : {"lhs", "sobol", "halton", "chain", "file"}
    explicit : bool
        Set in the spec (else chosen: the store's, or the default).
    path : Path, optional
        A design file.
    points : ndarray, shape (n_points, n_inputs + n_parameters), optional
        The design file's points, declared units.
    label : str
        What the store records: the kind, or ``file:<name>``.
    """

    kind: str
    explicit: bool
    path: Path | None = None
    points: np.ndarray | None = None
    label: str = ""


def settings_of(network: Network, model: Model) -> CampaignSettings:
    """The campaign settings that apply to ``model`` (its own, else the network's)."""
    return model.campaign or network.settings.campaign


def has_links(network: Network, model: Model) -> bool:
    """Whether any input of ``model`` is fed by a link."""
    return any(network.link_into(model.name, v.name) is not None for v in model.inputs)


def stored_design(meta: dict[str, str]) -> str | None:
    """The design label a store records (``lhs`` for a store from before designs had a
    choice); None for a store that plans no design yet."""
    if meta.get("design_kind"):
        return meta["design_kind"]
    return "lhs" if meta.get("design", "").startswith("scipy.stats.qmc.LatinHypercube") else None


def choose_design(network: Network, model: Model, meta: dict[str, str],
                  asked: DesignChoice | None = None) -> DesignChoice:
    """The design the spec asks for (``asked``, from :func:`spec_design`), or, unset, the
    store's (``meta``) or the default."""
    if asked is not None:
        return asked
    stored = stored_design(meta)
    kind = stored or ("chain" if has_links(network, model) else "lhs")
    return DesignChoice("file" if kind.startswith("file:") else kind, False, label=kind)


#: The part of a store's design description that marks a chain design made without runs
#: of the parents (a Latin hypercube instead).
NOT_CHAIN = "not a chain design: the parents had no runs"


def fallback_note(network: Network, model: Model, choice: DesignChoice,
                  meta: dict[str, str], path: Path) -> str | None:
    """A note when ``model``'s store continues a Latin hypercube that stood in for a chain
    design (its parents had no runs when it was planned) and the spec names no design:
    the points do not follow the parents' runs."""
    if choice.explicit or choice.label != "lhs" or NOT_CHAIN not in meta.get("design", ""):
        return None
    return (f"the store '{path}' of '{model.name}' holds a Latin hypercube, not a chain "
            "design: its parents had no runs when it was planned, so its points do not "
            "follow theirs; simulate it again with --fresh for a chain design, or set "
            f"models.{model.name}.campaign.design: lhs to keep it without this note")


def spec_design(network: Network, model: Model) -> DesignChoice | None:
    """The design the spec sets for ``model`` (a design file read and validated), or None
    when it sets none."""
    settings = settings_of(network, model)
    _only_per_model(network)
    if settings.design is None:
        return None
    if settings.design in DESIGN_KINDS:
        return DesignChoice(settings.design, True, label=settings.design)
    path = network.path(settings.design)
    if not path.is_file():
        raise SpecError(f"no design file '{path}'; give a .csv or .parquet file of points "
                        "(a path relative to the spec) or one of "
                        f"{', '.join(DESIGN_KINDS)}", file=network.source or None,
                        field=f"models.{model.name}.campaign.design")
    points = read_points(path, model, strict=network.settings.strict)
    return DesignChoice("file", True, path, points, f"file:{path.name}")


def design_conflict(choice: DesignChoice, meta: dict[str, str], path: Path) -> str | None:
    """Why a store cannot continue with ``choice`` (None: it can)."""
    stored = stored_design(meta)
    if not choice.explicit or stored is None or stored == choice.label:
        return None
    return (f"the store '{path}' holds a '{stored}' design, but the spec asks for "
            f"'{choice.label}'; set campaign.design: {stored.removeprefix('file:')} to "
            "continue it, or simulate again with --fresh (or a new --store)")


def target_runs(runs: int | None, network: Network, model: Model, choice: DesignChoice,
                planned: int, imported: int) -> int:
    """Size of the design: ``--runs``; else a design file's rows; else ``campaign.runs``,
    where an import without ``runs`` in the spec simulates nothing more. Never fewer than
    the store plans: its design is kept whole (:func:`fewer_note` says so)."""
    if runs is not None:
        return max(runs, planned)
    if choice.points is not None:
        return max(len(choice.points), planned)
    settings = settings_of(network, model)
    if "runs" not in settings.model_fields_set and (settings.import_ or imported):
        return planned
    return max(settings.runs, planned)


def fewer_note(runs: int | None, network: Network, model: Model, choice: DesignChoice,
               planned: int) -> str | None:
    """The line saying that ``--runs`` (``runs``) or the spec's ``campaign.runs`` asks for
    fewer runs than the store plans, all of which are kept; None when it does not."""
    if runs is not None:
        asked, where = runs, "--runs"
    else:
        settings = settings_of(network, model)
        if choice.points is not None or "runs" not in settings.model_fields_set:
            return None
        asked = settings.runs
        where = (f"models.{model.name}.campaign.runs" if model.campaign is not None
                 else "settings.campaign.runs")
    if asked >= planned:
        return None
    return (f"{where} asks for {asked} runs, the store plans {planned}: all {planned} are "
            "kept (a design shrinks only in a new store: --fresh, which deletes these runs, "
            "or a new --store)")


def plan(db: RunStore, network: Network, model: Model, choice: DesignChoice, runs: int,
         seed: int) -> int:
    """Plan the points of a ``runs``-point design that the store lacks; return the design's
    size. Stored points stay as they are, bit for bit."""
    rows = db.design_rows()
    new = (_file_rows(choice, design_columns(model), rows, db.path)
           if choice.points is not None else [])
    have = len(rows) + len(new)
    groups = [(new, choice.label)]  # a design file's new rows, then generated points
    if runs > have:
        groups.append(_generated(db, network, model, choice, rows, new, runs, seed))
    for points, source in groups:
        start = db.next_index()
        db.plan(((start + k, row) for k, row in enumerate(points)), seed=seed, source=source)
    new = [row for points, _ in groups for row in points]
    meta = db.meta()
    if not meta.get("design_kind") and (rows or new):
        label = stored_design(meta) or choice.label
        description = DESCRIPTIONS.get(label, f"points of {label[5:]}")
        if label == "chain" and not rows and groups[-1][1] == "lhs":
            # the parents had no runs: the points are a Latin hypercube, and say so
            label = "lhs"
            description = f"{DESCRIPTIONS['lhs']} ({NOT_CHAIN})"
        db.set_meta({"design_kind": label, "design": description})
    return max(runs, have)


def _file_rows(choice: DesignChoice, columns: tuple[str, ...], rows: list[dict],
               path: Path) -> list[dict[str, float]]:
    """The design file's rows after those the store plans from it, which must be its first
    rows (the store may also hold points that ``--runs`` added; those stay)."""
    points = [{c: float(v) for c, v in zip(columns, p, strict=True)} for p in choice.points]
    rows = [r for r in rows if r.get("source") in (None, choice.label)]
    for k, row in enumerate(rows[:len(points)]):
        if input_hash(row["inputs"]) != input_hash(points[k]):
            raise CampaignError(f"the design file '{choice.path}' changed: row {k + 1} is not "
                                f"the point of the store '{path}' (run {row['idx']}); restore "
                                "the file (new points go at its end), or simulate again "
                                "with --fresh (or a new --store)")
    return points[len(rows):]


def _generated(db: RunStore, network: Network, model: Model, choice: DesignChoice,
               rows: list[dict], new: list[dict], runs: int,
               seed: int) -> tuple[list[dict], str]:
    """``runs - len(rows) - len(new)`` points of the design ``choice`` that fill the gaps
    the stored (and the file's) points leave, and how they were placed (the runs'
    ``source``): the design's label, ``lhs`` where a chain design fell back to a Latin
    hypercube, ``maximin`` for points added to a design."""
    columns, log = design_columns(model), log_columns(model)
    lower, upper = model_box(model)
    have = [[r["inputs"][c] for c in columns] for r in rows] + [[p[c] for c in columns]
                                                                 for p in new]
    old = Design(columns, lower, upper,
                 to_unit(np.array(have, dtype=float).reshape(len(have), len(columns)),
                         lower, upper, log), log)
    extra = runs - len(have)
    source = choice.label
    if choice.kind == "chain":
        design, aware = chain_points(network, model, old, extra, seed=seed, store=db.path)
        source = "chain" if aware else ("lhs" if len(have) == 0 else "maximin")
    elif len(have) == 0 and choice.kind == "lhs":
        design = latin_hypercube(model, runs, seed=seed)
    elif len(have) == 0 and choice.kind in ("sobol", "halton"):
        design = qmc_design(model, runs, kind=choice.kind, seed=seed)
    else:
        design, source = augment(old, extra, seed=seed, model_name=model.name), "maximin"
    return [design.row(i) for i in range(len(have), len(design))], source


def _only_per_model(network: Network) -> None:
    """A design file and an import belong to one model, not to ``settings.campaign``."""
    settings = network.settings.campaign
    for key, value in (("design", settings.design), ("import", settings.import_)):
        if value is not None and (key == "import" or value not in DESIGN_KINDS):
            raise SpecError(f"'{value}' holds one model's points or runs; move it under "
                            f"models.<name>.campaign.{key}", file=network.source or None,
                            field=f"settings.campaign.{key}")
