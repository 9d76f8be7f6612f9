"""2D primitives (points ``(..., 2)``: x, y). Lift them to 3D with ``extrude`` or ``revolve``.
Formulas from Inigo Quilez, "2D distance functions" (iquilezles.org/articles/distfunctions2d).

Each primitive is one function ``(p (..., 2), *values) -> (...)`` registered by :func:`primitive`."""

from __future__ import annotations

import math

import torch

from ipm.sdf._boxes import points_box, sym
from ipm.sdf._math import box_combine, length2, polygon_sdf
from ipm.sdf.node import POS, P, Primitive, primitive, register


@primitive(2, "circle", P("radius", 0.5), box=lambda r: sym(r, r))
def Circle(p, r):
    """Circle of radius ``radius``. Exact (sdCircle)."""
    return length2(p[..., 0], p[..., 1]) - r


@primitive(2, "rect", P("size_x", 1.0), P("size_y", 1.0), box=lambda x, y: sym(x / 2, y / 2))
def Rect(p, sx, sy):
    """Axis-aligned rectangle with full sides ``size_x``, ``size_y`` (a square when equal). Exact (sdBox 2D)."""
    return box_combine(p[..., 0].abs() - 0.5 * sx, p[..., 1].abs() - 0.5 * sy)


@primitive(2, "round_rect", P("size_x", 1.0), P("size_y", 1.0), P("radius", 0.1, 0.0, 10.0),
           box=lambda x, y, r: sym(x / 2, y / 2))
def RoundRect(p, sx, sy, r):
    """Rectangle with corners rounded by ``radius`` (clamped to half the smaller side). Exact (sdRoundedBox)."""
    r = torch.minimum(r, 0.5 * torch.minimum(sx, sy))
    return box_combine(p[..., 0].abs() - 0.5 * sx + r, p[..., 1].abs() - 0.5 * sy + r) - r


@primitive(2, "triangle", P("x0", 0.0, *POS), P("y0", 0.5, *POS), P("x1", -0.5, *POS), P("y1", -0.4, *POS),
           P("x2", 0.5, *POS), P("y2", -0.4, *POS), box=lambda *v: points_box(v[0::2], v[1::2]))
def Triangle(p, x0, y0, x1, y1, x2, y2):
    """Triangle through three free points ``(x0, y0) .. (x2, y2)``, either orientation. Exact (sdTriangle
    via the general polygon distance)."""
    return polygon_sdf(p[..., 0], p[..., 1], [(x0, y0), (x1, y1), (x2, y2)])


@primitive(2, "ellipse", P("radius_x", 0.5), P("radius_y", 0.3), exact=False, box=sym)
def Ellipse(p, rx, ry):
    """Axis-aligned ellipse with semi-axes ``radius_x``, ``radius_y``. Approximate, not exact (the
    same gradient-normalized estimate as Quilez's sdEllipsoid, in 2D)."""
    x, y = p[..., 0], p[..., 1]
    k0 = length2(x / rx, y / ry)
    k1 = length2(x / (rx * rx), y / (ry * ry))
    near = k1 < 1e-9
    k1s = torch.where(near, torch.ones_like(k1), k1)
    return torch.where(near, -torch.minimum(rx, ry) + 0.0 * k0, k0 * (k0 - 1.0) / k1s)


@primitive(2, "wind_rose", *(P(f"r{i}", 0.5 if i % 2 == 0 else 0.25) for i in range(8)),
           box=lambda *r: sym(max(r), max(r)))
def WindRose(p, *radii):
    """The thesis's Polygon-8 ("wind rose"): a star-shaped octagon with radius ``r0 .. r7`` on the
    rays at 0°, 45°, ..., 315°. Exact (sdPolygon)."""
    verts = [(r * math.cos(i * math.pi / 4.0), r * math.sin(i * math.pi / 4.0)) for i, r in enumerate(radii)]
    return polygon_sdf(p[..., 0], p[..., 1], verts)


@register
class Polygon(Primitive):
    """Closed polygon through k points ``(x0, y0) .. (x{k-1}, y{k-1})`` (the thesis's "spline" node with
    straight segments). Any orientation; must not self-intersect. Exact (sdPolygon)."""

    type_name = "polygon"
    dim, exact = 2, True
    size_prefix, default_size, min_size = "x", 4, 3

    @classmethod
    def point_params(cls, i, k):
        """``x{i}``, ``y{i}``: defaults on a circle of radius 0.5 (a regular k-gon), counter-clockwise."""
        a = 2.0 * math.pi * i / k
        return P(f"x{i}", round(0.5 * math.cos(a), 6), *POS), P(f"y{i}", round(0.5 * math.sin(a), 6), *POS)

    def eval(self, p, th, kids):
        """Exact distance to the polygon (Quilez's sdPolygon), negative inside."""
        return polygon_sdf(p[..., 0], p[..., 1], list(zip(th[0::2], th[1::2])))

    def bbox(self, v, kids):
        """The box of the polygon's points."""
        return points_box(v[0::2], v[1::2])
