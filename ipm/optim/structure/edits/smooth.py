"""``smooth``: rounded edges and blends: a primitive wrapped in ``round`` (its extents shrunk by the radius,
so the outline stays) and a union turned into a ``smooth_union``."""

from __future__ import annotations

import numpy as np

from ipm.optim.structure.edits import EDITS, Context, Proposal
from ipm.optim.structure.program import extent, get, primitive, primitives, replaced, walk

RADIUS = 0.02   # the starting radius and blend width (unit-sphere frame)


@EDITS.register("smooth")
def smooth(tree: dict, ctx: Context) -> list[Proposal]:
    """A primitive rounded, or a union made smooth."""
    out = []
    for path, prim in primitives(tree):
        parent = get(tree, path[:-1]) if path else None
        if parent is not None and parent.get("node") == "round":
            continue
        inner = primitive(prim["node"], np.maximum(extent(prim) - 2 * RADIUS, 0.01))
        out.append(Proposal(f"round {prim['node']} at {list(path)}",
                            replaced(tree, path, {"node": "round", "params": {"radius": RADIUS},
                                                  "children": [inner]})))
    for path, node in walk(tree):
        if node.get("node") == "union":
            out.append(Proposal(f"smooth union at {list(path)}",
                                replaced(tree, path, {**node, "node": "smooth_union", "params": {"k": RADIUS}})))
    return out
