"""``add``: a new part where the candidate misses the target (joined by union) or covers too much (cut by
subtraction), one proposal per region, primitive kind and box: the primitive fitted to the region's
bounding box, and to its core (a box of cells nearly all inside it) where that differs, which is where a
region of several joined parts starts. For a cut the box is grown by one grid cell on every side, so that
the cut reaches past the surface it opens, and besides cutting the whole tree it may cut only the part
whose box overlaps the region most (a hole in one part that a later part covers again)."""

from __future__ import annotations

import numpy as np

from ipm.optim.structure.edits import EDITS, Context, Proposal
from ipm.optim.structure.program import combine, next_name, part, part_box, parts, replaced


def _overlap(box: tuple[np.ndarray, np.ndarray], lo: np.ndarray, hi: np.ndarray) -> float:
    return float(np.prod(np.clip(np.minimum(box[1], hi) - np.maximum(box[0], lo), 0.0, None)))


def _cut_one(tree: dict, cut: dict, kind: str, what: str, r: int, lo: np.ndarray, hi: np.ndarray) -> list[Proposal]:
    """``cut`` applied only to the part whose box overlaps the region most, where two or more parts overlap it
    (with one, cutting the whole tree is the same)."""
    scored = [(_overlap(b, lo, hi), path, node) for path, node in parts(tree) if (b := part_box(node)) is not None]
    scored = [x for x in scored if x[0] > 0.0]
    if len(scored) < 2:
        return []
    _, path, node = max(scored, key=lambda x: x[0])
    return [Proposal(f"subtraction {kind} from {node['name']} at the {what} of extra region {r}",
                     replaced(tree, path, combine("subtraction", node, cut)))]


@EDITS.register("add")
def add(tree: dict, ctx: Context) -> list[Proposal]:
    """A new part at a region the tree misses (union) or covers too much (subtraction)."""
    out = []
    cell = ctx.samples.cell
    for op, prefix, regions, grow in (("union", "part", ctx.missing, 0.0), ("subtraction", "cut", ctx.extra, 1.0)):
        for r, region in enumerate(regions):
            boxes = [("core", region.core_lo, region.core_hi)]
            if not np.allclose(region.core_lo, region.lo) or not np.allclose(region.core_hi, region.hi):
                boxes.append(("box", region.lo, region.hi))
            for what, lo, hi in boxes:
                for kind in ctx.kinds:
                    name = next_name(tree, prefix)
                    new = part(name, kind, 0.5 * (lo + hi), hi - lo + 2 * grow * cell)
                    where = "missing" if op == "union" else "extra"
                    out.append(Proposal(f"{op} {kind} at the {what} of {where} region {r}", combine(op, tree, new)))
                    if op == "subtraction":
                        out.extend(_cut_one(tree, new, kind, what, r, lo, hi))
    return out
