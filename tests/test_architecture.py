"""Data flows one way (docs/architecture.md): import contracts hold; library code never prints."""

from __future__ import annotations

import ast
import shutil
import subprocess
import sys
from pathlib import Path

PKG = Path(__file__).resolve().parents[1] / "ipm"
ROOT = PKG.parent


def test_import_contracts_hold():
    """The layers and the no-cycle rule of docs/architecture.md, as import-linter contracts in
    pyproject.toml. import-linter reads every import statement, also ``from ipm import x`` and imports
    inside functions."""
    exe = shutil.which("lint-imports") or str(Path(sys.executable).parent / "lint-imports")
    proc = subprocess.run([exe, "--config", str(ROOT / "pyproject.toml"), "--no-cache"], cwd=ROOT,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-2000:]
    assert "0 broken" in proc.stdout


def test_every_top_level_module_has_a_layer():
    """The layers contract is exhaustive: a new top-level module must be placed in a layer."""
    import tomllib

    cfg = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]["contracts"]
    layers = next(c for c in cfg if c["type"] == "layers")
    assert layers.get("exhaustive") is True
    named = {m.strip() for layer in layers["layers"] for m in layer.split("|")}
    tops = {p.stem for p in PKG.glob("*.py") if p.stem not in ("__init__", "__main__")}
    tops |= {p.name for p in PKG.iterdir() if (p / "__init__.py").is_file()}
    assert tops <= named, f"not in a layer: {sorted(tops - named)}"


def test_library_code_never_prints():
    bad = []
    for path in PKG.rglob("*.py"):
        if path.relative_to(PKG).parts[0].removesuffix(".py") in ("cli", "__main__"):
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "print":
                bad.append(f"{path.relative_to(PKG)}:{node.lineno}")
    assert not bad, bad


def test_functions_are_short_documented_and_blind_to_the_generators_kind():
    """Issue #33's numbers, held: no function over 80 lines, at least 90 % of the public functions and methods
    with a docstring, no comparison of a generator's kind outside the shape adapters and the generators
    (``python -m benchmarks.code_health`` prints them)."""
    from benchmarks import code_health as H

    m = H.measure()
    assert len(m["long"]) <= H.MAX_LONG, m["long"]
    assert m["documented"] / m["public"] >= H.MIN_DOCUMENTED, m["missing"]
    assert m["kind_branches"] == []
