"""``delete``: a subtree removed: a union or subtraction node replaced by one of its children (the
other child's subtree goes; a subtraction keeps only its first child: the cut goes)."""

from __future__ import annotations

from ipm.optim.structure.edits import EDITS, Context, Proposal
from ipm.optim.structure.program import count_nodes, get, replaced, walk

OPS = ("union", "smooth_union", "subtraction", "smooth_subtraction")


@EDITS.register("delete")
def delete(tree: dict, ctx: Context) -> list[Proposal]:
    """A union's or subtraction's subtree removed."""
    out = []
    for path, node in walk(tree):
        if node.get("node") not in OPS:
            continue
        keep = (0, 1) if "union" in node["node"] else (0,)
        for k in keep:
            gone = get(node, (1 - k,))
            out.append(Proposal(f"delete {count_nodes(gone)} nodes at {list(path) + [1 - k]}",
                                replaced(tree, path, node["children"][k])))
    return out
