"""Lifts: a 2D child becomes a 3D solid (Quilez, "Distance functions": opExtrusion, opRevolution)."""

from __future__ import annotations

import numpy as np

from ipm.sdf._math import box_combine, length2, stack_coords
from ipm.sdf.node import LEN, P, operation


@operation("extrude", P("height", 0.5, *LEN), child_dim=2,
           box=lambda b, h: (np.array([b[0][0], b[0][1], -h / 2]), np.array([b[1][0], b[1][1], h / 2])))
def Extrude(child, p, h):
    """Extrude a 2D child (in the XY plane) along Z to a slab of full ``height``. Exact if the child is."""
    return box_combine(child(p[..., :2]), p[..., 2].abs() - 0.5 * h)


def _revolve_box(b, offset):
    R = max(abs(b[0][0]), abs(b[1][0])) + offset
    return np.array([-R, b[0][1], -R]), np.array([R, b[1][1], R])


@operation("revolve", P("offset", 0.0, 0.0, 20.0), child_dim=2, box=_revolve_box)
def Revolve(child, p, offset):
    """Revolve a 2D child about the Y axis: the child's x is the distance from the axis minus
    ``offset``, its y is height. Exact if the child is."""
    return child(stack_coords([length2(p[..., 0], p[..., 2]) - offset, p[..., 1]]))
