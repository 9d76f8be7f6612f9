"""Transforms: one child, whose points are moved (or whose distance is modified).

Domain operators from Quilez, "Distance functions" (rotation/translation, scale, rounding,
onion, elongation, symmetry, limited repetition). A transform is exact when its child is exact,
except where the docstring says it is a bound.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
import torch

from ipm.params import Param
from ipm.sdf._math import axis_from_tilt, box_combine, deg2rad, rotate_points, rotation_matrix, stack_coords
from ipm.sdf.d3 import LEN, POS, P
from ipm.sdf.nodes import Node, register

ANGLE = (-360.0, 360.0)


class Transform3D(Node):
    dim = 3
    arity = 1
    exact = True


class Transform2D(Node):
    dim = 2
    arity = 1
    exact = True


def corners(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The 2^d corners of a box, (2^d, d)."""
    return np.array(list(itertools.product(*zip(lo, hi))), dtype=np.float64)


def grow(box, r: float):
    lo, hi = box
    return lo - r, hi + r


# -- 3D ----------------------------------------------------------------------------------------

@register
@dataclass(frozen=True, eq=False)
class Translate(Transform3D):
    """Move the child by ``(x, y, z)``. Exact."""

    type_name = "translate"
    params = (P("x", 0.0, *POS), P("y", 0.0, *POS), P("z", 0.0, *POS))

    def eval(self, p, th, kids):
        x, y, z = th
        return kids[0](p - torch.stack([x, y, z]))

    def bbox(self, v, kids):
        lo, hi = kids[0]
        t = np.array(v)
        return lo + t, hi + t


@register
@dataclass(frozen=True, eq=False)
class Rotate(Transform3D):
    """Rotate the child by ``angle`` degrees about an axis: +Y tilted by ``tilt`` degrees towards the
    XZ direction at ``azimuth`` degrees (the thesis's angle plus two axis angles). Exact."""

    type_name = "rotate"
    params = (P("angle", 0.0, *ANGLE), P("tilt", 0.0, *ANGLE), P("azimuth", 0.0, *ANGLE))

    def eval(self, p, th, kids):
        angle, tilt, az = th
        R = rotation_matrix(axis_from_tilt(tilt, az), angle).to(p.dtype)
        return kids[0](rotate_points(p, R))  # p^T R = (R^T p)^T: the inverse rotation

    def bbox(self, v, kids):
        angle, tilt, az = (torch.tensor(x, dtype=torch.float64) for x in v)
        R = rotation_matrix(axis_from_tilt(tilt, az), angle).numpy()
        c = corners(*kids[0]) @ R.T
        return c.min(0), c.max(0)


@register
@dataclass(frozen=True, eq=False)
class Scale(Transform3D):
    """Uniform scale by ``factor``: ``f(p / s) * s``. Exact."""

    type_name = "scale"
    params = (P("factor", 1.0, 1e-3, 100.0),)

    def eval(self, p, th, kids):
        (s,) = th
        return kids[0](p / s) * s

    def bbox(self, v, kids):
        return kids[0][0] * v[0], kids[0][1] * v[0]


@register
@dataclass(frozen=True, eq=False)
class Scale3(Transform3D):
    """Non-uniform scale by ``(sx, sy, sz)``: ``f(p / s) * min(s)``. A bound, not exact."""

    type_name = "scale3"
    exact = False
    params = (P("sx", 1.0, 1e-3, 100.0), P("sy", 1.0, 1e-3, 100.0), P("sz", 1.0, 1e-3, 100.0))

    def eval(self, p, th, kids):
        sx, sy, sz = th
        return kids[0](p / torch.stack([sx, sy, sz])) * torch.minimum(sx, torch.minimum(sy, sz))

    def bbox(self, v, kids):
        s = np.array(v)
        return kids[0][0] * s, kids[0][1] * s


@register
@dataclass(frozen=True, eq=False)
class Round(Transform3D):
    """Inflate the child by ``radius`` (rounds its edges): ``f(p) - r`` (opRound). Exact outside."""

    type_name = "round"
    params = (P("radius", 0.05, 0.0, 10.0),)

    def eval(self, p, th, kids):
        return kids[0](p) - th[0]

    def bbox(self, v, kids):
        return grow(kids[0], v[0])


@register
@dataclass(frozen=True, eq=False)
class Shell(Transform3D):
    """Hollow the child into a shell of ``thickness``: ``|f(p)| - t/2`` (opOnion). Exact."""

    type_name = "shell"
    params = (P("thickness", 0.05, *LEN),)

    def eval(self, p, th, kids):
        return kids[0](p).abs() - 0.5 * th[0]

    def bbox(self, v, kids):
        return grow(kids[0], v[0] / 2)


@register
@dataclass(frozen=True, eq=False)
class Elongate(Transform3D):
    """Stretch the child by inserting ``(hx, hy, hz)`` of straight extent at its center (opElongate,
    the simple variant ``f(p - clamp(p, -h/2, h/2))``). Exact outside; inside the inserted slab it is
    a bound (the child's value at its center)."""

    type_name = "elongate"
    exact = False
    params = (P("hx", 0.2, 0.0, 20.0), P("hy", 0.1, 0.0, 20.0), P("hz", 0.1, 0.0, 20.0))

    def eval(self, p, th, kids):
        hx, hy, hz = th
        h = 0.5 * torch.stack([hx, hy, hz])
        return kids[0](p - torch.clamp(p, min=-h, max=h))

    def bbox(self, v, kids):
        lo, hi = kids[0]
        h = np.array(v) / 2
        return lo - h, hi + h


@register
@dataclass(frozen=True, eq=False)
class Mirror(Transform3D):
    """Mirror symmetry: the child's half at coordinate ``axis`` >= ``offset`` is reflected across the
    plane coordinate = offset (opSymX/Y/Z). Exact if the child lies on the kept side; otherwise a bound."""

    type_name = "mirror"
    exact = False
    params = (Param("axis", 0, 0, 2, "int", "0 = x, 1 = y, 2 = z"), P("offset", 0.0, *POS))

    def eval(self, p, th, kids):
        axis, off = th
        cols = list(p.unbind(-1))
        cols[axis] = (cols[axis] - off).abs() + off
        return kids[0](stack_coords(cols))

    def bbox(self, v, kids):
        axis, off = int(v[0]), v[1]
        lo, hi = kids[0][0].copy(), kids[0][1].copy()
        ext = max(abs(hi[axis] - off), abs(lo[axis] - off))
        lo[axis], hi[axis] = off - ext, off + ext
        return lo, hi


@register
@dataclass(frozen=True, eq=False)
class Repeat(Transform3D):
    """Finite repetition: ``count`` copies along ``axis`` spaced by ``spacing``, centered at the origin
    (opRepLim). Exact when the child fits inside its cell, otherwise a bound."""

    type_name = "repeat"
    exact = False
    params = (Param("axis", 0, 0, 2, "int", "0 = x, 1 = y, 2 = z"), Param("count", 3, 1, 64, "int"),
              P("spacing", 0.5, *LEN))

    def eval(self, p, th, kids):
        axis, n, s = th
        half = 0.5 * (n - 1)
        cols = list(p.unbind(-1))
        x = cols[axis]
        idx = torch.clamp(torch.round(x.detach() / s.detach() + half), 0, n - 1)
        cols[axis] = x - (idx - half) * s
        return kids[0](stack_coords(cols))

    def bbox(self, v, kids):
        axis, n, s = int(v[0]), int(v[1]), v[2]
        lo, hi = kids[0][0].copy(), kids[0][1].copy()
        half = 0.5 * (n - 1) * s
        lo[axis] -= half
        hi[axis] += half
        return lo, hi


# -- 2D ----------------------------------------------------------------------------------------

def _rot2(p, angle_deg):
    a = deg2rad(angle_deg)
    c, s = torch.cos(a), torch.sin(a)
    x, y = p[..., 0], p[..., 1]
    return stack_coords([c * x + s * y, -s * x + c * y])  # inverse rotation of the points


def _rot2_box(lo, hi, angle_deg):
    a = np.deg2rad(angle_deg)
    R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    pts = corners(lo, hi) @ R.T
    return pts.min(0), pts.max(0)


@register
@dataclass(frozen=True, eq=False)
class Translate2D(Transform2D):
    """Move a 2D child by ``(x, y)``. Exact."""

    type_name = "translate2d"
    params = (P("x", 0.0, *POS), P("y", 0.0, *POS))

    def eval(self, p, th, kids):
        x, y = th
        return kids[0](p - torch.stack([x, y]))

    def bbox(self, v, kids):
        return kids[0][0] + np.array(v), kids[0][1] + np.array(v)


@register
@dataclass(frozen=True, eq=False)
class Rotate2D(Transform2D):
    """Rotate a 2D child by ``angle`` degrees (counter-clockwise) about the origin. Exact."""

    type_name = "rotate2d"
    params = (P("angle", 0.0, *ANGLE),)

    def eval(self, p, th, kids):
        return kids[0](_rot2(p, th[0]))

    def bbox(self, v, kids):
        return _rot2_box(*kids[0], v[0])


@register
@dataclass(frozen=True, eq=False)
class Scale2D(Transform2D):
    """Uniform 2D scale by ``factor``. Exact."""

    type_name = "scale2d"
    params = (P("factor", 1.0, 1e-3, 100.0),)

    def eval(self, p, th, kids):
        return kids[0](p / th[0]) * th[0]

    def bbox(self, v, kids):
        return kids[0][0] * v[0], kids[0][1] * v[0]


@register
@dataclass(frozen=True, eq=False)
class Round2D(Transform2D):
    """Inflate a 2D child by ``radius``. Exact outside."""

    type_name = "round2d"
    params = (P("radius", 0.05, 0.0, 10.0),)

    def eval(self, p, th, kids):
        return kids[0](p) - th[0]

    def bbox(self, v, kids):
        return grow(kids[0], v[0])


@register
@dataclass(frozen=True, eq=False)
class Shell2D(Transform2D):
    """Turn a 2D child into its outline of ``thickness`` (opOnion). Exact."""

    type_name = "shell2d"
    params = (P("thickness", 0.05, *LEN),)

    def eval(self, p, th, kids):
        return kids[0](p).abs() - 0.5 * th[0]

    def bbox(self, v, kids):
        return grow(kids[0], v[0] / 2)


__all__ = ["box_combine"]
