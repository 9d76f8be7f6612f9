"""``replace``: a primitive swapped for another kind with the same bounding box (a box that should be a
cylinder)."""

from __future__ import annotations

from ipm.optim.structure.edits import EDITS, Context, Proposal
from ipm.optim.structure.program import extent, primitive, primitives, replaced


@EDITS.register("replace")
def replace(tree: dict, ctx: Context) -> list[Proposal]:
    """A primitive swapped for another kind with the same bounding box."""
    out = []
    for path, prim in primitives(tree):
        for kind in ctx.kinds:
            if kind != prim["node"]:
                out.append(Proposal(f"replace {prim['node']} at {list(path)} by {kind}",
                                    replaced(tree, path, primitive(kind, extent(prim)))))
    return out
