"""``mirror``: the macro of symmetric parts. A part that lies off the target's middle along x or z is
mirrored across the middle plane (``mirror`` node: a pair, the arms of a chair), or across both (a quad: its
legs). The mirror planes are the target's bounding-box middle (a symmetric object's plane of symmetry); the
part is first moved to the plane's positive side, where the mirror node reads it."""

from __future__ import annotations

import copy

import numpy as np

from ipm.optim.structure.edits import EDITS, Context, Proposal
from ipm.optim.structure.program import extent, get, parts, replaced

AXES = {0: "x", 2: "z"}


def _mirrored(node: dict, axes: tuple[int, ...], mid: np.ndarray) -> dict:
    moved = copy.deepcopy(node)
    prim = get(moved, (0,))
    while prim.get("node") in ("round", "mirror", "rotate"):
        prim = get(prim, (0,))
    half = 0.5 * extent(prim) if prim.get("node") in ("box", "cylinder", "sphere") else np.zeros(3)
    for a in axes:
        key = AXES[a]
        c = moved["params"][key]
        # on the positive side, clear of the plane (else the mirror would fold the part onto itself)
        moved["params"][key] = float(mid[a] + max(abs(c - mid[a]), half[a]))
    out = moved
    for a in axes:
        out = {"node": "mirror", "params": {"axis": a, "offset": float(mid[a])}, "children": [out]}
    return out


@EDITS.register("mirror")
def mirror(tree: dict, ctx: Context) -> list[Proposal]:
    """A part mirrored across the target's middle plane in x, z or both (a pair, a quad)."""
    out = []
    mid = 0.5 * (ctx.samples.lo + ctx.samples.hi)
    tol = 2.0 * ctx.samples.cell
    for path, node in parts(tree):
        parent = get(tree, path[:-1]) if path else None
        if parent is not None and parent.get("node") == "mirror":
            continue
        off = [a for a in AXES if abs(node["params"][AXES[a]] - mid[a]) > tol[a]]
        for axes in [(a,) for a in off] + ([tuple(off)] if len(off) == 2 else []):
            label = "+".join(AXES[a] for a in axes)
            new = replaced(tree, path, _mirrored(node, axes, mid))
            out.append(Proposal(f"mirror {node['name']} across {label}", new))
    return out
