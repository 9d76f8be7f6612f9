"""3D primitives. Formulas from Inigo Quilez, "Distance functions" (iquilezles.org/articles/distfunctions),
unless stated otherwise. All are centered at the origin, Y up; sizes are full extents.

Each primitive is one function ``(p (..., 3), *values) -> (...)`` registered by :func:`primitive`."""

from __future__ import annotations

import numpy as np
import torch

from ipm.sdf._boxes import sym
from ipm.sdf._math import axis_from_tilt, box_combine, length2, length3, polygon_sdf, relu, safe_sqrt
from ipm.sdf.node import POS, P, Primitive, primitive, register

SIN60 = 0.8660254037844386


@primitive(3, "sphere", P("radius", 0.5), box=lambda r: sym(r, r, r))
def Sphere(p, r):
    """Sphere of radius ``radius``. Exact (sdSphere)."""
    return length3(p[..., 0], p[..., 1], p[..., 2]) - r


@primitive(3, "box", P("size_x", 1.0), P("size_y", 1.0), P("size_z", 1.0), box=lambda x, y, z: sym(x / 2, y / 2, z / 2))
def Box(p, sx, sy, sz):
    """Axis-aligned box with full edge lengths ``size_x/y/z``. Exact (sdBox)."""
    q = p.abs()
    return box_combine(q[..., 0] - 0.5 * sx, q[..., 1] - 0.5 * sy, q[..., 2] - 0.5 * sz)


@primitive(3, "round_box", P("size_x", 1.0), P("size_y", 1.0), P("size_z", 1.0), P("radius", 0.1, 0.0, 10.0),
           box=lambda x, y, z, r: sym(x / 2, y / 2, z / 2))
def RoundBox(p, sx, sy, sz, r):
    """Box with rounded edges of radius ``radius`` (clamped to half the smallest side). Exact (sdRoundBox)."""
    r = torch.minimum(r, 0.5 * torch.minimum(sx, torch.minimum(sy, sz)))
    q = p.abs()
    return box_combine(q[..., 0] - 0.5 * sx + r, q[..., 1] - 0.5 * sy + r, q[..., 2] - 0.5 * sz + r) - r


@primitive(3, "cylinder", P("radius", 0.5), P("height", 1.0), box=lambda r, h: sym(r, h / 2, r))
def Cylinder(p, r, h):
    """Capped cylinder along Y: ``radius``, full ``height``. Exact (sdCappedCylinder)."""
    return box_combine(length2(p[..., 0], p[..., 2]) - r, p[..., 1].abs() - 0.5 * h)


@primitive(3, "cone", P("radius_bottom", 0.5), P("radius_top", 0.0, 0.0, 20.0), P("height", 1.0),
           box=lambda r1, r2, h: sym(max(r1, r2), h / 2, max(r1, r2)))
def Cone(p, r1, r2, height):
    """Capped cone along Y: bottom radius ``radius_bottom`` at y = -h/2, top ``radius_top`` at +h/2.

    Exact (sdCappedCone). A zero top radius gives a pointed cone.
    """
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


@primitive(3, "tri_prism", P("radius", 0.5), P("length", 1.0),
           box=lambda r, ln: (np.array([-r, -r / 2, -ln / 2]), np.array([r, r, ln / 2])))
def TriPrism(p, r, ln):
    """Prism along Z over an equilateral triangle of circumradius ``radius`` (apex towards +Y),
    full length ``length``. Exact: the extrusion (opExtrusion) of the exact 2D triangle distance."""
    verts = [(0.0 * r, r), (-SIN60 * r, -0.5 * r), (SIN60 * r, -0.5 * r)]
    d2 = polygon_sdf(p[..., 0], p[..., 1], verts)
    return box_combine(d2, p[..., 2].abs() - 0.5 * ln)


@primitive(3, "hex_prism", P("radius", 0.5), P("height", 1.0), box=lambda r, h: sym(r / SIN60, h / 2, r / SIN60))
def HexPrism(p, r, h):
    """Hexagonal prism along Y: inradius ``radius`` (center to flat side) in XZ, full ``height``.
    Exact (sdHexPrism)."""
    kx, ky, kz = -SIN60, 0.5, 0.5773502691896258
    x, y, z = p[..., 0].abs(), p[..., 2].abs(), p[..., 1].abs()  # hexagon in (x, z); axis y
    dot = torch.clamp(kx * x + ky * y, max=0.0)
    x = x - 2.0 * dot * kx
    y = y - 2.0 * dot * ky
    cx = torch.clamp(x, -kz * r, kz * r)
    dx = length2(x - cx, y - r) * torch.sign(y - r)
    return box_combine(dx, z - 0.5 * h)


@primitive(3, "torus", P("major", 0.5), P("minor", 0.15), box=lambda R, r: sym(R + r, r, R + r))
def Torus(p, R, r):
    """Torus in the XZ plane: ``major`` radius of the ring, ``minor`` radius of the tube. Exact (sdTorus)."""
    return length2(length2(p[..., 0], p[..., 2]) - R, p[..., 1]) - r


@primitive(3, "capsule", P("radius", 0.25), P("height", 1.0, 0.0, 20.0), box=lambda r, h: sym(r, h / 2 + r, r))
def Capsule(p, r, h):
    """Vertical capsule: a segment of length ``height`` along Y swept by ``radius``. Exact (sdVerticalCapsule)."""
    y = p[..., 1] - torch.clamp(p[..., 1], -0.5 * h, 0.5 * h)
    return length3(p[..., 0], y, p[..., 2]) - r


@primitive(3, "ellipsoid", P("radius_x", 0.5), P("radius_y", 0.3), P("radius_z", 0.4), exact=False, box=sym)
def Ellipsoid(p, rx, ry, rz):
    """Ellipsoid with semi-axes ``radius_x/y/z``. Approximate, not exact (Quilez's sdEllipsoid
    "improved" estimate: exact on the surface, close to the distance near it)."""
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    k0 = length3(x / rx, y / ry, z / rz)
    k1 = length3(x / (rx * rx), y / (ry * ry), z / (rz * rz))
    near = k1 < 1e-9
    k1s = torch.where(near, torch.ones_like(k1), k1)
    rmin = torch.minimum(rx, torch.minimum(ry, rz))
    return torch.where(near, -rmin + 0.0 * k0, k0 * (k0 - 1.0) / k1s)


@primitive(3, "plane", P("tilt", 0.0, -180.0, 180.0), P("azimuth", 0.0, -180.0, 180.0), P("offset", 0.0, *POS),
           box=lambda *v: sym(20.0, 20.0, 20.0))
def Plane(p, tilt, az, off):
    """Half-space below a plane: unit normal from (``tilt``, ``azimuth``) in degrees (+Y tilted
    towards the azimuth direction), ``offset`` along the normal. Exact (sdPlane).
    Its box is the cube of side 40 (the parameter range): intersect it with something finite."""
    nx, ny, nz = axis_from_tilt(tilt, az)
    return p[..., 0] * nx + p[..., 1] * ny + p[..., 2] * nz - off


@primitive(3, "octahedron", P("radius", 0.5), box=lambda r: sym(r, r, r))
def Octahedron(p, s):
    """Regular octahedron with vertices at distance ``radius`` on the axes. Exact (sdOctahedron)."""
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


@primitive(3, "pyramid", P("base", 1.0), P("height", 1.0),
           box=lambda b, h: (np.array([-b / 2, 0.0, -b / 2]), np.array([b / 2, h, b / 2])))
def Pyramid(p, b, height):
    """Square pyramid: base of side ``base`` on y = 0, apex at y = ``height``. Exact (sdPyramid,
    scaled uniformly by the base size, which keeps it exact)."""
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


@register
class Revolution(Primitive):
    """Body of revolution about Y (the thesis's revolution node): radii ``r0 .. r{k-1}`` at k evenly
    spaced heights from y = 0 to y = ``height``, joined by straight segments and closed by the
    axis. Exact: the 2D polygon distance (sdPolygon) of the profile mirrored across the axis,
    evaluated at (|p.xz|, p.y)."""

    type_name = "revolution"
    dim, exact = 3, True
    params = (P("height", 1.0),)
    size_prefix, default_size, min_size = "r", 5, 2

    @classmethod
    def point_params(cls, i, k):
        """``r{i}``: radius at height ``i / (k - 1) * height``, default 0.4 (a cylinder)."""
        return (P(f"r{i}", 0.4, 0.0, 20.0),)

    def eval(self, p, th, kids):
        """sdPolygon of the profile and its mirror image at ``(|p.xz|, p.y)``."""
        h, *radii = th
        k = len(radii)
        ys = [h * (i / (k - 1)) for i in range(k)]
        right = [(r, y) for r, y in zip(radii, ys)]
        left = [(-r, y) for r, y in zip(reversed(radii), reversed(ys))]
        return polygon_sdf(length2(p[..., 0], p[..., 2]), p[..., 1], right + left)

    def bbox(self, v, kids):
        """``[-r, 0, -r] .. [r, height, r]`` with ``r`` the largest radius."""
        r = max(v[1:])
        return np.array([-r, 0.0, -r]), np.array([r, v[0], r])
