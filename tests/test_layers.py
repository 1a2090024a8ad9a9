"""The package's layers (docs/design.md): each module imports only its own layer and those below, never a
private name of another module, and no source file is over 600 lines."""
from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "torch_grid"
# bottom to top; a module of the package root (robot.py, __init__.py, demo.py) is the top layer
LAYERS = ("model", "space", "ops", "step", "optim")
TOP = len(LAYERS)


def _layer(module: tuple[str, ...]) -> int:
    """The layer of a module given as its parts under the package ("ops", "table")."""
    return LAYERS.index(module[0]) if module and module[0] in LAYERS else TOP


def _modules() -> dict[tuple[str, ...], Path]:
    return {path.relative_to(PACKAGE).with_suffix("").parts: path for path in PACKAGE.rglob("*.py")}


def _imports(module: tuple[str, ...], path: Path):
    """(target module parts, imported names, line) of every import of the package in `path`, at any depth
    (function-level imports included)."""
    package = module[:-1]
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.level:
            base = package[:len(package) - (node.level - 1)]
            target = base + tuple(node.module.split(".")) if node.module else base
            yield target, [a.name for a in node.names], node.lineno
        elif isinstance(node, ast.ImportFrom) and (node.module or "").startswith("torch_grid"):
            yield tuple(node.module.split(".")[1:]), [a.name for a in node.names], node.lineno
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.startswith("torch_grid"):
                    yield tuple(alias.name.split(".")[1:]), [], node.lineno


def test_layers_import_only_downwards():
    modules = _modules()
    upward = []
    for module, path in modules.items():
        for target, names, line in _imports(module, path):
            # `from . import load` in a top module names the package itself: the top layer
            if _layer(target) > _layer(module):
                upward.append(f"{path.relative_to(PACKAGE)}:{line} imports {'.'.join(target)}")
    assert not upward, "imports from a higher layer:\n" + "\n".join(upward)


def test_no_private_name_of_another_module():
    private = []
    for module, path in _modules().items():
        for target, names, line in _imports(module, path):
            private += [f"{path.relative_to(PACKAGE)}:{line} imports {'.'.join(target)}.{n}" for n in names
                        if n.startswith("_")]
    assert not private, "imports of another module's private names:\n" + "\n".join(private)


def test_every_module_is_in_a_layer():
    strays = [p for m, p in _modules().items() if len(m) > 2 or (len(m) == 2 and m[0] not in LAYERS)]
    assert not strays, f"modules outside the layers {LAYERS}: {strays}"


def test_no_source_file_over_600_lines():
    sources = [*PACKAGE.rglob("*.py"), *PACKAGE.rglob("*.h"), *PACKAGE.rglob("*.cuh")]
    long = {str(p.relative_to(PACKAGE)): n for p in sources if (n := len(p.read_text().splitlines())) > 600}
    assert not long, f"source files over 600 lines: {long}"
