"""``merge``: two parts joined by a union replaced by one part over both their bounding boxes (the search
sometimes covers one block with two; a delete alone cannot regrow the other in a short refinement). The
merged part takes the first part's kind and name."""

from __future__ import annotations

import numpy as np

from ipm.optim.structure.edits import EDITS, Context, Proposal
from ipm.optim.structure.program import get, part, part_box, parts, replaced, walk


def _without(tree: dict, path: tuple[int, ...]) -> dict | None:
    """``tree`` with the subtree at ``path`` removed from the union holding it (None: not under a union)."""
    if not path:
        return None
    parent = get(tree, path[:-1])
    if parent.get("node") not in ("union", "smooth_union"):
        return None
    return replaced(tree, path[:-1], parent["children"][1 - path[-1]])


@EDITS.register("merge")
def merge(tree: dict, ctx: Context) -> list[Proposal]:
    """Two parts of a union replaced by one over both their boxes."""
    out = []
    found = [(p, n, part_box(n)) for p, n in parts(tree) if n["name"].startswith("part")]
    found = [(p, n, b) for p, n, b in found if b is not None]
    for i, (_, a, ba) in enumerate(found):
        for pb, b, bb in found[i + 1:]:
            rest = _without(tree, pb)
            if rest is None:
                continue
            lo, hi = np.minimum(ba[0], bb[0]), np.maximum(ba[1], bb[1])
            where = next(p for p, n in walk(rest) if n.get("name") == a["name"])
            new = part(a["name"], get(a, (0,))["node"], 0.5 * (lo + hi), hi - lo)
            out.append(Proposal(f"merge {b['name']} into {a['name']}", replaced(rest, where, new)))
    return out
