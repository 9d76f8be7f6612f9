"""``add``: a new part where the candidate misses the target (joined by union) or covers too much (cut by
subtraction), one proposal per region, primitive kind and box: the primitive fitted to the region's
bounding box, and to its core (a box of cells nearly all inside it) where that differs, which is where a
region of several joined parts starts. For a cut the box is grown by one grid cell on every side, so that
the cut reaches past the surface it opens."""

from __future__ import annotations

import numpy as np

from ipm.optim.structure.edits import EDITS, Context, Proposal
from ipm.optim.structure.program import combine, next_name, part


@EDITS.register("add")
def add(tree: dict, ctx: Context) -> list[Proposal]:
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
    return out
