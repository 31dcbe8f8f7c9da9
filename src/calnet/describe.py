"""A readable rendering of a network for ``calnet check``, with the problems that would
make every run of a model fail (a simulator that cannot be imported or reached)."""

from __future__ import annotations

import shutil
from pathlib import Path

from rich.console import Console
from rich.markup import escape
from rich.table import Table

from calnet.campaign.importing import read_runs
from calnet.campaign.planning import settings_of
from calnet.campaign.runners import load_callable, resolve_program
from calnet.errors import CampaignError
from calnet.files import shown_path
from calnet.spec.data import read_dataset
from calnet.spec.network import Network


def describe_network(network: Network, console: Console) -> None:
    """Print the models in topological order with their inputs, parameters and outputs."""
    console.print(f"[bold]network[/] {network.name}  ({network.source or 'built in Python'})")
    console.print(f"order: {' -> '.join(network.order)}")
    for i, name in enumerate(network.order, 1):
        model = network.model(name)
        table = Table(title=f"{i}. {name}  [dim]({_simulator(model.simulator)})[/]",
                      title_justify="left", show_edge=False, pad_edge=False)
        for col in ("variable", "kind", "unit", "range / role"):
            table.add_column(col)
        for var in model.inputs:
            link = network.link_into(name, var.name)
            role = (f"<- {link.source}" + (" (identity)" if _identity(network, link) else "")
                    if link else "free (set by experiment)")
            scale = " log scale" if getattr(var, "scale", "linear") == "log" else ""
            table.add_row(var.name, "input", var.unit,
                          f"[{var.lower:g}, {var.upper:g}]{scale}  {role}")
        for var in model.parameters:
            table.add_row(var.name, "parameter", var.unit,
                          f"[{var.lower:g}, {var.upper:g}]  prior {var.prior_text()}"
                          + _sharing(network, name, var.name))
        uses = network.output_uses(name)
        for var in model.outputs:
            table.add_row(var.name, "output", var.unit, _output_role(network, name, var, uses))
        console.print(table)
        problems = [simulator_problem(network, name), *unused_outputs(network, name)]
        for problem in filter(None, problems):
            console.print(f"[yellow]warning:[/] {escape(problem)}", soft_wrap=True)
    if not network.data:
        predicted = ", ".join(network.settings.predict) or "nothing (settings.predict is empty)"
        console.print(f"no data sets: emulation only (nothing is calibrated); predicts "
                      f"{predicted}")
    if network.data:
        console.print("[bold]data sets[/]")
        for ds in network.data:
            data = read_dataset(network, ds)
            console.print(escape(f"  {ds.name}: {ds.path} observes {ds.observes}; "
                                 f"{_count(len(data.y), 'point')} "
                                 f"({int((~data.is_test).sum())} train, "
                                 f"{int(data.is_test.sum())} test); inputs "
                                 f"{list(data.input_keys)}"), soft_wrap=True)
            console.print(escape(f"    {network.term_text(ds)}"), soft_wrap=True)
        console.print(escape(settings_text(network)), soft_wrap=True)
        compare = network.settings.compare
        if compare:
            from calnet.validation import changes_nothing, same_as_spec

            same = same_as_spec(network, compare)
            console.print(f"compared by leave-one-out with the variants {', '.join(compare)}"
                          + (f"; [yellow]warning:[/] {changes_nothing(same, 'not run')}"
                             if same else ""), soft_wrap=True)


def settings_text(network: Network) -> str:
    """How the network is calibrated: mode, surrogate variance and sampler settings."""
    cal, smp = network.settings.calibration, network.settings.sampler
    mode = cal.mode
    if cal.mode == "segmented":
        from calnet.calibration.calibrate_network import segmented_stages

        stages, prior = segmented_stages(network)
        mode = (f"segmented (plug: {cal.plug}; stages: "
                + ", then ".join(f"{'+'.join(models)} with {', '.join(data)}"
                                 for models, data in stages)
                + (f"; at their prior (no data depends on them): {', '.join(prior)}"
                   if prior else "") + ")")
    elif cal.plug == "mode":
        mode += " (plug: mode applies to segmented mode only: ignored)"
    return (f"calibration: {mode}, surrogate variance "
            f"{'in' if cal.emulator_variance else 'left out of'} the likelihood; sampler: "
            f"{_count(smp.chains, 'chain')} x ({smp.warmup} warm-up + {smp.draws} draws"
            f"{f', thin {smp.thin}' if smp.thin > 1 else ''}), target_accept "
            f"{smp.target_accept:g}, {'dense' if smp.dense_mass else 'diagonal'} mass matrix")


def _count(n: int, noun: str) -> str:
    """``"1 point"``, ``"3 points"``."""
    return f"{n} {noun}{'' if n == 1 else 's'}"


def unused_outputs(network: Network, model: str) -> list[str]:
    """A warning naming the outputs of ``model`` that nothing uses (no data set observes
    them, no link reads them, ``settings.predict`` does not list them): they get no
    surrogate. One line for all of a model's."""
    unused = [out for out, use in network.output_uses(model).items() if not use]
    if not unused:
        return []
    if len(unused) == 1:
        what, it, is_, gets = f"output {unused[0]}", "it", "is", "it gets"
    else:
        what, it, is_, gets = f"outputs {', '.join(unused)}", "them", "are", "they get"
    return [f"{model}: {what} {is_} used by nothing (no data set observes {it}, no link "
            f"reads {it}, settings.predict does not list {it}), so {gets} no surrogate and "
            f"{is_} never predicted; list {it} in settings.predict to emulate {it}, or "
            f"remove {it} from the spec"]


def import_problems(network: Network) -> list[tuple[str, str]]:
    """``(field, message)`` for each ``campaign.import`` table that the campaign would
    refuse, read with the campaign's own reader: a missing file, a missing column, a
    value that is not a finite number, a value outside the bounds with ``settings.strict``.
    A value outside the bounds without it is a :class:`~calnet.errors.CampaignWarning`."""
    out = []
    for model in network.models:
        name = settings_of(network, model).import_
        if name is None:
            continue
        table = network.path(name)
        try:
            read_runs(table, model, strict=network.settings.strict,
                      shown=shown_path(table, network.root))
        except CampaignError as err:
            out.append((f"models.{model.name}.campaign.import", str(err)))
    return out


def simulator_problem(network: Network, model: str) -> str | None:
    """Why every run of ``model`` would fail on this machine, if it can be told without
    running it: a Python target that cannot be imported, a command not found, a UM-Bridge
    server that does not answer or does not serve the model. (Workers of
    a remote Dask cluster may see other modules and programs, so this is a warning.)"""
    sim = network.model(model).simulator
    if sim.kind == "python":
        try:
            load_callable(sim.target, (str(Path(network.root).resolve()),))
        except CampaignError as err:  # the module has no such function
            return f"{model}: {err}; every run would fail"
        except ImportError as err:
            return (f"{model}: simulator 'python:{sim.target}' cannot be imported here "
                    f"({err}); every run would fail. Fix the target, or put the module "
                    "beside the spec or on PYTHONPATH")
        except Exception as err:  # importing ran the module's code, which raised
            return (f"{model}: importing the module of 'python:{sim.target}' raised "
                    f"{type(err).__name__}: {err}")
    elif sim.kind == "command":
        if shutil.which(resolve_program(sim.argv, network)[0]) is None:
            return (f"{model}: command '{sim.argv[0]}' is not found or not executable here; "
                    "every run would fail. Give its path (relative to the spec) or put it "
                    "on PATH")
    elif sim.kind == "umbridge":
        return _umbridge_problem(model, sim)
    return None


def _umbridge_problem(model: str, sim) -> str | None:
    """Why the UM-Bridge server of ``sim`` cannot run ``model`` (its ``/Info``, 5 s at most)."""
    import requests

    where = f"UM-Bridge server '{sim.url}'"
    try:
        reply = requests.get(f"{sim.url.rstrip('/')}/Info", timeout=5)
    except requests.RequestException as err:
        return (f"{model}: {where} cannot be reached ({type(err).__name__}); every run would "
                "fail. Start the server, or fix the URL (umbridge:URL/MODEL)")
    try:
        served = reply.json()["models"]
    except (ValueError, KeyError, TypeError):
        return (f"{model}: {where} does not answer /Info as a UM-Bridge server (HTTP "
                f"{reply.status_code}); every run would fail. Fix the URL (umbridge:URL/MODEL)")
    if sim.model not in served:
        return (f"{model}: {where} serves {list(served)}, not '{sim.model}'; every run would "
                "fail. Fix the model name (umbridge:URL/MODEL)")
    return None


def _simulator(sim) -> str:
    detail = {"builtin": sim.name, "python": sim.target, "command": " ".join(sim.argv),
              "umbridge": f"{sim.url} {sim.model}"}[sim.kind]
    return f"{sim.kind}: {detail}"


def _identity(network: Network, link) -> bool:
    return link.source_var in network.model(link.source_model).input_names


def _sharing(network: Network, model: str, name: str) -> str:
    """``  shared with M2, M3`` for a parameter that is one parameter of several models."""
    if not network.model(model).variable(name).shared:
        return ""
    others = [m for m in network.order if m != model
              and any(p.name == name and p.shared for p in network.model(m).parameters)]
    return f"  shared with {', '.join(others)}" if others else "  shared"


def _output_role(network: Network, model: str, var, uses: dict[str, tuple[str, ...]]) -> str:
    parts = [f"[green]{', '.join(uses[var.name])}[/]" if uses[var.name]
             else "[yellow]unused[/]"]
    observed = [d.name for d in network.datasets_for(model) if d.observed_output == var.name]
    if var.measurable:
        parts.append("measurable" + (f", observed by {', '.join(observed)}" if observed
                                     else ", no data set"))
    else:
        parts.append("unmeasurable")
    links = [ln.target for ln in network.links if ln.source == f"{model}.{var.name}"]
    if links:
        parts.append(f"-> {', '.join(links)}")
    if uses[var.name]:  # an unused output gets no surrogate, on any scale
        parts.append("surrogate" + (f" on {var.transform} scale" if var.transform else ""))
    return "; ".join(parts)
