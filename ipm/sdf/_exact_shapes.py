"""The manifold3d counterparts of SDF node types, for :mod:`ipm.sdf.exact`: one builder per type name.

A builder is ``fn(walk, node, values) -> Manifold | CrossSection``: ``values`` are the node's stored values in
declaration order, ``walk.shape(child)`` gives a child's counterpart (:class:`ipm.sdf.exact._Walk`) and
``walk.segments`` the pieces per full circle. Each follows the node's own convention (its docstring and
``eval`` in :mod:`ipm.sdf.nodes`): sizes are full extents, ipm's axis of revolution is Y while manifold's
cylinders and revolutions stand on Z (hence :data:`Z_TO_Y`), and a transform that evaluates its child at
``g(p)`` maps the child's solid by the inverse of ``g``. Every vertex a primitive makes lies on its zero set.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import torch

from ipm.sdf._math import axis_from_tilt, rotation_matrix

# (x, y, z) -> (x, z, -y): a rotation taking manifold's Z axis (cylinders, revolutions) to ipm's Y axis
Z_TO_Y = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, -1.0, 0.0, 0.0]])
SIN60 = math.sqrt(3.0) / 2.0
PLANE_CUBE = 40.0  # the side of a plane's bounding cube (its parameter range), where a plane is kept finite

BUILDERS: dict[str, Callable] = {}


class NoExact(Exception):  # noqa: N818 - a signal between the builders and the walk, not an error
    """A 2D node without a counterpart; its message is the node's label."""


def builds(*type_names: str) -> Callable:
    """Decorator: register a builder for these node type names."""

    def deco(fn: Callable) -> Callable:
        for name in type_names:
            BUILDERS[name] = fn
        return fn

    return deco


def _m3d():
    import manifold3d

    return manifold3d


def _affine(R: np.ndarray, t=(0.0, 0.0, 0.0)) -> np.ndarray:
    return np.hstack([np.asarray(R, dtype=np.float64), np.asarray(t, dtype=np.float64)[:, None]])


def _polygon(points) -> object:
    """A CrossSection of one closed polygon ``[(x, y), ...]`` in either orientation."""
    m3d = _m3d()
    return m3d.CrossSection([np.asarray(points, dtype=np.float64).reshape(-1, 2)], m3d.FillRule.NonZero)


# ---------------------------------------------------------------------------------------------------------------
# 3D primitives
# ---------------------------------------------------------------------------------------------------------------

@builds("sphere")
def _sphere(walk, node, v):
    """Geodesic sphere, its vertices on the sphere (manifold rounds its segments up to a multiple of 4)."""
    return _m3d().Manifold.sphere(v[0], walk.segments)


@builds("ellipsoid")
def _ellipsoid(walk, node, v):
    """A unit sphere scaled by the semi-axes: the zero set of the (approximate) SDF is that ellipsoid."""
    return _m3d().Manifold.sphere(1.0, walk.segments).scale(tuple(v))


@builds("box")
def _box(walk, node, v):
    """Full edge lengths, centered."""
    return _m3d().Manifold.cube(tuple(v), True)


@builds("round_box")
def _round_box(walk, node, v):
    """The hull of eight corner spheres of the (clamped) radius."""
    m3d = _m3d()
    sizes = np.array(v[:3])
    r = min(v[3], 0.5 * float(sizes.min()))
    if r <= 1e-9 * float(sizes.max()):
        return m3d.Manifold.cube(tuple(sizes), True)
    ball = m3d.Manifold.sphere(r, walk.segments)
    half = 0.5 * sizes - r
    return m3d.Manifold.batch_hull([ball.translate(tuple(half * s)) for s in _signs(3)])


def _signs(d: int) -> np.ndarray:
    return np.array(np.meshgrid(*([[-1.0, 1.0]] * d), indexing="ij")).reshape(d, -1).T


@builds("cylinder")
def _cylinder(walk, node, v):
    """Along Y, full height, centered."""
    r, h = v
    return _m3d().Manifold.cylinder(h, r, r, walk.segments, True).transform(Z_TO_Y)


@builds("cone")
def _cone(walk, node, v):
    """Along Y: ``radius_bottom`` at y = -h/2, ``radius_top`` at +h/2 (zero: a point)."""
    r1, r2, h = v
    return _m3d().Manifold.cylinder(h, r1, r2, walk.segments, True).transform(Z_TO_Y)


@builds("capsule")
def _capsule(walk, node, v):
    """The hull of the two end spheres (their equators are circles of vertices)."""
    m3d = _m3d()
    r, h = v
    ball = m3d.Manifold.sphere(r, walk.segments)
    return m3d.Manifold.batch_hull([ball.translate((0.0, -0.5 * h, 0.0)), ball.translate((0.0, 0.5 * h, 0.0))])


@builds("torus")
def _torus(walk, node, v):
    """A circle of the minor radius at the major radius, revolved about Y."""
    m3d = _m3d()
    R, r = v
    section = m3d.CrossSection.circle(r, walk.segments).translate((R, 0.0))
    return m3d.Manifold.revolve(section, walk.segments).transform(Z_TO_Y)


@builds("hex_prism")
def _hex_prism(walk, node, v):
    """Inradius ``radius`` in XZ (corners on the X axis), along Y."""
    r, h = v
    R = r / SIN60
    hexagon = _polygon([(R * math.cos(k * math.pi / 3), R * math.sin(k * math.pi / 3)) for k in range(6)])
    return _m3d().Manifold.extrude(hexagon, h).translate((0.0, 0.0, -0.5 * h)).transform(Z_TO_Y)


@builds("tri_prism")
def _tri_prism(walk, node, v):
    """Circumradius ``radius``, apex towards +Y, along Z."""
    r, ln = v
    tri = _polygon([(0.0, r), (-SIN60 * r, -0.5 * r), (SIN60 * r, -0.5 * r)])
    return _m3d().Manifold.extrude(tri, ln).translate((0.0, 0.0, -0.5 * ln))


@builds("pyramid")
def _pyramid(walk, node, v):
    """Square base of side ``base`` on y = 0, apex at y = ``height``."""
    b, h = v
    pts = [(x * b / 2, 0.0, z * b / 2) for x, z in _signs(2)] + [(0.0, h, 0.0)]
    return _m3d().Manifold.hull_points(np.array(pts))


@builds("octahedron")
def _octahedron(walk, node, v):
    """Vertices at distance ``radius`` on the axes."""
    return _m3d().Manifold.hull_points(np.vstack([np.eye(3), -np.eye(3)]) * v[0])


@builds("revolution")
def _revolution(walk, node, v):
    """The profile (radii at even heights from 0 to ``height``) and its mirror image, revolved about Y."""
    h, *radii = v
    k = len(radii)
    right = [(r, h * i / (k - 1)) for i, r in enumerate(radii)]
    left = [(-x, y) for x, y in reversed(right)]
    return _m3d().Manifold.revolve(_polygon(right + left), walk.segments).transform(Z_TO_Y)


@builds("plane")
def _plane(walk, node, v):
    """The half-space below the plane, kept to the cube of side :data:`PLANE_CUBE` (its bounds)."""
    n, off = half_space(node)
    return _m3d().Manifold.cube((PLANE_CUBE,) * 3, True).trim_by_plane(tuple(-n), -off)


def half_space(node) -> tuple[np.ndarray, float]:
    """``(unit normal (3,), offset)`` of a ``plane`` node: its solid is ``n . p <= offset``."""
    tilt, az, off = (float(x) for x in node.values)
    n = np.array([float(c) for c in axis_from_tilt(torch.tensor(tilt, dtype=torch.float64),
                                                   torch.tensor(az, dtype=torch.float64))])
    return n, off


# ---------------------------------------------------------------------------------------------------------------
# 2D primitives (CrossSection in the XY plane)
# ---------------------------------------------------------------------------------------------------------------

@builds("circle")
def _circle(walk, node, v):
    """A regular polygon on the circle."""
    return _m3d().CrossSection.circle(v[0], walk.segments)


@builds("ellipse")
def _ellipse(walk, node, v):
    """A unit circle scaled by the semi-axes (the SDF's zero set is that ellipse)."""
    return _m3d().CrossSection.circle(1.0, walk.segments).scale(tuple(v))


@builds("rect")
def _rect(walk, node, v):
    """Full sides, centered."""
    return _m3d().CrossSection.square(tuple(v), True)


@builds("round_rect")
def _round_rect(walk, node, v):
    """The hull of four corner circles of the (clamped) radius."""
    m3d = _m3d()
    sx, sy, r = v
    r = min(r, 0.5 * min(sx, sy))
    if r <= 1e-9 * max(sx, sy):
        return m3d.CrossSection.square((sx, sy), True)
    disc = m3d.CrossSection.circle(r, walk.segments)
    half = np.array([0.5 * sx - r, 0.5 * sy - r])
    return m3d.CrossSection.batch_hull([disc.translate(tuple(half * s)) for s in _signs(2)])


@builds("triangle", "polygon")
def _points_polygon(walk, node, v):
    """The polygon through the points ``(x0, y0), (x1, y1), ...``."""
    return _polygon(list(zip(v[0::2], v[1::2])))


@builds("wind_rose")
def _wind_rose(walk, node, v):
    """Radius ``r_i`` on the ray at ``45 i`` degrees."""
    return _polygon([(r * math.cos(i * math.pi / 4), r * math.sin(i * math.pi / 4)) for i, r in enumerate(v)])


# ---------------------------------------------------------------------------------------------------------------
# Lifts, transforms, booleans
# ---------------------------------------------------------------------------------------------------------------

@builds("extrude")
def _extrude(walk, node, v):
    """The 2D child along Z, full height, centered."""
    h = v[0]
    return _m3d().Manifold.extrude(walk.shape(node.children[0]), h).translate((0.0, 0.0, -0.5 * h))


@builds("revolve")
def _revolve(walk, node, v):
    """The 2D child moved out by ``offset`` (its x is the distance from the axis), its part at x >= 0 revolved
    about Y (its y is the height)."""
    section = walk.shape(node.children[0]).translate((v[0], 0.0))
    return _m3d().Manifold.revolve(section, walk.segments).transform(Z_TO_Y)


@builds("translate", "translate2d")
def _translate(walk, node, v):
    """Moved by the offsets."""
    return walk.shape(node.children[0]).translate(tuple(v))


@builds("scale", "scale2d")
def _scale(walk, node, v):
    """Scaled uniformly about the origin."""
    return walk.shape(node.children[0]).scale((v[0],) * node.out_dim)


@builds("scale3")
def _scale3(walk, node, v):
    """Scaled per axis: the zero set of ``f(p / s) * min(s)`` is the scaled solid."""
    return walk.shape(node.children[0]).scale(tuple(v))


@builds("place", "place2d")
def _place(walk, node, v):
    """Scaled by ``unit``, then moved: ``f((p - t) / unit) * unit``."""
    *t, unit = v
    return walk.shape(node.children[0]).scale((unit,) * node.out_dim).translate(tuple(t))


@builds("rotate")
def _rotate(walk, node, v):
    """The SDF evaluates its child at ``R^T p``, so the solid is turned by ``R``."""
    angle, tilt, az = (torch.tensor(float(x), dtype=torch.float64) for x in v)
    R = rotation_matrix(axis_from_tilt(tilt, az), angle).numpy()
    return walk.shape(node.children[0]).transform(_affine(R))


@builds("rotate2d")
def _rotate2d(walk, node, v):
    """Turned counter-clockwise by ``angle`` degrees."""
    return walk.shape(node.children[0]).rotate(v[0])


@builds("mirror")
def _mirror(walk, node, v):
    """The child's part at coordinate ``axis >= offset`` and its reflection across that plane."""
    axis, off = int(v[0]), float(v[1])
    n = np.zeros(3)
    n[axis] = 1.0
    kept = walk.shape(node.children[0]).trim_by_plane(tuple(n), off)
    flip = np.eye(3)
    flip[axis, axis] = -1.0
    return kept + kept.transform(_affine(flip, 2.0 * off * n))


@builds("repeat")
def _repeat(walk, node, v):
    """The union of ``count`` copies spaced along ``axis``, centered (the SDF's zero set when the child fits
    inside its cell)."""
    m3d = _m3d()
    axis, count, spacing = int(v[0]), int(v[1]), float(v[2])
    child = walk.shape(node.children[0])
    copies = []
    for i in range(count):
        t = np.zeros(3)
        t[axis] = (i - 0.5 * (count - 1)) * spacing
        copies.append(child.translate(tuple(t)))
    return m3d.Manifold.batch_boolean(copies, m3d.OpType.Add) if count > 1 else copies[0]


@builds("union", "union_n")
def _union(walk, node, v):
    """Manifold's (or CrossSection's) union of every child."""
    m3d = _m3d()
    parts = [walk.shape(c) for c in node.children]
    return type(parts[0]).batch_boolean(parts, m3d.OpType.Add)


@builds("intersection")
def _intersection(walk, node, v):
    """``a ∩ b``; a plane child trims the other child instead (no finite stand-in)."""
    a, b = node.children
    for plane, other in ((a, b), (b, a)):
        if plane.type_name == "plane":
            n, off = half_space(plane)
            return walk.shape(other).trim_by_plane(tuple(-n), -off)
    return walk.shape(a) ^ walk.shape(b)


@builds("subtraction")
def _subtraction(walk, node, v):
    """``a − b``; a plane cut keeps the part of ``a`` above the plane."""
    a, b = node.children
    if b.type_name == "plane":
        n, off = half_space(b)
        return walk.shape(a).trim_by_plane(tuple(n), off)
    return walk.shape(a) - walk.shape(b)
