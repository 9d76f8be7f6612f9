"""``turn``: a part's primitive turned about its centre: ``rotate`` inserted between the part's translation
and its primitive, starting at angle 0 about the x axis or the z axis (a chair's reclined back, a tilted
leg); the refinement finds the angle (and may tilt the axis)."""

from __future__ import annotations

from ipm.optim.structure.edits import EDITS, Context, Proposal
from ipm.optim.structure.program import get, parts, replaced

AXES = {"x": (90.0, 0.0), "z": (90.0, 90.0)}   # (tilt, azimuth) of the rotation axis, ipm.sdf._math.axis_from_tilt


@EDITS.register("turn")
def turn(tree: dict, ctx: Context) -> list[Proposal]:
    """A part's primitive turned about its centre (about x or z)."""
    out = []
    for path, node in parts(tree):
        child = get(node, (0,))
        if child.get("node") in ("rotate", "sphere"):   # turned already, or round
            continue
        for name, (tilt, azimuth) in AXES.items():
            rot = {"node": "rotate", "params": {"angle": 0.0, "tilt": tilt, "azimuth": azimuth}, "children": [child]}
            out.append(Proposal(f"turn {node['name']} about {name}", replaced(tree, (*path, 0), rot)))
    return out
