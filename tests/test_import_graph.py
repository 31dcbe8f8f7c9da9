"""Imports flow down the pipeline: no circle, no edge from a lower layer to a higher one.

Every module of ``src/calnet`` is parsed with :mod:`ast`; an edge ``a -> b`` is an import
of calnet module ``b`` anywhere in ``a`` (at the top or inside a function). Imports under
``if TYPE_CHECKING:`` are left out: they never run, so they order nothing at load time.

The layers, lowest first (a module may import from its own layer or a lower one):

- utilities: errors, files, parallel, progress, JAX configuration;
- simulators: the built-in physics, which know nothing of specs (loading a spec checks a
  built-in simulator's names against :mod:`calnet.simulators.registry`);
- spec: variables, models, the network, loading YAML;
- results: the typed stage results that the report renders (plain data);
- gp: the Gaussian-process library (kernels, likelihood, fit, cross-validation, files,
  the GP input space of a model) and :mod:`calnet.chain` (the network as a function of
  GPs): pure numerics that chain-aware campaign designs use to place downstream runs;
- campaign, surrogates (the network's GPs from its campaign runs), calibration;
- the stages after calibration: prediction, emulation, validation, sensitivity, verify;
- report, pipeline, and the command line at the top.
"""

from __future__ import annotations

import ast
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src"

LAYERS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("utilities", ("calnet", "calnet._jax", "calnet.errors", "calnet.files", "calnet.interrupts",
                   "calnet.parallel", "calnet.progress")),
    ("simulators", ("calnet.simulators",)),
    ("spec", ("calnet.spec",)),
    ("results", ("calnet.results",)),
    ("gp", ("calnet.surrogates.kernels", "calnet.surrogates.likelihood",
            "calnet.surrogates.gp", "calnet.surrogates.fit", "calnet.surrogates.cv",
            "calnet.surrogates.persist", "calnet.surrogates.space", "calnet.chain")),
    ("campaign", ("calnet.campaign",)),
    ("surrogates", ("calnet.surrogates",)),
    ("calibration", ("calnet.calibration",)),
    ("stages", ("calnet.predict", "calnet.emulation", "calnet.validation",
                "calnet.sensitivity", "calnet.explore", "calnet.verify")),
    ("report", ("calnet.report",)),
    ("pipeline", ("calnet.pipeline",)),
    ("cli", ("calnet.cli", "calnet.describe", "calnet.__main__")),
)

#: circles that are known and named here with the move that removes them; the test fails
#: when one of them is gone (delete it here) or a new one appears
KNOWN_CYCLES: dict[frozenset[str], str] = {}


def modules(src: Path = SRC) -> dict[str, Path]:
    """``{"calnet.spec.models": path, ...}``; a package is named by its ``__init__``."""
    out = {}
    for path in sorted((src / "calnet").rglob("*.py")):
        parts = list(path.relative_to(src).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        out[".".join(parts)] = path
    return out


def _is_type_checking(node: ast.If) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _imports(tree: ast.AST) -> list[ast.Import | ast.ImportFrom]:
    """Every import statement of ``tree`` except those under ``if TYPE_CHECKING:``."""
    found, todo = [], [tree]
    while todo:
        node = todo.pop()
        if isinstance(node, ast.If) and _is_type_checking(node):
            todo.extend(node.orelse)
            continue
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            found.append(node)
        todo.extend(ast.iter_child_nodes(node))
    return found


def import_graph(src: Path = SRC) -> dict[str, set[str]]:
    """``{module: {calnet modules it imports}}`` over every module of the package."""
    mods = modules(src)

    def owner(name: str) -> str | None:  # the module a dotted name lives in
        while name and name not in mods:
            name = name.rpartition(".")[0]
        return name or None

    graph = {}
    for name, path in mods.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        targets = set()
        for node in _imports(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.Import):
                targets.update(owner(a.name) for a in node.names if a.name.startswith("calnet"))
                continue
            base = node.module or ""
            if node.level:  # relative: from .x import y
                up = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*up, base] if base else up)
            if base == "calnet" or base.startswith("calnet."):
                for alias in node.names:
                    full = f"{base}.{alias.name}"
                    targets.add(full if full in mods else owner(base))
        graph[name] = targets - {name, None}
    return graph


def layer_of(module: str) -> int | None:
    """Index in :data:`LAYERS` of the longest prefix naming ``module``; None if none does."""
    best, length = None, -1
    for i, (_, prefixes) in enumerate(LAYERS):
        for prefix in prefixes:
            hit = module == prefix or (prefix != "calnet" and module.startswith(prefix + "."))
            if hit and len(prefix) > length:
                best, length = i, len(prefix)
    return best


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan), each as a
    closed path ``[a, b, ..., a]`` through the component."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = set()
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.add(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(_closed_path(graph, comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def _closed_path(graph: dict[str, set[str]], comp: set[str]) -> list[str]:
    """A shortest path from the component's first module back to itself (breadth first)."""
    start = min(comp)
    prev, todo = {start: None}, [start]
    while todo:
        v = todo.pop(0)
        for w in sorted(graph[v] & comp):
            if w == start:
                path = [v]
                while prev[path[-1]] is not None:
                    path.append(prev[path[-1]])
                return [*reversed(path), start]
            if w not in prev:
                prev[w] = v
                todo.append(w)
    return sorted(comp)


def test_every_module_has_a_layer():
    missing = sorted(m for m in modules() if layer_of(m) is None)
    assert not missing, f"modules in no layer (add them to LAYERS): {missing}"


def test_no_upward_import():
    graph = import_graph()
    upward = [f"{a} ({LAYERS[layer_of(a)][0]}) -> {b} ({LAYERS[layer_of(b)][0]})"
              for a in sorted(graph) for b in sorted(graph[a])
              if None not in (layer_of(a), layer_of(b)) and layer_of(b) > layer_of(a)]
    assert not upward, "imports from a lower layer to a higher one:\n" + "\n".join(upward)


def test_no_import_cycle():
    found = cycles(import_graph())
    new = [" -> ".join(c) for c in found if frozenset(c) not in KNOWN_CYCLES]
    gone = [sorted(c) for c in KNOWN_CYCLES if c not in {frozenset(f) for f in found}]
    assert not new, "import cycles:\n" + "\n".join(new)
    assert not gone, f"these known cycles are gone; delete them from KNOWN_CYCLES: {gone}"


#: what the report may not import, directly or through another module: it renders the
#: stages' results (:mod:`calnet.results`) and computes nothing of its own
NOT_IN_REPORT = ("calnet.calibration", "calnet.predict", "calnet.surrogates",
                 "calnet.validation")


def reachable(graph: dict[str, set[str]], start: set[str]) -> set[str]:
    """Every module imported from ``start``, directly or through others."""
    seen, todo = set(), list(start)
    while todo:
        for w in graph.get(todo.pop(), ()):
            if w not in seen:
                seen.add(w)
                todo.append(w)
    return seen


def test_the_report_only_renders():
    graph = import_graph()
    report = {m for m in graph if m == "calnet.report" or m.startswith("calnet.report.")}
    bad = sorted(m for m in reachable(graph, report)
                 if any(m == p or m.startswith(p + ".") for p in NOT_IN_REPORT))
    paths = [f"{a} -> {b}" for a in sorted(report) for b in sorted(graph[a])
             if b in bad or reachable(graph, {b}) & set(bad)]
    assert not bad, (f"report/ reaches {bad} through: {paths}; compute it in the stage and "
                     "hand it over in calnet.results")


def test_the_graph_sees_function_local_and_relative_imports(tmp_path):
    pkg = tmp_path / "calnet"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "low.py").write_text("def f():\n    from calnet.sub import high\n")
    (pkg / "sub" / "__init__.py").write_text("")
    (pkg / "sub" / "high.py").write_text(
        "from typing import TYPE_CHECKING\nfrom ..low import f\n"
        "if TYPE_CHECKING:\n    from calnet import nothing\n")
    graph = import_graph(tmp_path)
    assert graph["calnet.low"] == {"calnet.sub.high"}
    assert graph["calnet.sub.high"] == {"calnet.low"}
    assert cycles(graph) == [["calnet.low", "calnet.sub.high", "calnet.low"]]
    assert reachable(graph, {"calnet.low"}) == {"calnet.low", "calnet.sub.high"}
