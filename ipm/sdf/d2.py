"""2D primitives (points ``(..., 2)``: x, y). Lift them to 3D with ``extrude`` or ``revolve``.
Formulas from Inigo Quilez, "2D distance functions" (iquilezles.org/articles/distfunctions2d)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from ipm.sdf._math import box_combine, length2, polygon_sdf
from ipm.sdf.d3 import POS, P
from ipm.sdf.nodes import Node, register


class Primitive2D(Node):
    dim = 2
    arity = 0


def sym2(hx, hy):
    return np.array([-hx, -hy]), np.array([hx, hy])


@register
@dataclass(frozen=True, eq=False)
class Circle(Primitive2D):
    """Circle of radius ``radius``. Exact (sdCircle)."""

    type_name = "circle"
    exact = True
    params = (P("radius", 0.5),)

    def eval(self, p, th, kids):
        (r,) = th
        return length2(p[..., 0], p[..., 1]) - r

    def bbox(self, v, kids):
        return sym2(v[0], v[0])


@register
@dataclass(frozen=True, eq=False)
class Rect(Primitive2D):
    """Axis-aligned rectangle with full sides ``size_x``, ``size_y`` (a square when equal). Exact (sdBox 2D)."""

    type_name = "rect"
    exact = True
    params = (P("size_x", 1.0), P("size_y", 1.0))

    def eval(self, p, th, kids):
        sx, sy = th
        return box_combine(p[..., 0].abs() - 0.5 * sx, p[..., 1].abs() - 0.5 * sy)

    def bbox(self, v, kids):
        return sym2(v[0] / 2, v[1] / 2)


@register
@dataclass(frozen=True, eq=False)
class RoundRect(Primitive2D):
    """Rectangle with corners rounded by ``radius`` (clamped to half the smaller side). Exact (sdRoundedBox)."""

    type_name = "round_rect"
    exact = True
    params = (P("size_x", 1.0), P("size_y", 1.0), P("radius", 0.1, 0.0, 10.0))

    def eval(self, p, th, kids):
        sx, sy, r = th
        r = torch.minimum(r, 0.5 * torch.minimum(sx, sy))
        return box_combine(p[..., 0].abs() - 0.5 * sx + r, p[..., 1].abs() - 0.5 * sy + r) - r

    def bbox(self, v, kids):
        return sym2(v[0] / 2, v[1] / 2)


@register
@dataclass(frozen=True, eq=False)
class Triangle(Primitive2D):
    """Triangle through three free points ``(x0, y0) .. (x2, y2)``, either orientation. Exact (sdTriangle
    via the general polygon distance)."""

    type_name = "triangle"
    exact = True
    params = (P("x0", 0.0, *POS), P("y0", 0.5, *POS), P("x1", -0.5, *POS), P("y1", -0.4, *POS),
              P("x2", 0.5, *POS), P("y2", -0.4, *POS))

    def eval(self, p, th, kids):
        x0, y0, x1, y1, x2, y2 = th
        return polygon_sdf(p[..., 0], p[..., 1], [(x0, y0), (x1, y1), (x2, y2)])

    def bbox(self, v, kids):
        xs, ys = v[0::2], v[1::2]
        return np.array([min(xs), min(ys)]), np.array([max(xs), max(ys)])


@register
@dataclass(frozen=True, eq=False)
class Ellipse(Primitive2D):
    """Axis-aligned ellipse with semi-axes ``radius_x``, ``radius_y``. Approximate, not exact (the
    same gradient-normalized estimate as Quilez's sdEllipsoid, in 2D)."""

    type_name = "ellipse"
    exact = False
    params = (P("radius_x", 0.5), P("radius_y", 0.3))

    def eval(self, p, th, kids):
        rx, ry = th
        x, y = p[..., 0], p[..., 1]
        k0 = length2(x / rx, y / ry)
        k1 = length2(x / (rx * rx), y / (ry * ry))
        near = k1 < 1e-9
        k1s = torch.where(near, torch.ones_like(k1), k1)
        return torch.where(near, -torch.minimum(rx, ry) + 0.0 * k0, k0 * (k0 - 1.0) / k1s)

    def bbox(self, v, kids):
        return sym2(v[0], v[1])


@register
@dataclass(frozen=True, eq=False)
class WindRose(Primitive2D):
    """The thesis's Polygon-8 ("wind rose"): a star-shaped octagon with radius ``r0 .. r7`` on the
    rays at 0°, 45°, ..., 315°. Exact (sdPolygon)."""

    type_name = "wind_rose"
    exact = True
    params = tuple(P(f"r{i}", 0.5 if i % 2 == 0 else 0.25) for i in range(8))

    def eval(self, p, th, kids):
        verts = []
        for i, r in enumerate(th):
            a = i * math.pi / 4.0
            verts.append((r * math.cos(a), r * math.sin(a)))
        return polygon_sdf(p[..., 0], p[..., 1], verts)

    def bbox(self, v, kids):
        r = max(v)
        return sym2(r, r)


@register
@dataclass(frozen=True, eq=False)
class Polygon(Primitive2D):
    """Closed polygon through k points ``(x0, y0) .. (x{k-1}, y{k-1})`` (the thesis's "spline" node with
    straight segments). Any orientation; must not self-intersect. Exact (sdPolygon)."""

    type_name = "polygon"
    exact = True
    sized = True
    default_size = 4
    min_size = 3

    @classmethod
    def param_defs_for(cls, size):
        k = cls.default_size if size is None else size
        out = []
        for i in range(k):
            a = 2.0 * math.pi * i / k
            out += [P(f"x{i}", round(0.5 * math.cos(a), 6), *POS), P(f"y{i}", round(0.5 * math.sin(a), 6), *POS)]
        return tuple(out)

    @classmethod
    def size_from_names(cls, names):
        return sum(1 for n in names if n.startswith("x") and n[1:].isdigit()) or None

    def eval(self, p, th, kids):
        verts = list(zip(th[0::2], th[1::2]))
        return polygon_sdf(p[..., 0], p[..., 1], verts)

    def bbox(self, v, kids):
        xs, ys = v[0::2], v[1::2]
        return np.array([min(xs), min(ys)]), np.array([max(xs), max(ys)])
