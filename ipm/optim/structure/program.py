"""Candidate trees of a structure search, as the nested JSON form of :mod:`ipm.sdf` (what a person edits).

A *part* is a primitive placed by a translation, ``translate(x, y, z)`` over ``box``, ``cylinder`` or
``sphere`` (optionally rounded, or mirrored into a pair or a quad); parts are joined by ``union`` and cut by
``subtraction``. Every translation node is named (``part3``, ``cut1``) so that the tree file reads as a list
of parts and its parameters as ``part3.x``. Edits (:mod:`ipm.optim.structure.edits`) rewrite these dicts; the
helpers here read and build them. Paths are tuples of child indices from the root.
"""

from __future__ import annotations

import copy
import json
import re
from collections.abc import Iterator

import numpy as np

PRIMITIVES = ("box", "cylinder", "sphere")
ROUND_TYPES = ("round",)
SIZE_MIN = 0.01       # the smallest extent a new primitive is given (unit-sphere frame)

Path = tuple[int, ...]


def primitive(kind: str, extent) -> dict:
    """A primitive node ``kind`` whose bounding box has the extents ``extent`` (3,) (x, y, z)."""
    sx, sy, sz = (max(float(e), SIZE_MIN) for e in extent)
    if kind == "box":
        params = {"size_x": sx, "size_y": sy, "size_z": sz}
    elif kind == "cylinder":
        params = {"radius": max(sx, sz) / 2, "height": sy}
    elif kind == "sphere":
        params = {"radius": (sx + sy + sz) / 6}
    else:
        raise ValueError(f"unknown primitive {kind!r}; known: {', '.join(PRIMITIVES)}")
    return {"node": kind, "params": params}


def extent(prim: dict) -> np.ndarray:
    """The bounding-box extents (3,) of a primitive node."""
    p = prim["params"]
    if prim["node"] == "box":
        return np.array([p["size_x"], p["size_y"], p["size_z"]], dtype=np.float64)
    if prim["node"] == "cylinder":
        return np.array([2 * p["radius"], p["height"], 2 * p["radius"]], dtype=np.float64)
    if prim["node"] == "sphere":
        return np.full(3, 2 * p["radius"], dtype=np.float64)
    raise ValueError(f"not a primitive: {prim['node']!r}")


def part(name: str, kind: str, center, ext) -> dict:
    """A named part: ``translate`` to ``center`` (3,) over a ``kind`` primitive of extents ``ext``."""
    x, y, z = (float(c) for c in center)
    return {"node": "translate", "name": name, "params": {"x": x, "y": y, "z": z},
            "children": [primitive(kind, ext)]}


def part_box(node: dict) -> tuple[np.ndarray, np.ndarray] | None:
    """The bounding box ``(lo, hi)`` of a part whose child is a plain primitive, else None."""
    child = node["children"][0]
    if child.get("node") not in PRIMITIVES:
        return None
    c = np.array([node["params"][a] for a in "xyz"], dtype=np.float64)
    h = 0.5 * extent(child)
    return c - h, c + h


def combine(op: str, a: dict, b: dict) -> dict:
    """A new ``op`` node (union, subtraction, ...) over ``a`` and ``b`` (not copied)."""
    return {"node": op, "children": [a, b]}


def walk(d: dict, path: Path = ()) -> Iterator[tuple[Path, dict]]:
    """Every node (pre-order) with its path."""
    yield path, d
    for i, c in enumerate(d.get("children", ())):
        yield from walk(c, (*path, i))


def get(d: dict, path: Path) -> dict:
    """The node at ``path`` (child indices from the root)."""
    for i in path:
        d = d["children"][i]
    return d


def replaced(d: dict, path: Path, new: dict) -> dict:
    """A deep copy of ``d`` with the node at ``path`` replaced by ``new``."""
    if not path:
        return copy.deepcopy(new)
    out = copy.deepcopy(d)
    parent = get(out, path[:-1])
    parent["children"][path[-1]] = copy.deepcopy(new)
    return out


def count_nodes(d: dict) -> int:
    """Nodes in the tree as written (transforms included; a macro node counts as one)."""
    return sum(1 for _ in walk(d))


def parts(d: dict) -> list[tuple[Path, dict]]:
    """The named parts (translate nodes named ``part*`` or ``cut*``) with their paths."""
    return [(p, n) for p, n in walk(d) if n.get("node") == "translate" and re.fullmatch(r"(part|cut)\d+",
                                                                                         str(n.get("name", "")))]


def primitives(d: dict) -> list[tuple[Path, dict]]:
    """Every primitive node of the search's kinds with its path."""
    return [(p, n) for p, n in walk(d) if n.get("node") in PRIMITIVES]


def next_name(d: dict, prefix: str) -> str:
    """``prefix`` plus one more than the highest number any part of ``d`` carries."""
    nums = [int(m.group(1)) for _, n in walk(d) if (m := re.fullmatch(r"(?:part|cut)(\d+)", str(n.get("name", ""))))]
    return f"{prefix}{max(nums, default=0) + 1}"


def structure(d: dict) -> str:
    """The tree's structure without parameters or names, children of a union in a canonical order: two
    trees with the same string have the same primitives joined the same way (up to the order of a union)."""
    kids = [structure(c) for c in d.get("children", ())]
    if d["node"] in ("union", "union_n", "smooth_union"):
        kids.sort()
    discrete = {k: v for k, v in d.get("params", {}).items() if isinstance(v, int) and not isinstance(v, bool)}
    head = d["node"] + (json.dumps(discrete, sort_keys=True) if discrete and d["node"] != "translate" else "")
    return head + ("(" + ",".join(kids) + ")" if kids else "")


def primitive_counts(d: dict) -> dict[str, int]:
    """How many primitives of each kind the tree holds (``{"box": 2, "sphere": 1}``)."""
    out: dict[str, int] = {}
    for _, n in primitives(d):
        out[n["node"]] = out.get(n["node"], 0) + 1
    return dict(sorted(out.items()))


def signature(d: dict) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """The kinds of the primitives that add material and of those that cut it (under the second child of an
    odd number of subtractions), each sorted: two trees agree here when they have the same primitives up
    to order, the equivalence the structure table checks against a known tree."""
    add: list[str] = []
    cut: list[str] = []

    def visit(n: dict, negative: bool) -> None:
        if n.get("node") in PRIMITIVES:
            (cut if negative else add).append(n["node"])
        for i, c in enumerate(n.get("children", ())):
            visit(c, negative ^ (n["node"] in ("subtraction", "smooth_subtraction") and i == 1))

    visit(d, False)
    return tuple(sorted(add)), tuple(sorted(cut))


__all__ = ["PRIMITIVES", "combine", "count_nodes", "extent", "get", "next_name", "part", "part_box", "parts",
           "primitive", "primitive_counts", "primitives", "replaced", "signature", "structure", "walk"]
