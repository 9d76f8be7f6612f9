"""Combinations (CSG), written once for 2D and 3D: a node takes its children's dimension.

Hard booleans are min/max; smooth ones use Quilez's polynomial smooth minimum ("Smooth minimum",
iquilezles.org/articles/smin) with blend radius ``k``. Unions are exact outside and a bound inside;
intersections and subtractions are bounds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ipm.sdf.d3 import P
from ipm.sdf.nodes import Node, register

BLEND = (1e-4, 10.0)


class Combine(Node):
    dim = 0  # same as the children
    arity = 2
    exact = False


def smin(a: torch.Tensor, b: torch.Tensor, k: torch.Tensor) -> torch.Tensor:
    """Polynomial smooth minimum; equals min(a, b) where |a - b| >= k, and is at most k/4 below it."""
    h = torch.clamp(0.5 + 0.5 * (b - a) / k, 0.0, 1.0)
    return b + (a - b) * h - k * h * (1.0 - h)


def box_union(boxes):
    return np.min([b[0] for b in boxes], 0), np.max([b[1] for b in boxes], 0)


def box_intersection(boxes):
    lo, hi = np.max([b[0] for b in boxes], 0), np.min([b[1] for b in boxes], 0)
    return lo, np.maximum(hi, lo)


@register
@dataclass(frozen=True, eq=False)
class Union(Combine):
    """a ∪ b: min(a, b)."""

    type_name = "union"

    def eval(self, p, th, kids):
        return torch.minimum(kids[0](p), kids[1](p))

    def bbox(self, v, kids):
        return box_union(kids)


@register
@dataclass(frozen=True, eq=False)
class UnionN(Combine):
    """n-ary union of two or more children: the minimum of all."""

    type_name = "union_n"
    arity = None

    def eval(self, p, th, kids):
        d = kids[0](p)
        for k in kids[1:]:
            d = torch.minimum(d, k(p))
        return d

    def bbox(self, v, kids):
        return box_union(kids)


@register
@dataclass(frozen=True, eq=False)
class Intersection(Combine):
    """a ∩ b: max(a, b)."""

    type_name = "intersection"

    def eval(self, p, th, kids):
        return torch.maximum(kids[0](p), kids[1](p))

    def bbox(self, v, kids):
        return box_intersection(kids)


@register
@dataclass(frozen=True, eq=False)
class Subtraction(Combine):
    """a − b: max(a, −b)."""

    type_name = "subtraction"

    def eval(self, p, th, kids):
        return torch.maximum(kids[0](p), -kids[1](p))

    def bbox(self, v, kids):
        return kids[0]


@register
@dataclass(frozen=True, eq=False)
class SmoothUnion(Combine):
    """Smooth union with blend radius ``k`` (opSmoothUnion)."""

    type_name = "smooth_union"
    params = (P("k", 0.1, *BLEND),)

    def eval(self, p, th, kids):
        return smin(kids[0](p), kids[1](p), th[0])

    def bbox(self, v, kids):
        lo, hi = box_union(kids)
        return lo - v[0], hi + v[0]


@register
@dataclass(frozen=True, eq=False)
class SmoothIntersection(Combine):
    """Smooth intersection with blend radius ``k``: −smin(−a, −b)."""

    type_name = "smooth_intersection"
    params = (P("k", 0.1, *BLEND),)

    def eval(self, p, th, kids):
        return -smin(-kids[0](p), -kids[1](p), th[0])

    def bbox(self, v, kids):
        return box_intersection(kids)


@register
@dataclass(frozen=True, eq=False)
class SmoothSubtraction(Combine):
    """Smooth subtraction a − b with blend radius ``k``: −smin(−a, b)."""

    type_name = "smooth_subtraction"
    params = (P("k", 0.1, *BLEND),)

    def eval(self, p, th, kids):
        return -smin(-kids[0](p), kids[1](p), th[0])

    def bbox(self, v, kids):
        return kids[0]
