"""3D primitives. Formulas from Inigo Quilez, "Distance functions" (iquilezles.org/articles/distfunctions),
unless stated otherwise. All are centered at the origin, Y up; sizes are full extents."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ipm.params import Param
from ipm.sdf._math import axis_from_tilt, box_combine, length2, length3, polygon_sdf, relu, safe_sqrt
from ipm.sdf.nodes import Node, register

LEN = (1e-3, 20.0)
POS = (-20.0, 20.0)


def P(name: str, default: float, lo: float = LEN[0], hi: float = LEN[1], doc: str = "") -> Param:
    return Param(name, default, lo, hi, "float", doc)


def sym_box(hx, hy, hz):
    return np.array([-hx, -hy, -hz]), np.array([hx, hy, hz])


class Primitive3D(Node):
    dim = 3
    arity = 0


@register
@dataclass(frozen=True, eq=False)
class Sphere(Primitive3D):
    """Sphere of radius ``radius``. Exact (sdSphere)."""

    type_name = "sphere"
    exact = True
    params = (P("radius", 0.5),)

    def eval(self, p, th, kids):
        (r,) = th
        return length3(p[..., 0], p[..., 1], p[..., 2]) - r

    def bbox(self, v, kids):
        return sym_box(v[0], v[0], v[0])


@register
@dataclass(frozen=True, eq=False)
class Box(Primitive3D):
    """Axis-aligned box with full edge lengths ``size_x/y/z``. Exact (sdBox)."""

    type_name = "box"
    exact = True
    params = (P("size_x", 1.0), P("size_y", 1.0), P("size_z", 1.0))

    def eval(self, p, th, kids):
        sx, sy, sz = th
        q = p.abs()
        return box_combine(q[..., 0] - 0.5 * sx, q[..., 1] - 0.5 * sy, q[..., 2] - 0.5 * sz)

    def bbox(self, v, kids):
        return sym_box(v[0] / 2, v[1] / 2, v[2] / 2)


@register
@dataclass(frozen=True, eq=False)
class RoundBox(Primitive3D):
    """Box with rounded edges of radius ``radius`` (clamped to half the smallest side). Exact (sdRoundBox)."""

    type_name = "round_box"
    exact = True
    params = (P("size_x", 1.0), P("size_y", 1.0), P("size_z", 1.0), P("radius", 0.1, 0.0, 10.0))

    def eval(self, p, th, kids):
        sx, sy, sz, r = th
        r = torch.minimum(r, 0.5 * torch.minimum(sx, torch.minimum(sy, sz)))
        q = p.abs()
        return box_combine(q[..., 0] - 0.5 * sx + r, q[..., 1] - 0.5 * sy + r, q[..., 2] - 0.5 * sz + r) - r

    def bbox(self, v, kids):
        return sym_box(v[0] / 2, v[1] / 2, v[2] / 2)


@register
@dataclass(frozen=True, eq=False)
class Cylinder(Primitive3D):
    """Capped cylinder along Y: ``radius``, full ``height``. Exact (sdCappedCylinder)."""

    type_name = "cylinder"
    exact = True
    params = (P("radius", 0.5), P("height", 1.0))

    def eval(self, p, th, kids):
        r, h = th
        rad = length2(p[..., 0], p[..., 2])
        return box_combine(rad - r, p[..., 1].abs() - 0.5 * h)

    def bbox(self, v, kids):
        return sym_box(v[0], v[1] / 2, v[0])


@register
@dataclass(frozen=True, eq=False)
class Cone(Primitive3D):
    """Capped cone along Y: bottom radius ``radius_bottom`` at y = -h/2, top ``radius_top`` at +h/2.

    Exact (sdCappedCone). A zero top radius gives a pointed cone.
    """

    type_name = "cone"
    exact = True
    params = (P("radius_bottom", 0.5), P("radius_top", 0.0, 0.0, 20.0), P("height", 1.0))

    def eval(self, p, th, kids):
        r1, r2, height = th
        h = 0.5 * height
        qx = length2(p[..., 0], p[..., 2])
        qy = p[..., 1]
        k2x, k2y = r2 - r1, 2.0 * h
        cax = qx - torch.minimum(qx, torch.where(qy < 0.0, r1, r2))
        cay = qy.abs() - h
        k2k2 = torch.clamp(k2x * k2x + k2y * k2y, min=1e-24)
        t = torch.clamp(((r2 - qx) * k2x + (h - qy) * k2y) / k2k2, 0.0, 1.0)
        cbx = qx - r2 + k2x * t
        cby = qy - h + k2y * t
        s = torch.where((cbx < 0.0) & (cay < 0.0), -1.0, 1.0).to(p.dtype)
        return s * safe_sqrt(torch.minimum(cax * cax + cay * cay, cbx * cbx + cby * cby))

    def bbox(self, v, kids):
        r = max(v[0], v[1])
        return sym_box(r, v[2] / 2, r)


@register
@dataclass(frozen=True, eq=False)
class TriPrism(Primitive3D):
    """Prism along Z over an equilateral triangle of circumradius ``radius`` (apex towards +Y),
    full length ``length``. Exact: the extrusion (opExtrusion) of the exact 2D triangle distance."""

    type_name = "tri_prism"
    exact = True
    params = (P("radius", 0.5), P("length", 1.0))

    def eval(self, p, th, kids):
        r, ln = th
        c, s = 0.8660254037844386, 0.5
        verts = [(0.0 * r, r), (-c * r, -s * r), (c * r, -s * r)]
        d2 = polygon_sdf(p[..., 0], p[..., 1], verts)
        return box_combine(d2, p[..., 2].abs() - 0.5 * ln)

    def bbox(self, v, kids):
        return np.array([-v[0], -v[0] / 2, -v[1] / 2]), np.array([v[0], v[0], v[1] / 2])


@register
@dataclass(frozen=True, eq=False)
class HexPrism(Primitive3D):
    """Hexagonal prism along Y: inradius ``radius`` (center to flat side) in XZ, full ``height``.
    Exact (sdHexPrism)."""

    type_name = "hex_prism"
    exact = True
    params = (P("radius", 0.5), P("height", 1.0))

    def eval(self, p, th, kids):
        r, h = th
        kx, ky, kz = -0.8660254037844386, 0.5, 0.5773502691896258
        x, y, z = p[..., 0].abs(), p[..., 2].abs(), p[..., 1].abs()  # hexagon in (x, z); axis y
        dot = torch.clamp(kx * x + ky * y, max=0.0)
        x = x - 2.0 * dot * kx
        y = y - 2.0 * dot * ky
        cx = torch.clamp(x, -kz * r, kz * r)
        dx = length2(x - cx, y - r) * torch.sign(y - r)
        return box_combine(dx, z - 0.5 * h)

    def bbox(self, v, kids):
        R = v[0] / 0.8660254037844386
        return sym_box(R, v[1] / 2, R)


@register
@dataclass(frozen=True, eq=False)
class Torus(Primitive3D):
    """Torus in the XZ plane: ``major`` radius of the ring, ``minor`` radius of the tube. Exact (sdTorus)."""

    type_name = "torus"
    exact = True
    params = (P("major", 0.5), P("minor", 0.15))

    def eval(self, p, th, kids):
        R, r = th
        return length2(length2(p[..., 0], p[..., 2]) - R, p[..., 1]) - r

    def bbox(self, v, kids):
        return sym_box(v[0] + v[1], v[1], v[0] + v[1])


@register
@dataclass(frozen=True, eq=False)
class Capsule(Primitive3D):
    """Vertical capsule: a segment of length ``height`` along Y swept by ``radius``. Exact (sdVerticalCapsule)."""

    type_name = "capsule"
    exact = True
    params = (P("radius", 0.25), P("height", 1.0, 0.0, 20.0))

    def eval(self, p, th, kids):
        r, h = th
        y = p[..., 1] - torch.clamp(p[..., 1], -0.5 * h, 0.5 * h)
        return length3(p[..., 0], y, p[..., 2]) - r

    def bbox(self, v, kids):
        return sym_box(v[0], v[1] / 2 + v[0], v[0])


@register
@dataclass(frozen=True, eq=False)
class Ellipsoid(Primitive3D):
    """Ellipsoid with semi-axes ``radius_x/y/z``. Approximate, not exact (Quilez's sdEllipsoid
    "improved" estimate: exact on the surface, close to the distance near it)."""

    type_name = "ellipsoid"
    exact = False
    params = (P("radius_x", 0.5), P("radius_y", 0.3), P("radius_z", 0.4))

    def eval(self, p, th, kids):
        rx, ry, rz = th
        x, y, z = p[..., 0], p[..., 1], p[..., 2]
        k0 = length3(x / rx, y / ry, z / rz)
        k1 = length3(x / (rx * rx), y / (ry * ry), z / (rz * rz))
        near = k1 < 1e-9
        k1s = torch.where(near, torch.ones_like(k1), k1)
        rmin = torch.minimum(rx, torch.minimum(ry, rz))
        return torch.where(near, -rmin + 0.0 * k0, k0 * (k0 - 1.0) / k1s)

    def bbox(self, v, kids):
        return sym_box(v[0], v[1], v[2])


@register
@dataclass(frozen=True, eq=False)
class Plane(Primitive3D):
    """Half-space below a plane: unit normal from (``tilt``, ``azimuth``) in degrees (+Y tilted
    towards the azimuth direction), ``offset`` along the normal. Exact (sdPlane).
    Its box is the cube of side 40 (the parameter range): intersect it with something finite."""

    type_name = "plane"
    exact = True
    params = (P("tilt", 0.0, -180.0, 180.0), P("azimuth", 0.0, -180.0, 180.0), P("offset", 0.0, *POS))

    def eval(self, p, th, kids):
        tilt, az, off = th
        nx, ny, nz = axis_from_tilt(tilt, az)
        return p[..., 0] * nx + p[..., 1] * ny + p[..., 2] * nz - off

    def bbox(self, v, kids):
        return sym_box(20.0, 20.0, 20.0)


@register
@dataclass(frozen=True, eq=False)
class Octahedron(Primitive3D):
    """Regular octahedron with vertices at distance ``radius`` on the axes. Exact (sdOctahedron)."""

    type_name = "octahedron"
    exact = True
    params = (P("radius", 0.5),)

    def eval(self, p, th, kids):
        (s,) = th
        a = p.abs()
        x, y, z = a[..., 0], a[..., 1], a[..., 2]
        m = x + y + z - s
        cx, cy, cz = 3.0 * x < m, 3.0 * y < m, 3.0 * z < m
        # q = p.xyz, p.yzx or p.zxy depending on which face region the point is in
        qx = torch.where(cx, x, torch.where(cy, y, z))
        qy = torch.where(cx, y, torch.where(cy, z, x))
        qz = torch.where(cx, z, torch.where(cy, x, y))
        k = torch.clamp(0.5 * (qz - qy + s), min=torch.zeros_like(s), max=s)
        corner = length3(qx, qy - s + k, qz - k)
        return torch.where(cx | cy | cz, corner, m * 0.57735026918962573)

    def bbox(self, v, kids):
        return sym_box(v[0], v[0], v[0])


@register
@dataclass(frozen=True, eq=False)
class Pyramid(Primitive3D):
    """Square pyramid: base of side ``base`` on y = 0, apex at y = ``height``. Exact (sdPyramid,
    scaled uniformly by the base size, which keeps it exact)."""

    type_name = "pyramid"
    exact = True
    params = (P("base", 1.0), P("height", 1.0))

    def eval(self, p, th, kids):
        b, height = th
        h = height / b
        q3 = p / b
        m2 = h * h + 0.25
        ax, az = q3[..., 0].abs(), q3[..., 2].abs()
        px = torch.maximum(ax, az) - 0.5
        pz = torch.minimum(ax, az) - 0.5
        py = q3[..., 1]
        qx = pz
        qy = h * py - 0.5 * px
        qz = h * px + 0.5 * py
        s = relu(-qx)
        t = torch.clamp((qy - 0.5 * pz) / (m2 + 0.25), 0.0, 1.0)
        qs, qt, qm = qx + s, qx + 0.5 * t, qy - m2 * t
        a = m2 * qs * qs + qy * qy
        bb = m2 * qt * qt + qm * qm
        d2 = torch.where(torch.minimum(qy, -qx * m2 - qy * 0.5) > 0.0, torch.zeros_like(a), torch.minimum(a, bb))
        sign = torch.sign(torch.maximum(qz, -py))
        return safe_sqrt((d2 + qz * qz) / m2) * sign * b

    def bbox(self, v, kids):
        return np.array([-v[0] / 2, 0.0, -v[0] / 2]), np.array([v[0] / 2, v[1], v[0] / 2])


@register
@dataclass(frozen=True, eq=False)
class Revolution(Primitive3D):
    """Body of revolution about Y (the thesis's revolution node): radii ``r0 .. r{k-1}`` at k evenly
    spaced heights from y = 0 to y = ``height``, joined by straight segments and closed by the
    axis. Exact: the 2D polygon distance (sdPolygon) of the profile mirrored across the axis,
    evaluated at (|p.xz|, p.y)."""

    type_name = "revolution"
    exact = True
    sized = True
    default_size = 5
    min_size = 2

    @classmethod
    def param_defs_for(cls, size):
        k = cls.default_size if size is None else size
        return (P("height", 1.0),) + tuple(P(f"r{i}", 0.4, 0.0, 20.0) for i in range(k))

    @classmethod
    def size_from_names(cls, names):
        return sum(1 for n in names if n.startswith("r") and n[1:].isdigit()) or None

    def eval(self, p, th, kids):
        h, *radii = th
        k = len(radii)
        ys = [h * (i / (k - 1)) for i in range(k)]
        right = [(r, y) for r, y in zip(radii, ys)]
        left = [(-r, y) for r, y in zip(reversed(radii), reversed(ys))]
        return polygon_sdf(length2(p[..., 0], p[..., 2]), p[..., 1], right + left)

    def bbox(self, v, kids):
        r = max(v[1:])
        return np.array([-r, 0.0, -r]), np.array([r, v[0], r])


__all__ = ["P", "Primitive3D", "sym_box", "POS", "LEN"]
