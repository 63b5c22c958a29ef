"""The package's layers: the pure rendering math below the models, the models below
what renders and trains them (no import cycles between layers)."""

import ast
from pathlib import Path

import nerfkit

ROOT = Path(nerfkit.__file__).parent
# each layer may import only from the layers listed before it
LAYERS = [
    {"errors", "config", "io", "precision", "cameras"},
    {"kernels", "fields", "render"},
    {"models"},
    {"output", "train"},
]


def imported_packages(path: Path) -> set[str]:
    """Top-level nerfkit modules/packages a file imports (relative or absolute)."""
    parts = path.relative_to(ROOT).with_suffix("").parts
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            if node.level:  # relative: resolve against the file's package
                base = list(parts[:-1])[: len(parts) - node.level]
                target = base + (node.module.split(".") if node.module else [])
            elif node.module and node.module.startswith("nerfkit."):
                target = node.module.split(".")[1:]
            else:
                continue
            if target:
                found.add(target[0])
            else:  # "from .. import x": x is the top-level package
                found.update(alias.name for alias in node.names)
    return found


def test_no_layer_imports_a_layer_above_it():
    rank = {name: i for i, layer in enumerate(LAYERS) for name in layer}
    wrong = []
    for i, layer in enumerate(LAYERS):
        for name in layer:
            files = [ROOT / f"{name}.py"] if (ROOT / f"{name}.py").exists() else sorted((ROOT / name).rglob("*.py"))
            assert files, name
            for f in files:
                for used in imported_packages(f):
                    if rank.get(used, -1) > i:
                        wrong.append(f"{f.relative_to(ROOT)} imports {used}")
    assert not wrong, wrong


def test_the_import_finder_sees_relative_and_absolute_imports():
    f = ROOT / "render" / "occupancy.py"  # imports ..kernels.reference and .volrend
    assert {"kernels", "render"} <= imported_packages(f)
