"""Data flows one way (DESIGN.md): a module imports only from layers above it; library code never prints."""

from __future__ import annotations

import ast
from pathlib import Path

PKG = Path(__file__).resolve().parents[1] / "ipm"

# Layer of each top-level module or subpackage; an import may only go to a layer <= its own.
LAYERS = {
    "params": 0, "types": 0, "errors": 0, "registry": 0,
    "tree": 0,             # the node/tree framework shared by SDF and mesh trees
    "sdf": 1, "generators": 2, "jacobian": 2,
    "render": 3, "losses": 4, "metrics": 4, "optim": 5,
    "convert": 6,          # mesh -> universal representations: above generators and metrics, below the CLI
    # the edge: may import anything
    "io": 9, "viz": 9, "bench": 9, "cli": 9, "fitting": 9, "__main__": 9, "__init__": 9,
}


def _module_key(path: Path) -> str:
    rel = path.relative_to(PKG)
    return rel.parts[0].removesuffix(".py")


def _imports(path: Path):
    tree = ast.parse(path.read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("ipm."):
            yield node.module.split(".")[1], node.lineno
        elif isinstance(node, ast.Import):
            for a in node.names:
                if a.name.startswith("ipm."):
                    yield a.name.split(".")[1], node.lineno


def test_no_upward_imports():
    bad = []
    for path in PKG.rglob("*.py"):
        key = _module_key(path)
        level = LAYERS.get(key)
        assert level is not None, f"{path}: add its layer to LAYERS in this test"
        for target, line in _imports(path):
            if target in LAYERS and LAYERS[target] > level and LAYERS[target] != 9:
                bad.append(f"{path.relative_to(PKG)}:{line} imports ipm.{target}")
            if LAYERS.get(target) == 9 and level != 9 and target not in ("io",):
                bad.append(f"{path.relative_to(PKG)}:{line} imports the edge module ipm.{target}")
    assert not bad, "\n".join(bad)


def test_library_code_never_prints():
    bad = []
    for path in PKG.rglob("*.py"):
        if _module_key(path) in ("cli", "__main__"):
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "print":
                bad.append(f"{path.relative_to(PKG)}:{node.lineno}")
    assert not bad, bad
