"""Mesh primitives: centered at the origin, Y up, sizes are full extents like the SDF nodes.

``box``, ``cylinder``, ``cone``, ``uv_sphere``, ``revolve`` (a polyline ``(r_i, y_i)`` revolved about Y
and closed on the axis), ``extrude`` (a polygon ``(x_i, z_i)`` in the XZ plane extruded along Y). The
number of segments of round primitives is the level of detail (:class:`MeshLod`), not a parameter.
"""

from __future__ import annotations

import math
from abc import abstractmethod

import numpy as np
import torch

from ipm.errors import InputError
from ipm.generators import _meshkit as mk
from ipm.generators._meshkit import smul
from ipm.generators.meshtree.lod import MeshLod
from ipm.generators.meshtree.node import POS, P, Primitive, register


def _revolved(r: torch.Tensor, y: torch.Tensor, bottom, top, lod: MeshLod) -> torch.Tensor:
    return mk.revolve(r, y, lod.segments, bottom=bottom, top=top)


@register
class Box(Primitive):
    """Axis-aligned box with full edge lengths ``size_x/y/z`` (8 vertices)."""

    linear = True
    type_name = "box"
    params = (P("size_x", 1.0), P("size_y", 1.0), P("size_z", 1.0))

    def verts(self, th, lod):
        """The 8 corners ``(8, 3)`` of the box ``[-size / 2, size / 2]`` (linear in ``th``)."""
        h = smul(th, 0.5)[None]
        return mk.box_verts(-h, h)

    def faces(self, lod):
        """The box's 12 triangles (the same at every level of detail)."""
        return mk.repeat_faces_np(None, 8, 1, 2, 4)

    def n_verts(self, lod):
        """Always 8, whatever the level of detail."""
        return 8


class Frustum(Primitive):
    """Base of ``cylinder`` and ``cone``: two rings of ``segments`` vertices at y = -h/2 and +h/2 and
    two cap centers. Subclasses say which parameters are the bottom radius, top radius and height."""

    linear = True

    @abstractmethod
    def radii_height(self, th: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``(r_bottom, r_top, height)``, each ``(1,)``, from ``th: (k,)``."""

    def verts(self, th, lod):
        """Bottom cap center, the two rings and the top cap center, ``(2 segments + 2, 3)``."""
        r0, r1, h = self.radii_height(th)
        y = smul(h, 0.5)
        return _revolved(torch.cat([r0, r1]), torch.cat([-y, y]), -y, y, lod)

    def faces(self, lod):
        """Two rings joined by a band and closed by fans from the two cap centers."""
        return mk.loft_faces_np(2, lod.segments, "pole", "pole")

    def n_verts(self, lod):
        """``2 * lod.segments + 2``, without building the faces."""
        return 2 * lod.segments + 2


@register
class Cylinder(Frustum):
    """Capped cylinder along Y: ``radius``, full ``height`` (two rings and two cap centers)."""

    type_name = "cylinder"
    params = (P("radius", 0.5), P("height", 1.0))

    def radii_height(self, th):
        """The same ``radius`` at the bottom and the top."""
        r, h = th.split(1)
        return r, r, h


@register
class Cone(Frustum):
    """Capped cone along Y: ``radius_bottom`` at y = -h/2, ``radius_top`` at +h/2 (small, not zero,
    for a pointed cone: the mesh keeps its top ring)."""

    type_name = "cone"
    params = (P("radius_bottom", 0.5), P("radius_top", 0.1), P("height", 1.0))

    def radii_height(self, th):
        """``radius_bottom``, ``radius_top`` and ``height`` as they are."""
        return tuple(th.split(1))


def _meridian(rings: int) -> np.ndarray:
    """``(2, rings - 1)``: sin and -cos of the interior latitudes of a half turn."""
    a = np.arange(1, rings) * (math.pi / rings)
    return np.stack([np.sin(a), -np.cos(a)])


@register
class UVSphere(Primitive):
    """UV sphere of ``radius``: ``rings - 1`` latitude rings of ``segments`` vertices and two poles."""

    linear = True
    type_name = "uv_sphere"
    params = (P("radius", 0.5),)

    def verts(self, th, lod):
        """South pole, the ``rings - 1`` latitude rings and north pole, ``((rings - 1) segments + 2, 3)``."""
        s, c = mk.const(_meridian, lod.rings, like=th)
        return _revolved(th * s, th * c, -th, th, lod)

    def faces(self, lod):
        """The latitude bands, closed by fans at the two poles."""
        return mk.loft_faces_np(lod.rings - 1, lod.segments, "pole", "pole")

    def n_verts(self, lod):
        """``(lod.rings - 1) * lod.segments + 2``, without building the faces."""
        return (lod.rings - 1) * lod.segments + 2


@register
class Revolve(Primitive):
    """A polyline ``(r0, y0) .. (r{k-1}, y{k-1})`` revolved about Y and closed by the axis points
    ``(0, y0)`` and ``(0, y{k-1})``. The outside is on the right going from the first point to the
    last with the axis on the left, so ``y{k-1} > y0`` (checked)."""

    linear = True
    type_name = "revolve"
    size_prefix, default_size, min_size = "r", 4, 1

    @classmethod
    def point_params(cls, i, k):
        """``r{i}`` (default on a bulging half-sine profile) and ``y{i}`` (default evenly spaced in [-0.5, 0.5])."""
        t = i / max(k - 1, 1)
        return (P(f"r{i}", round(0.5 * math.sin(math.pi * (0.15 + 0.7 * t)), 6), 1e-3, 20.0),
                P(f"y{i}", round(t - 0.5, 6), *POS))

    def check(self):
        """Raises ``InputError`` unless the last profile point is above the first (``y{k-1} > y0``)."""
        ys = self.values[1::2]
        if not ys[-1] > ys[0]:
            raise InputError(f"revolve: expected the profile to end above its start (y{len(ys) - 1} > y0), "
                             f"got y0 = {ys[0]}, y{len(ys) - 1} = {ys[-1]}")

    def verts(self, th, lod):
        """The profile's rings between the axis points ``(0, y0)`` and ``(0, y{k-1})``, ``(k segments + 2, 3)``."""
        pts = th.reshape(-1, 2)
        r, y = pts[:, 0], pts[:, 1]
        return _revolved(r, y, y[:1], y[-1:], lod)

    def faces(self, lod):
        """One ring per profile point, closed by fans at the two axis points."""
        return mk.loft_faces_np(self.size, lod.segments, "pole", "pole")

    def n_verts(self, lod):
        """``size * lod.segments + 2``, without building the faces."""
        return self.size * lod.segments + 2


@register
class Extrude(Primitive):
    """A polygon ``(x0, z0) .. (x{k-1}, z{k-1})`` in the XZ plane extruded along Y by ``height``
    (centered). The caps are fans from the vertex mean, so the polygon must be star-shaped around it
    (convex polygons are); either orientation is accepted (fixed when the node is built)."""

    linear = True
    type_name = "extrude"
    params = (P("height", 0.5),)
    size_prefix, default_size, min_size = "x", 6, 3

    @classmethod
    def point_params(cls, i, k):
        """``x{i}``, ``z{i}``: defaults on a circle of radius 0.5, counter-clockwise about +Y."""
        a = 2.0 * math.pi * i / k
        return P(f"x{i}", round(0.5 * math.cos(a), 6), *POS), P(f"z{i}", round(-0.5 * math.sin(a), 6), *POS)

    def _area(self) -> float:
        """Twice the signed area in the (z, x) plane: positive when counter-clockwise about +Y."""
        x, z = np.array(self.values[1::2]), np.array(self.values[2::2])
        return float(np.sum(z * np.roll(x, -1) - np.roll(z, -1) * x))

    def _reversed(self) -> bool:
        return self._area() < 0.0

    def check(self):
        """Raises ``InputError`` for a polygon of (near) zero signed area."""
        if abs(self._area()) < 1e-12:
            raise InputError(f"extrude: expected a polygon with a non-zero area, got area {self._area() / 2:g}")

    def verts(self, th, lod):
        """Bottom cap center, bottom ring, top ring, top cap center, ``(2 k + 2, 3)``; a clockwise polygon
        is reversed first."""
        h = smul(th[:1], 0.5)
        pts = th[1:].reshape(-1, 2)
        if self._reversed():
            pts = torch.flip(pts, (0,))
        k = pts.shape[0]
        center = smul(pts.sum(0), 1.0 / k)                                     # (2,)
        ring_lo = torch.stack([pts[:, 0], (-h).expand(k), pts[:, 1]], -1)
        ring_hi = torch.stack([pts[:, 0], h.expand(k), pts[:, 1]], -1)
        c_lo = torch.cat([center[:1], -h, center[1:]])[None]
        c_hi = torch.cat([center[:1], h, center[1:]])[None]
        return torch.cat([c_lo, ring_lo, ring_hi, c_hi])

    def faces(self, lod):
        """The side band and fan caps from the two centers (the level of detail does not change them)."""
        return mk.loft_faces_np(2, self.size, "pole", "pole")

    def n_verts(self, lod):
        """``2 * size + 2``, without building the faces."""
        return 2 * self.size + 2
