"""The network: models joined by links into a directed acyclic graph.

Validation of cross-references (links, data sets) happens here, when the network is
built, so that every later stage can rely on a consistent graph.
"""

from __future__ import annotations

import graphlib
from functools import cached_property
from pathlib import Path
from typing import Any

from pydantic import Field, field_validator, model_validator

from calnet.errors import UnknownName
from calnet.spec.models import Dataset, Link, Model, Settings, named_mapping_to_list
from calnet.spec.variables import Frozen, Input, Output


class Network(Frozen):
    """A declared network of coupled models.

    Parameters
    ----------
    name : str
        Short name used in reports.
    models : tuple of Model
        The nodes (a YAML mapping ``{name: {...}}`` is accepted too).
    links : tuple of Link
        Edges ``model.output -> model.input`` (or identity ``model.input -> model.input``).
    data : tuple of Dataset
        Experimental data sets, each observing one measurable output.
    settings : Settings
        Seeds, campaign sizes, sampler settings (documented defaults).
    root : str
        Folder that relative paths (data files, stores) are resolved against.

    Examples
    --------
    >>> from calnet.spec import Network, Model, Input, Output, SimulatorRef
    >>> m = Model(name="a", simulator=SimulatorRef(kind="python", target="mod:f"),
    ...           inputs=[Input(name="x", lower=0, upper=1)], outputs=[Output(name="y")])
    >>> Network(name="tiny", models=[m]).order
    ('a',)
    """

    name: str = "network"
    description: str = ""
    models: tuple[Model, ...] = Field(min_length=1)
    links: tuple[Link, ...] = ()
    data: tuple[Dataset, ...] = ()
    settings: Settings = Field(default_factory=Settings)
    root: str = "."
    source: str = ""

    @field_validator("models", "data", mode="before")
    @classmethod
    def _named_mapping(cls, value: Any) -> Any:
        return named_mapping_to_list(value)

    @model_validator(mode="after")
    def _consistent(self) -> Network:
        """Every problem of the network as a whole, one line each (a ValueError whose
        lines the loader lists as separate problems): the checks that need a sound graph
        (data sets, predicted outputs) run once the links and the order are sound."""
        _unique([m.name for m in self.models], "model")
        _unique([d.name for d in self.data], "data set")
        problems: list[str] = []

        def collect(check, *args) -> bool:
            try:
                check(*args)
            except ValueError as err:
                problems.append(str(err))
                return False
            return True

        graph = all([collect(self._check_link, i, link) for i, link in enumerate(self.links)])
        graph = graph and collect(lambda: self.order)  # raises on a cycle
        collect(self._check_parameters)
        for name in self.settings.criteria:
            if name not in {d.name for d in self.data}:
                problems.append(f"settings.criteria: no data set named '{name}'; known: "
                                f"{[d.name for d in self.data]}")
        for i, ds in enumerate(self.data):
            collect(self._check_dataset, i, ds, graph)
        if graph:
            for i, key in enumerate(self.settings.predict):
                collect(self._check_predicted, i, key)
        if problems:
            raise ValueError("\n".join(problems))
        return self

    def _check_predicted(self, i: int, key: str) -> None:
        where = f"settings.predict[{i}]"
        name, var = key.split(".")
        model = self._model_or_error(name, where)
        if var not in model.output_names:
            raise ValueError(f"{where}: model '{name}' has no output '{var}'; known outputs: "
                             f"{list(model.output_names)}")

    def _check_link(self, i: int, link: Link) -> None:
        where = f"links[{i}]"
        src_model = self._model_or_error(link.source_model, f"{where}.from")
        dst_model = self._model_or_error(link.target_model, f"{where}.to")
        try:
            src = src_model.variable(link.source_var)
        except KeyError:
            raise ValueError(
                f"{where}.from: model '{src_model.name}' has no output or input "
                f"'{link.source_var}'; known: {_names(src_model.outputs + src_model.inputs)}"
            ) from None
        if src.__class__.__name__ == "Parameter":
            raise ValueError(f"{where}.from: '{link.source}' is a calibration parameter; "
                             "link from an output or a control input")
        if link.target_var not in dst_model.input_names:
            raise ValueError(
                f"{where}.to: model '{dst_model.name}' has no control input "
                f"'{link.target_var}'; known inputs: {list(dst_model.input_names)}"
            )
        if link.source_model == link.target_model:
            raise ValueError(f"{where}: links a model to itself ('{link.source}' -> "
                             f"'{link.target}'), which is a cycle; remove it")
        dst = dst_model.variable(link.target_var)
        if norm_unit(src.unit) != norm_unit(dst.unit):
            raise ValueError(
                f"{where}: unit mismatch, '{link.source}' is in '{src.unit}' but "
                f"'{link.target}' expects '{dst.unit}'; declare both in the same unit"
            )
        others = [j for j, ln in enumerate(self.links) if ln.target == link.target]
        if len(others) > 1:
            if i != others[0]:
                return  # said once, with the first of them
            raise ValueError(f"{where}.to: '{link.target}' is fed by {len(others)} links ("
                             + ", ".join(f"links[{j}]" for j in others)
                             + "); an input can be fed by one link only")
        twins = [ln.target for ln in self.links if ln.source == link.source
                 and ln.target_model == link.target_model and ln.target != link.target]
        if twins:
            raise ValueError(
                f"{where}: '{link.source}' feeds both '{link.target}' and '{twins[0]}' of "
                f"model '{link.target_model}', so the two inputs are always equal; declare "
                "one input and let the simulator use it twice")

    def _check_parameters(self) -> None:
        """A parameter name in several models must be shared, with one declaration."""
        seen: dict[str, list[tuple[str, object]]] = {}
        for m in self.models:
            for p in m.parameters:
                seen.setdefault(p.name, []).append((m.name, p))
        for name, decls in seen.items():
            if len(decls) < 2:
                continue
            models = [m for m, _ in decls]
            if not all(p.shared for _, p in decls):
                raise ValueError(
                    f"models: parameter '{name}' is declared in {models} as separate "
                    "parameters; to calibrate one parameter for all of them add 'shared: "
                    "true' to each declaration, or rename one of them")
            first = decls[0][1].model_dump(exclude={"description"})
            for model, p in decls[1:]:
                other = p.model_dump(exclude={"description"})
                diff = [k for k in first if first[k] != other[k]]
                if diff:
                    raise ValueError(
                        f"models.{model}.parameters.{name}: shared parameter '{name}' has "
                        f"{', '.join(f'{k}={other[k]!r}' for k in diff)} here but "
                        f"{', '.join(f'{k}={first[k]!r}' for k in diff)} in "
                        f"'{models[0]}'; declare it the same way in every model")

    def param_key(self, model: str, name: str) -> str:
        """Key of a calibration parameter: ``model.name``, or ``name`` when shared."""
        return name if self.model(model).variable(name).shared else f"{model}.{name}"

    def _check_dataset(self, i: int, ds: Dataset, graph: bool = True) -> None:
        """What ``ds`` observes; with a sound ``graph``, also its columns (the process
        inputs come from the links)."""
        where = f"data.{ds.name}"
        model = self._model_or_error(ds.observed_model, f"{where}.observes")
        try:
            out = model.output(ds.observed_output)
        except KeyError:
            raise ValueError(f"{where}.observes: model '{model.name}' has no output "
                             f"'{ds.observed_output}'; known: {list(model.output_names)}"
                             ) from None
        if not out.measurable:
            raise ValueError(f"{where}.observes: output '{ds.observes}' is not measurable; "
                             "set 'measurable: true' on it or observe another output")
        if not graph:
            return
        wanted = self.process_input_keys(model.name) + [ds.observes]
        if ds.columns is None:  # each read from the column of its own name
            bare = [w.split(".")[1] for w in wanted]
            twice = sorted({w for w, b in zip(wanted, bare, strict=True) if bare.count(b) > 1})
            if twice:
                raise ValueError(f"{where}: {twice} share a name, so each cannot be read from "
                                 "the column of its own name; add 'columns: {model.variable: "
                                 "<csv column>, ...}'")
            return
        resolved = {self.resolve_column_key(ds, key, wanted) for key in ds.columns}
        missing = [w for w in wanted if w not in resolved]
        if missing:
            raise ValueError(f"{where}.columns: no column given for {missing}; add "
                             "'<variable>: <csv column>' entries for them")

    def dataset_columns(self, ds: Dataset) -> dict[str, str]:
        """``{model.variable: CSV column}`` of ``ds``: each process input of the observed
        model and the observed output, from ``columns`` or, without it, by bare name."""
        wanted = self.process_input_keys(ds.observed_model) + [ds.observes]
        if ds.columns is None:
            return {w: w.split(".")[1] for w in wanted}
        return {self.resolve_column_key(ds, k, wanted): col for k, col in ds.columns.items()}

    def resolve_column_key(self, ds: Dataset, key: str, wanted: list[str]) -> str:
        """Resolve a ``columns`` key (bare or qualified) to ``model.variable``."""
        if key in wanted:
            return key
        matches = [w for w in wanted if w.split(".")[1] == key]
        if len(matches) == 1:
            return matches[0]
        if len(matches) > 1:
            raise ValueError(f"data.{ds.name}.columns: '{key}' is ambiguous ({matches}); "
                             "write it as model.variable")
        raise ValueError(f"data.{ds.name}.columns: '{key}' is not a free input of "
                         f"'{ds.observed_model}' or its ancestors nor the observed output; "
                         f"expected some of {wanted}")

    def _model_or_error(self, name: str, where: str) -> Model:
        try:
            return self.model(name)
        except KeyError:
            raise ValueError(f"{where}: no model named '{name}'; known models: "
                             f"{[m.name for m in self.models]}") from None

    # ------------------------------------------------------------ graph queries
    def model(self, name: str) -> Model:
        """The model called ``name`` (:class:`~calnet.errors.UnknownName`, a KeyError, if
        absent)."""
        for m in self.models:
            if m.name == name:
                return m
        raise UnknownName(f"no model named '{name}'; the network's models: "
                          f"{[m.name for m in self.models]}")

    @cached_property
    def order(self) -> tuple[str, ...]:
        """Model names in topological order (parents first, ties in declaration order)."""
        sorter = graphlib.TopologicalSorter({m.name: set() for m in self.models})
        for link in self.links:
            sorter.add(link.target_model, link.source_model)
        try:
            ready = []
            sorter.prepare()
            rank = {m.name: i for i, m in enumerate(self.models)}
            while sorter.is_active():
                batch = sorted(sorter.get_ready(), key=rank.__getitem__)
                ready.extend(batch)
                sorter.done(*batch)
        except graphlib.CycleError as err:
            cycle = " -> ".join(err.args[1])
            raise ValueError(f"links: the network has a cycle ({cycle}); a network must be "
                             "acyclic, remove one of these links") from None
        return tuple(ready)

    def parents(self, name: str) -> tuple[str, ...]:
        return tuple(dict.fromkeys(ln.source_model for ln in self.links
                                   if ln.target_model == name))

    def children(self, name: str) -> tuple[str, ...]:
        return tuple(dict.fromkeys(ln.target_model for ln in self.links
                                   if ln.source_model == name))

    def ancestors(self, name: str) -> tuple[str, ...]:
        """All upstream models of ``name``, in topological order."""
        found: set[str] = set()
        stack = list(self.parents(name))
        while stack:
            p = stack.pop()
            if p not in found:
                found.add(p)
                stack.extend(self.parents(p))
        return tuple(m for m in self.order if m in found)

    def link_into(self, model: str, input_name: str) -> Link | None:
        """The link feeding ``model.input_name``, or None for a free input."""
        for link in self.links:
            if link.target_model == model and link.target_var == input_name:
                return link
        return None

    def free_inputs(self, model: str) -> tuple[Input, ...]:
        """Inputs of ``model`` not fed by a link (set by the experimenter)."""
        return tuple(v for v in self.model(model).inputs if self.link_into(model, v.name) is None)

    def process_inputs(self, model: str) -> tuple[tuple[str, str], ...]:
        """``(model, input)`` pairs of every free input that ``model``'s prediction needs:
        its own free inputs and its ancestors', in topological order."""
        pairs = []
        for name in (*self.ancestors(model), model):
            pairs.extend((name, v.name) for v in self.free_inputs(name))
        return tuple(pairs)

    def process_input_keys(self, model: str) -> list[str]:
        """:meth:`process_inputs` as ``"model.input"`` keys."""
        return [f"{m}.{v}" for m, v in self.process_inputs(model)]

    def output_uses(self, model: str) -> dict[str, tuple[str, ...]]:
        """What each output of ``model`` is for: some of ``"observed"`` (by a data set),
        ``"linked"`` (feeds a downstream input) and ``"predicted"`` (listed in
        ``settings.predict``), in that order; an empty tuple for an unused output."""
        observed = {d.observed_output for d in self.data if d.observed_model == model}
        linked = {ln.source_var for ln in self.links if ln.source_model == model}
        predicted = {k.split(".")[1] for k in self.settings.predict
                     if k.split(".")[0] == model}
        return {o.name: tuple(use for use, names in (("observed", observed), ("linked", linked),
                                                      ("predicted", predicted))
                              if o.name in names)
                for o in self.model(model).outputs}

    def needed_outputs(self, model: str) -> tuple[Output, ...]:
        """Outputs of ``model`` that need a surrogate: observed by data, feeding a link or
        requested by ``settings.predict``."""
        uses = self.output_uses(model)
        return tuple(o for o in self.model(model).outputs if uses[o.name])

    def datasets_for(self, model: str) -> tuple[Dataset, ...]:
        return tuple(d for d in self.data if d.observed_model == model)

    def dataset(self, name: str) -> Dataset:
        """The data set called ``name`` (:class:`~calnet.errors.UnknownName`, a KeyError,
        if absent)."""
        for d in self.data:
            if d.name == name:
                return d
        hint = (f" ('{name}' names a model's output: calnet.emulation.predict_output "
                "predicts one)" if "." in str(name) else "")
        raise UnknownName(f"no data set named '{name}'; the network's data sets: "
                          f"{[d.name for d in self.data]}{hint}")

    def observed(self, ds: Dataset) -> Output:
        """The output that data set ``ds`` observes."""
        return self.model(ds.observed_model).output(ds.observed_output)

    def term_text(self, ds: Dataset, noise: Any = None, discrepancy: Any = None) -> str:
        """``ds``'s noise and discrepancy in words, as they enter its likelihood; ``noise``
        and ``discrepancy`` (``NoiseSettings``, ``DiscrepancySettings``) stand in for the
        data set's own where given."""
        out = self.observed(ds)
        return (f"{(noise or ds.noise).text(out.unit, out.transform == 'log')}; "
                f"{(discrepancy or ds.discrepancy).text()}")

    def path(self, relative: str | Path) -> Path:
        """Resolve ``relative`` against the spec's folder."""
        p = Path(relative)
        return p if p.is_absolute() else Path(self.root) / p


def _unique(names: list[str], what: str) -> None:
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ValueError(f"duplicate {what} name(s) {dup}; every {what} needs its own name")


def _names(items: tuple) -> list[str]:
    return [v.name for v in items]


def norm_unit(unit: str) -> str:
    return "".join(unit.split()).replace("**", "^") if unit else "1"
