"""The import structure of nerfkit: no cycles between modules or between packages, and layers.

The source is parsed with :mod:`ast`, never imported. EVERY import statement counts, at the top
of a module or inside a function: a function-level import only delays a cycle, it does not
remove it (the two modules still cannot be understood, tested or moved apart). Imports under
``if TYPE_CHECKING:`` are left out, since they never run.

Edges:

- ``import nerfkit.a.b`` and ``from nerfkit.a import b`` (``b`` a submodule) go to ``nerfkit.a.b``;
  ``from nerfkit.a import name`` (``name`` not a submodule) goes to ``nerfkit.a`` (its
  ``__init__``). Relative imports are resolved first.
- Package graph: a node per first-level subpackage of nerfkit (``data``, ``sfm``, ``capture``,
  ...) and one per top-level module (``cameras``, ``errors``, ...); an edge when a module of one
  imports a module of another.
"""

from __future__ import annotations

import ast
import importlib
from dataclasses import dataclass
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"
ROOT = "nerfkit"

# The layering contract, lowest layer first: a module may import its own layer and the layers
# below, never a higher one. Names are first-level packages and top-level modules of nerfkit
# ("data", "cameras"); "nerfkit" is the package root (its course API is imported lazily, by
# name, and so adds no edge). Packages that share a layer may import each other in one
# direction only (test_no_package_cycles). A new package or top-level module takes its place here.
LAYERS: list[tuple[str, set[str]]] = [
    (
        "foundations: errors, files, images, camera conventions, settings, plain geometry",
        {
            "nerfkit",
            "errors",
            "arrays",
            "precision",
            "io",
            "images",
            "cameras",
            "config",
            "ground",
            "table_cut",
            "splat_files",
            "splat_constants",
            "scene_extent",
            "object_detail",
        },
    ),
    ("datasets: the Scene type and its file formats", {"data"}),
    (
        "rendering maths: volume rendering, sampling, kernels, fields, estimators, loss terms, "
        "a capture's surroundings",
        {"render", "kernels", "fields", "estimators", "losses", "surroundings"},
    ),
    ("figures, videos and the dataset viewer", {"viz"}),
    ("captures, structure from motion, models, mesh and point export", {"capture", "sfm", "models", "export"}),
    (
        "what models make and how they learn: rendered outputs, scene presets, training, image fitting",
        {"output", "presets", "train", "fit_image"},
    ),
    ("the command line and the Python API over it", {"commands", "cli", "__main__", "api"}),
]


@dataclass(frozen=True)
class Edge:
    src: str
    dst: str
    file: str
    line: int
    in_function: bool


def module_name(path: Path, src: Path = SRC) -> str:
    """``src/nerfkit/data/scene.py`` -> ``nerfkit.data.scene``; a package's ``__init__`` -> the package."""
    parts = list(path.relative_to(src).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _imports(tree: ast.AST):
    """Yield ``(node, in_function)`` for every Import/ImportFrom outside ``if TYPE_CHECKING:``."""

    def walk(node: ast.AST, in_function: bool):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and _is_type_checking(child.test):
                for sub in child.orelse:
                    yield from walk_one(sub, in_function)
                continue
            yield from walk_one(child, in_function)

    def walk_one(node: ast.AST, in_function: bool):
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            yield node, in_function
            return
        inner = in_function or isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
        yield from walk(node, inner)

    yield from walk(tree, False)


def _resolve(module: str, is_package: bool, level: int, target: str | None) -> str:
    """Absolute name of ``from <level dots><target> import ...`` written in ``module``."""
    if level == 0:
        return target or ""
    base = module.split(".")
    if not is_package:
        base = base[:-1]
    if level > 1:
        base = base[: len(base) - (level - 1)]
    return ".".join(base + ([target] if target else []))


def _known(name: str, modules: set[str]) -> str | None:
    """The longest known module that ``name`` is or lies in (``nerfkit.a.b.func`` -> ``nerfkit.a.b``)."""
    parts = name.split(".")
    while parts:
        candidate = ".".join(parts)
        if candidate in modules:
            return candidate
        parts.pop()
    return None


def module_edges(src: Path = SRC) -> tuple[set[str], list[Edge]]:
    """All nerfkit modules and every import edge between them (self-imports left out)."""
    files = sorted((src / ROOT).rglob("*.py"))
    modules = {module_name(f, src) for f in files}
    edges: list[Edge] = []
    for f in files:
        name = module_name(f, src)
        is_package = f.name == "__init__.py"
        tree = ast.parse(f.read_text(encoding="utf-8"), filename=str(f))
        for node, in_function in _imports(tree):
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            else:
                base = _resolve(name, is_package, node.level, node.module)
                for alias in node.names:
                    sub = f"{base}.{alias.name}"
                    targets.append(sub if sub in modules else base)
            for target in targets:
                dst = _known(target, modules)
                if dst is not None and dst != name:
                    rel = str(f.relative_to(src))
                    edges.append(Edge(name, dst, rel, node.lineno, in_function))
    return modules, edges


def package_of(module: str) -> str:
    """``nerfkit.data.scene`` -> ``data``; ``nerfkit.cameras`` -> ``cameras``; ``nerfkit`` -> ``nerfkit``."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else parts[0]


def graph_of(edges: list[Edge], key=lambda m: m) -> dict[str, dict[str, Edge]]:
    """Adjacency ``{src: {dst: first edge}}`` after mapping names through ``key``; self-edges dropped."""
    graph: dict[str, dict[str, Edge]] = {}
    for e in edges:
        a, b = key(e.src), key(e.dst)
        graph.setdefault(a, {})
        graph.setdefault(b, {})
        if a != b:
            graph[a].setdefault(b, e)
    return graph


def find_cycles(graph: dict[str, set[str]] | dict[str, dict[str, Edge]]) -> list[list[str]]:
    """One cycle ``[a, b, ..., a]`` per strongly connected component with more than one node.

    Tarjan's algorithm (iterative) finds the components; a breadth-first search inside each
    gives a shortest cycle through its smallest node. Self-loops are not cycles here.
    """
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    components: list[list[str]] = []
    counter = 0
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            advanced = False
            for child in children:
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph.get(child, ())))))
                    advanced = True
                    break
                if child in on_stack:
                    low[node] = min(low[node], index[child])
            if advanced:
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    top = stack.pop()
                    on_stack.discard(top)
                    component.append(top)
                    if top == node:
                        break
                if len(component) > 1:
                    components.append(sorted(component))
    cycles = []
    for component in sorted(components):
        members = set(component)
        start = component[0]
        previous: dict[str, str] = {}
        frontier = [start]
        found = None
        while frontier and found is None:
            next_frontier = []
            for node in frontier:
                for child in sorted(graph.get(node, ())):
                    if child not in members:
                        continue
                    if child == start:
                        found = node
                        break
                    if child not in previous:
                        previous[child] = node
                        next_frontier.append(child)
                if found is not None:
                    break
            frontier = next_frontier
        path = [start]
        node = found
        while node != start:
            path.append(node)
            node = previous[node]
        path.append(start)
        path.reverse()
        cycles.append(path)
    return cycles


def _describe(cycles: list[list[str]], graph: dict[str, dict[str, Edge]]) -> str:
    lines = []
    for cycle in cycles:
        lines.append(" -> ".join(cycle))
        for a, b in zip(cycle, cycle[1:], strict=False):
            e = graph[a][b]
            where = "in a function" if e.in_function else "top level"
            lines.append(f"    {a} -> {b}: {e.file}:{e.line} ({where})")
    return "\n".join(lines)


# ----------------------------------------------------------------------------- the cycle finder


def test_find_cycles_on_a_crafted_graph():
    graph = {
        "a": {"b"},
        "b": {"c"},
        "c": {"a", "d"},  # a -> b -> c -> a
        "d": {"e"},
        "e": {"d"},  # d <-> e
        "f": {"a", "f"},  # self-loop only: not a cycle
        "g": set(),
    }
    cycles = find_cycles(graph)
    assert cycles == [["a", "b", "c", "a"], ["d", "e", "d"]]
    for cycle in cycles:
        for a, b in zip(cycle, cycle[1:], strict=False):
            assert b in graph[a]
    assert find_cycles({"a": {"b"}, "b": {"c"}, "c": set()}) == []
    # a shortest cycle through the smallest node, not any cycle of the component
    assert find_cycles({"a": {"b", "x"}, "b": {"c"}, "c": {"a"}, "x": {"a"}}) == [["a", "x", "a"]]


def test_module_edges_resolve_relative_and_function_level_imports(tmp_path):
    pkg = tmp_path / ROOT
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "top.py").write_text("from .sub import leaf\nfrom .sub import THING\n")
    (pkg / "sub" / "__init__.py").write_text("THING = 1\n")
    (pkg / "sub" / "leaf.py").write_text(
        "from typing import TYPE_CHECKING\n"
        "if TYPE_CHECKING:\n    from .. import top\n"
        "def f():\n    from ..top import x\n    import nerfkit.sub\n"
    )
    _, edges = module_edges(tmp_path)
    got = {(e.src, e.dst, e.in_function) for e in edges}
    assert got == {
        ("nerfkit.top", "nerfkit.sub.leaf", False),
        ("nerfkit.top", "nerfkit.sub", False),
        ("nerfkit.sub.leaf", "nerfkit.top", True),
        ("nerfkit.sub.leaf", "nerfkit.sub", True),
    }
    graph = graph_of(edges)
    assert find_cycles(graph) == [["nerfkit.sub.leaf", "nerfkit.top", "nerfkit.sub.leaf"]]


# ----------------------------------------------------------------------------- nerfkit itself


@pytest.fixture(scope="module")
def edges() -> list[Edge]:
    return module_edges()[1]


def test_counts_function_level_imports(edges):
    # the check means something only if it sees the imports inside functions too
    assert any(e.in_function for e in edges)
    assert any(not e.in_function for e in edges)


def test_no_module_cycles(edges):
    graph = graph_of(edges)
    cycles = find_cycles(graph)
    assert not cycles, "import cycles between modules:\n" + _describe(cycles, graph)


def test_no_package_cycles(edges):
    graph = graph_of(edges, package_of)
    cycles = find_cycles(graph)
    assert not cycles, "import cycles between packages of nerfkit:\n" + _describe(cycles, graph)


def test_every_package_has_a_layer(edges):
    rank = {name for _, layer in LAYERS for name in layer}
    missing = sorted({package_of(m) for e in edges for m in (e.src, e.dst)} - rank)
    assert not missing, f"place these in LAYERS (tests/test_imports.py): {missing}"


def test_layers(edges):
    rank = {name: i for i, (_, layer) in enumerate(LAYERS) for name in layer}
    wrong = []
    for e in edges:
        a, b = package_of(e.src), package_of(e.dst)
        if a in rank and b in rank and rank[b] > rank[a]:
            wrong.append(
                f"{e.src} ({LAYERS[rank[a]][0].split(':')[0]}) -> {e.dst} "
                f"({LAYERS[rank[b]][0].split(':')[0]}): {e.file}:{e.line}"
            )
    assert not wrong, "a lower layer imports a higher one:\n" + "\n".join(sorted(set(wrong)))


BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


def _nerfkit_names(path: Path) -> list[tuple[str, str | None]]:
    """(module, name) for every ``from nerfkit... import name`` and (module, None) for every
    ``import nerfkit...`` in a script, wherever it stands (:func:`_imports`'s statements)."""
    found: list[tuple[str, str | None]] = []
    for node, _ in _imports(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.ImportFrom):
            if node.level == 0 and node.module and node.module.split(".")[0] == ROOT:
                found += [(node.module, a.name) for a in node.names]
        else:
            found += [(a.name, None) for a in node.names if a.name.split(".")[0] == ROOT]
    return found


@pytest.mark.parametrize("script", sorted(BENCHMARKS.glob("*.py")), ids=lambda p: p.name)
def test_benchmark_scripts_name_what_nerfkit_has(script):
    """Every module and name a benchmark script takes from nerfkit exists (the scripts are not
    run by the tests; a rename in the package must not leave them broken)."""
    missing = []
    for module, name in _nerfkit_names(script):
        mod = importlib.import_module(module)
        if name is not None and not hasattr(mod, name):
            try:
                importlib.import_module(f"{module}.{name}")
            except ModuleNotFoundError:
                missing.append(f"{module}.{name}")
    assert not missing, f"{script.name} imports what nerfkit does not have: {missing}"
