"""Lifts: a 2D child becomes a 3D solid (Quilez, "Distance functions": opExtrusion, opRevolution)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ipm.sdf._math import box_combine, length2, stack_coords
from ipm.sdf.d3 import LEN, P
from ipm.sdf.nodes import Node, register


class Lift(Node):
    dim = 3
    child_dim = 2
    arity = 1
    exact = True


@register
@dataclass(frozen=True, eq=False)
class Extrude(Lift):
    """Extrude a 2D child (in the XY plane) along Z to a slab of full ``height``. Exact if the child is."""

    type_name = "extrude"
    params = (P("height", 0.5, *LEN),)

    def eval(self, p, th, kids):
        d = kids[0](p[..., :2])
        return box_combine(d, p[..., 2].abs() - 0.5 * th[0])

    def bbox(self, v, kids):
        lo, hi = kids[0]
        return np.array([lo[0], lo[1], -v[0] / 2]), np.array([hi[0], hi[1], v[0] / 2])


@register
@dataclass(frozen=True, eq=False)
class Revolve(Lift):
    """Revolve a 2D child about the Y axis: the child's x is the distance from the axis minus
    ``offset``, its y is height. Exact if the child is."""

    type_name = "revolve"
    params = (P("offset", 0.0, 0.0, 20.0),)

    def eval(self, p, th, kids):
        r = length2(p[..., 0], p[..., 2]) - th[0]
        return kids[0](stack_coords([r, p[..., 1]]))

    def bbox(self, v, kids):
        lo, hi = kids[0]
        R = max(abs(lo[0]), abs(hi[0])) + v[0]
        return np.array([-R, lo[1], -R]), np.array([R, hi[1], R])
