"""Reading a network spec from YAML, with one-line errors that name file, field and fix."""

from __future__ import annotations

import types
import typing
import warnings
from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel, ValidationError

from calnet.errors import CalnetError, SpecError, SpecWarning
from calnet.simulators.registry import builtin_info, builtin_names
from calnet.spec.data import read_all
from calnet.spec.network import Network, norm_unit

SPEC_FILENAME = "network.yaml"


def resolve_spec_path(spec: str | Path) -> Path:
    """Return the YAML file of ``spec``: the file itself or ``<folder>/network.yaml``."""
    path = Path(spec)
    if path.is_dir():
        path = path / SPEC_FILENAME
        if not path.is_file():
            raise SpecError(f"folder has no {SPEC_FILENAME}; pass the YAML file itself or add "
                            f"{SPEC_FILENAME}", file=str(path.parent))
    elif not path.is_file():
        raise SpecError("no such file or folder; pass a YAML file or a folder holding "
                        f"{SPEC_FILENAME}", file=str(path))
    return path


def load_spec(spec: str | Path, *, read_data: bool = True) -> Network:
    """Load and validate a network spec.

    Parameters
    ----------
    spec : str or Path
        A YAML file, or a folder holding ``network.yaml``.
    read_data : bool
        Also read every data set and check its columns, values and bounds.

    Returns
    -------
    Network
        The frozen, validated network; relative paths resolve against the YAML's folder.

    Raises
    ------
    SpecError
        With a one-line message naming the file, the field and the fix.
    """
    path = resolve_spec_path(spec)
    raw = _read_yaml(path)
    network = parse_spec(raw, root=path.parent, source=str(path))
    check_simulators(network)
    check_priors(network)
    check_sampler(network)
    check_log_links(network)
    if read_data:
        read_all(network)
    return network


def parse_spec(raw: Any, *, root: str | Path = ".", source: str = "<spec>") -> Network:
    """Build a :class:`Network` from already-parsed YAML (a mapping)."""
    if not isinstance(raw, dict):
        raise SpecError(f"the spec must be a YAML mapping with 'models', got "
                        f"{type(raw).__name__}", file=source)
    for key in ("root", "source"):
        if key in raw:
            raise SpecError(f"unknown key '{key}'", file=source, field=key)
    try:
        return Network.model_validate({**raw, "root": str(root), "source": source})
    except ValidationError as err:
        raise _to_spec_error(err, raw, source) from None


class _UniqueKeyLoader(yaml.SafeLoader):
    """A safe YAML loader that rejects duplicate mapping keys (PyYAML keeps the last)."""


def _construct_mapping(loader: _UniqueKeyLoader, node: yaml.MappingNode, deep: bool = False):
    seen: dict[Any, int] = {}
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=deep)
        if key in seen:
            raise yaml.constructor.ConstructorError(
                None, None, f"duplicate key '{key}' (first on line {seen[key]}); "
                "names must be unique, rename or remove one", key_node.start_mark)
        seen[key] = key_node.start_mark.line + 1
    return loader.construct_mapping(node, deep=deep)


_UniqueKeyLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG,
                                 _construct_mapping)


def _read_yaml(path: Path) -> Any:
    try:
        with open(path, encoding="utf-8") as fh:
            return yaml.load(fh, Loader=_UniqueKeyLoader)  # noqa: S506 (safe loader subclass)
    except UnicodeDecodeError as err:
        text = path.read_bytes()
        line = text[:err.start].count(b"\n") + 1
        raise SpecError(f"not UTF-8 text (byte 0x{text[err.start]:02x} at line {line}); save "
                        "the file as UTF-8", file=str(path)) from None
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        line = f"line {mark.line + 1}" if mark else None
        problem = getattr(err, "problem", None) or str(err)
        raise SpecError(f"invalid YAML: {problem}", file=str(path), field=line) from None


MAX_PROBLEMS = 20  # spec problems listed, one line each


def _to_spec_error(err: ValidationError, raw: Any, source: str) -> SpecError:
    """A SpecError for the first problem of ``err``, with the others (up to
    :data:`MAX_PROBLEMS`) as ``more``. A problem reported only because a part of it
    failed (its location is a prefix of another problem's) is left out."""
    errors = err.errors()
    locs = [tuple(e["loc"]) for e in errors]
    kept = [e for e, loc in zip(errors, locs, strict=True)
            if not any(o != loc and o[:len(loc)] == loc for o in locs)] or errors[:1]
    # a check of the network as a whole reports its problems as the lines of one error
    problems = [(field, line) for e in kept for field, msg in [_problem(e, raw)]
                for line in msg.split("\n")]
    lines = [f"{field}: {msg}" if field else msg for field, msg in problems[1:MAX_PROBLEMS]]
    if len(problems) > MAX_PROBLEMS:
        lines.append(f"... and {len(problems) - MAX_PROBLEMS} more problems")
    field, msg = problems[0]
    return SpecError(msg, file=source, field=field or None, more=lines)


def _problem(first: dict, raw: Any) -> tuple[str, str]:
    """(dotted field, message) of one pydantic error."""
    loc = tuple(first["loc"])
    field, cls = _readable_loc(loc, raw)
    msg = first["msg"].removeprefix("Value error, ")
    if first["type"] == "extra_forbidden":
        cls = _readable_loc(loc[:-1], raw)[1]
        allowed = sorted(info.alias or a for a, info in cls.model_fields.items()
                         if a not in ("root", "source")) if cls else []
        msg = (f"unknown key '{loc[-1]}'; allowed keys here: {allowed}" if allowed
               else f"unknown key '{loc[-1]}'")
        field = field.rpartition(".")[0] or field
    elif first["type"] == "missing":
        msg = f"required field '{loc[-1]}' is missing; add it"
    elif first["type"] == "string_pattern_mismatch":
        msg = (f"'{first.get('input')}' is not a valid name; use letters, digits and "
               "underscores, starting with a letter")
    elif first["type"] == "too_short":
        what = loc[-1] if loc and isinstance(loc[-1], str) else "this list"
        msg = f"'{what}' is empty; declare at least one entry"
    elif first["type"] in ("float_parsing", "float_type", "int_parsing", "int_type"):
        msg = f"expected a number, got {first.get('input')!r}"
    return field, msg


def _readable_loc(loc: tuple, raw: Any) -> tuple[str, type[BaseModel] | None]:
    """Dotted field path with item names instead of list indices, and the model class."""
    parts: list[str] = []
    node: Any = raw
    cls: type[BaseModel] | None = Network
    for item in loc:
        if isinstance(item, int):
            if isinstance(node, dict):
                key = list(node)[item] if item < len(node) else item
                parts.append(str(key))
                node = node.get(key) if key in node else None
            else:
                parts.append(f"[{item}]")
                node = node[item] if isinstance(node, list) and item < len(node) else None
            cls = _element_model(cls)
        else:
            parts.append(str(item))
            node = node.get(item) if isinstance(node, dict) else None
            cls = _field_model(cls, str(item))
    return ".".join(parts).replace(".[", "["), cls


def _unwrap(tp: Any) -> Any:
    """The pydantic model class inside Optional[...] / tuple[...] / Annotated[...], if any."""
    origin = typing.get_origin(tp)
    if origin is typing.Annotated:
        return _unwrap(typing.get_args(tp)[0])
    if origin in (typing.Union, types.UnionType, tuple, list):
        for arg in typing.get_args(tp):
            found = _unwrap(arg)
            if found is not None:
                return found
        return None
    return tp if isinstance(tp, type) and issubclass(tp, BaseModel) else None


def _field_model(cls: type[BaseModel] | None, name: str) -> type[BaseModel] | None:
    if cls is None:
        return None
    for fname, info in cls.model_fields.items():
        if name in (fname, info.alias):
            return _unwrap(info.annotation) or cls
    return None


def _element_model(cls: type[BaseModel] | None) -> type[BaseModel] | None:
    return cls


def check_simulators(network: Network) -> None:
    """Check that built-in simulators know every declared input, parameter and output."""
    for model in network.models:
        sim = model.simulator
        if sim.kind != "builtin":
            continue
        field = f"models.{model.name}.simulator"
        if sim.name not in builtin_names():
            raise SpecError(f"unknown built-in simulator '{sim.name}'; choose one of "
                            f"{builtin_names()}", file=network.source, field=field)
        try:
            info = builtin_info(sim.name)
        except CalnetError as err:
            raise SpecError(str(err), file=network.source, field=field) from None
        for group, known in (("inputs", info.inputs), ("parameters", info.parameters),
                             ("outputs", info.outputs)):
            unknown = [v.name for v in getattr(model, group) if v.name not in known]
            if unknown:
                raise SpecError(f"built-in '{sim.name}' has no {group} {unknown}; its "
                                f"{group} are {list(known)}", file=network.source,
                                field=f"models.{model.name}.{group}")
        for var in (*model.inputs, *model.parameters, *model.outputs):
            expected = info.units.get(var.name)
            if expected is not None and norm_unit(var.unit) != norm_unit(expected):
                raise SpecError(f"'{var.name}' is declared in '{var.unit}' but built-in "
                                f"'{sim.name}' works in '{expected}'; declare '{expected}'",
                                file=network.source, field=f"models.{model.name}.{var.name}")
        missing = [n for n in info.inputs if n not in model.input_names]
        if missing:
            raise SpecError(f"built-in '{sim.name}' needs inputs {missing}; declare them",
                            file=network.source, field=f"models.{model.name}.inputs")
        undeclared = [n for n in info.parameters if n not in model.parameter_names]
        if undeclared:
            warnings.warn(f"{network.source}: models.{model.name}: parameters {undeclared} "
                          "are not declared and stay at the simulator's defaults",
                          SpecWarning, stacklevel=3)


def check_sampler(network: Network) -> None:
    """Warn of a single chain: R-hat then compares the chain's two halves, which cannot
    show a mode the chain never left (docs/method.md: several chains, never one)."""
    if network.settings.sampler.chains == 1:
        warnings.warn(f"{Path(network.source).name}: settings.sampler.chains is 1: R-hat "
                      "then compares the two halves of one chain, which cannot show a mode "
                      "that chain never left; run several chains (4, the default)",
                      SpecWarning, stacklevel=3)


def check_log_links(network: Network) -> None:
    """Warn of a link from an output modelled on its own scale into an input on the log
    scale: the output's surrogate can give values <= 0 there (its draws, far from its
    runs), whose logarithm the next model's surrogate cannot take, so predictions
    through the link come out not a number."""
    for i, link in enumerate(network.links):
        src = network.model(link.source_model)
        dst = network.model(link.target_model).variable(link.target_var)
        if (getattr(dst, "scale", "linear") == "log" and link.source_var in src.output_names
                and src.output(link.source_var).transform != "log"):
            where = Path(network.source).name if network.source else "spec"
            warnings.warn(f"{where}: links[{i}]: {link.target} is on the "
                          f"log scale but {link.source} is modelled on its own: its "
                          "surrogate can give values <= 0, whose logarithm does not exist, "
                          "and predictions through the link are then not a number; declare "
                          f"'transform: log' on {link.source}", SpecWarning, stacklevel=3)


#: a parameter prior with less than this share of its mass within the bounds is named
PRIOR_MASS_WARN = 0.01


def check_priors(network: Network) -> None:
    """Warn for every parameter whose prior has less than :data:`PRIOR_MASS_WARN` of its
    mass within the bounds and its median beyond one of them: truncated there, it presses
    the posterior against that bound."""
    for model in network.models:
        for p in model.parameters:
            below, within, above = p.prior_shares()
            if within >= PRIOR_MASS_WARN or max(below, above) <= 0.5:
                continue
            side, bound, fix = (("above", p.upper, "upper") if above > below
                                else ("below", p.lower, "lower"))
            warnings.warn(f"{network.source}: models.{model.name}.parameters.{p.name}: prior "
                          f"{p.prior_text()} puts {100 * within:.2g} % of its mass within "
                          f"[{p.lower:g}, {p.upper:g}] and most of it {side} {bound:g}, so "
                          f"the posterior will press against that bound whatever the data "
                          f"say; move the prior into the bounds or widen the {fix} bound",
                          SpecWarning, stacklevel=3)
