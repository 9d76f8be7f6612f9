"""Operations written once for 2D and 3D (fogleman/sdf ``dn.py`` style).

Combinations (CSG) take their children's dimension. Hard booleans are min/max; smooth ones use
Quilez's polynomial smooth minimum ("Smooth minimum", iquilezles.org/articles/smin) with blend radius
``k``. Unions are exact outside and a bound inside; intersections and subtractions are bounds.

Translate, scale, round and shell are defined once and registered for 3D (``translate``) and 2D
(``translate2d``) from one function (Quilez, "Distance functions": opTx, opScale, opRound, opOnion).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np
import torch

from ipm.sdf import _boxes
from ipm.sdf.node import LEN, POS, Node, P, operation, register

BLEND = (1e-4, 10.0)


def smin(a: torch.Tensor, b: torch.Tensor, k: torch.Tensor) -> torch.Tensor:
    """Polynomial smooth minimum; equals min(a, b) where |a - b| >= k, and is at most k/4 below it."""
    h = torch.clamp(0.5 + 0.5 * (b - a) / k, 0.0, 1.0)
    return b + (a - b) * h - k * h * (1.0 - h)


def combination(type_name: str, fn: Callable, box: Callable, doc: str, *, smooth: bool = False,
                arity: int | None = 2) -> type[Node]:
    """Register a CSG node type: ``fn(distances, *values) -> (...)`` over the children's distances
    (a list of ``(...)`` tensors, evaluated in order), ``box(child_boxes, *values)`` its bounds."""
    return register(type(type_name.title().replace("_", ""), (Node,), {
        "__doc__": doc, "__module__": __name__, "__qualname__": type_name,
        "type_name": type_name, "dim": 0, "arity": arity, "exact": False,
        "params": (P("k", 0.1, *BLEND),) if smooth else (),
        "eval": lambda self, p, th, kids: fn([k(p) for k in kids], *th),
        "bbox": lambda self, v, kids: box(kids, *v),
    }))


def _min_all(d):
    out = d[0]
    for x in d[1:]:
        out = torch.minimum(out, x)
    return out


def _first(boxes, *v):
    return boxes[0]


def _grown_union(boxes, k):
    return _boxes.grow(_boxes.union(boxes), k)


combination("union", lambda d: torch.minimum(d[0], d[1]), _boxes.union, "a ∪ b: min(a, b).")
combination("union_n", _min_all, _boxes.union, "n-ary union of two or more children: the minimum of all.",
            arity=None)
combination("intersection", lambda d: torch.maximum(d[0], d[1]), _boxes.intersection, "a ∩ b: max(a, b).")
combination("subtraction", lambda d: torch.maximum(d[0], -d[1]), _first, "a − b: max(a, −b).")
combination("smooth_union", lambda d, k: smin(d[0], d[1], k), _grown_union,
            "Smooth union with blend radius ``k`` (opSmoothUnion).", smooth=True)
combination("smooth_intersection", lambda d, k: -smin(-d[0], -d[1], k), lambda b, k: _boxes.intersection(b),
            "Smooth intersection with blend radius ``k``: −smin(−a, −b).", smooth=True)
combination("smooth_subtraction", lambda d, k: -smin(-d[0], d[1], k), _first,
            "Smooth subtraction a − b with blend radius ``k``: −smin(−a, b).", smooth=True)


@operation("translate", lambda dim: tuple(P(a, 0.0, *POS) for a in "xyz"[:dim]), dims=(3, 2),
           box=lambda b, *t: (b[0] + np.array(t), b[1] + np.array(t)))
def Translate(child, p, *t):
    """Move the child by ``(x, y, z)`` (2D: ``(x, y)``). Exact."""
    return child(p - torch.stack(t))


@operation("scale", P("factor", 1.0, 1e-3, 100.0), dims=(3, 2), box=lambda b, s: (b[0] * s, b[1] * s))
def Scale(child, p, s):
    """Uniform scale by ``factor``: ``f(p / s) * s``. Exact."""
    return child(p / s) * s


# a placement's range: any frame a target's file may use (it is held by fits: Param.held)
PLACE = 1e9


@operation("place", lambda dim: tuple(replace(P(a, 0.0, -PLACE, PLACE), held=True) for a in "xyz"[:dim])
           + (replace(P("unit", 1.0, 1.0 / PLACE, PLACE), held=True),), dims=(3, 2),
           box=lambda b, *v: (b[0] * v[-1] + np.array(v[:-1]), b[1] * v[-1] + np.array(v[:-1])))
def Place(child, p, *v):
    """Place a child made in a unit frame into a target's own frame: scaled by ``unit`` (the length of its unit
    there), then moved by ``(x, y, z)`` (2D: ``(x, y)``): ``f((p - t) / unit) * unit``. Exact. Its values are a
    frame, not a shape: fits hold them (ipm fit --structure search writes one around a tree fitted to a mesh)."""
    t, s = torch.stack(v[:-1]), v[-1]
    return child((p - t) / s) * s


@operation("round", P("radius", 0.05, 0.0, 10.0), dims=(3, 2), box=_boxes.grow)
def Round(child, p, r):
    """Inflate the child by ``radius`` (rounds its edges): ``f(p) - r`` (opRound). Exact outside."""
    return child(p) - r


@operation("shell", P("thickness", 0.05, *LEN), dims=(3, 2), box=lambda b, t: _boxes.grow(b, t / 2))
def Shell(child, p, t):
    """Hollow the child into a shell (2D: an outline) of ``thickness``: ``|f(p)| - t/2`` (opOnion). Exact."""
    return child(p).abs() - 0.5 * t
