"""How readable the package is, in the numbers issue #33 asked for: functions over 80 lines, public functions
and methods with a docstring, and branches on a generator's kind outside the shape adapters.

``python -m benchmarks.code_health [--missing]`` prints them (``--missing`` lists the public functions without
a docstring); ``tests/test_architecture.py`` holds the limits (:data:`MAX_LONG`, :data:`MIN_DOCUMENTED`).
Counted by walking each module's syntax tree: every function, nested ones included, counts for length; the
module-level functions and the methods of module-level classes whose names do not start with ``_`` count as
public.
"""

from __future__ import annotations

import ast
import re
import sys
from pathlib import Path

PKG = Path(__file__).resolve().parents[1] / "ipm"
LONG = 80           # lines a function may have
MAX_LONG = 0        # functions over LONG lines allowed in the package
MIN_DOCUMENTED = 0.9
# a comparison of a generator's kind with "mesh" or "sdf": what only the adapters (ipm/optim/shapes.py) and the
# generators themselves may do
KIND_BRANCH = re.compile(r"kind\s*(==|!=|in)\s*[(\"'](mesh|sdf)")


def _functions(tree: ast.AST):
    """(function node, public) for every function in ``tree``; public: at module level or a method of a
    module-level class, and not named with a leading underscore."""
    def walk(node, top: bool):
        for ch in ast.iter_child_nodes(node):
            if isinstance(ch, (ast.FunctionDef, ast.AsyncFunctionDef)):
                yield ch, top and not ch.name.startswith("_")
                yield from walk(ch, False)
            elif isinstance(ch, ast.ClassDef):
                yield from walk(ch, top)
            else:
                yield from walk(ch, top)
    yield from walk(tree, True)


def measure(pkg: Path = PKG) -> dict:
    """``{"long": [(lines, "file:line name")], "public": n, "documented": n, "missing": [...],
    "kind_branches": ["file:line"]}`` over every module of ``pkg``."""
    out = {"long": [], "public": 0, "documented": 0, "missing": [], "kind_branches": []}
    for f in sorted(pkg.rglob("*.py")):
        rel = f.relative_to(pkg.parent).as_posix()
        text = f.read_text()
        for fn, public in _functions(ast.parse(text)):
            n = fn.end_lineno - fn.lineno + 1
            if n > LONG:
                out["long"].append((n, f"{rel}:{fn.lineno} {fn.name}"))
            if public:
                out["public"] += 1
                if ast.get_docstring(fn):
                    out["documented"] += 1
                else:
                    out["missing"].append(f"{rel}:{fn.lineno} {fn.name}")
        if rel.startswith("ipm/generators/") or rel == "ipm/optim/shapes.py":
            continue
        for i, line in enumerate(text.splitlines(), 1):
            if KIND_BRANCH.search(line):
                out["kind_branches"].append(f"{rel}:{i}")
    out["long"].sort(reverse=True)
    return out


def main(argv: list[str]) -> int:
    m = measure()
    print(f"functions over {LONG} lines: {len(m['long'])}")
    for n, where in m["long"]:
        print(f"  {n:4d} {where}")
    print(f"public functions with a docstring: {m['documented']}/{m['public']} = {m['documented'] / m['public']:.1%}")
    print(f"branches on a generator's kind outside the adapters: {len(m['kind_branches'])}")
    for where in m["kind_branches"]:
        print(f"  {where}")
    if "--missing" in argv:
        print("\n".join(m["missing"]))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
