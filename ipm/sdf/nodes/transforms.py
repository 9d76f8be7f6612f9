"""Transforms of one dimension only: their child's points are moved. (Translate, scale, round and shell
are written once for 2D and 3D in :mod:`ipm.sdf.nodes.dn`.)

Domain operators from Quilez, "Distance functions" (rotation, non-uniform scale, elongation,
symmetry, limited repetition). A transform is exact when its child is exact, except where the
docstring says it is a bound.
"""

from __future__ import annotations

import numpy as np
import torch

from ipm.params import Param
from ipm.sdf._boxes import corners
from ipm.sdf._math import axis_from_tilt, deg2rad, rotate_points, rotation_matrix, stack_coords
from ipm.sdf.node import ANGLE, LEN, POS, P, operation

AXIS = Param("axis", 0, 0, 2, "int", "0 = x, 1 = y, 2 = z")
FACTOR = (1.0, 1e-3, 100.0)


def _rotate_box(box, angle, tilt, az):
    angle, tilt, az = (torch.tensor(x, dtype=torch.float64) for x in (angle, tilt, az))
    c = corners(*box) @ rotation_matrix(axis_from_tilt(tilt, az), angle).numpy().T
    return c.min(0), c.max(0)


@operation("rotate", P("angle", 0.0, *ANGLE), P("tilt", 0.0, *ANGLE), P("azimuth", 0.0, *ANGLE), box=_rotate_box)
def Rotate(child, p, angle, tilt, az):
    """Rotate the child by ``angle`` degrees about an axis: +Y tilted by ``tilt`` degrees towards the
    XZ direction at ``azimuth`` degrees (the thesis's angle plus two axis angles). Exact."""
    R = rotation_matrix(axis_from_tilt(tilt, az), angle).to(p.dtype)
    return child(rotate_points(p, R))  # p^T R = (R^T p)^T: the inverse rotation


def _rotate2_box(box, angle):
    a = np.deg2rad(angle)
    pts = corners(*box) @ np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]).T
    return pts.min(0), pts.max(0)


@operation("rotate2d", P("angle", 0.0, *ANGLE), dims=(2,), box=_rotate2_box)
def Rotate2D(child, p, angle):
    """Rotate a 2D child by ``angle`` degrees (counter-clockwise) about the origin. Exact."""
    a = deg2rad(angle)
    c, s = torch.cos(a), torch.sin(a)
    x, y = p[..., 0], p[..., 1]
    return child(stack_coords([c * x + s * y, -s * x + c * y]))  # inverse rotation of the points


@operation("scale3", P("sx", *FACTOR), P("sy", *FACTOR), P("sz", *FACTOR), exact=False,
           box=lambda b, *s: (b[0] * np.array(s), b[1] * np.array(s)))
def Scale3(child, p, sx, sy, sz):
    """Non-uniform scale by ``(sx, sy, sz)``: ``f(p / s) * min(s)``. A bound, not exact."""
    return child(p / torch.stack([sx, sy, sz])) * torch.minimum(sx, torch.minimum(sy, sz))


@operation("elongate", P("hx", 0.2, 0.0, 20.0), P("hy", 0.1, 0.0, 20.0), P("hz", 0.1, 0.0, 20.0), exact=False,
           box=lambda b, *h: (b[0] - np.array(h) / 2, b[1] + np.array(h) / 2))
def Elongate(child, p, hx, hy, hz):
    """Stretch the child by inserting ``(hx, hy, hz)`` of straight extent at its center (opElongate,
    the simple variant ``f(p - clamp(p, -h/2, h/2))``). Exact outside; inside the inserted slab it is
    a bound (the child's value at its center)."""
    h = 0.5 * torch.stack([hx, hy, hz])
    return child(p - torch.clamp(p, min=-h, max=h))


def _mirror_box(box, axis, off):
    axis = int(axis)
    lo, hi = box[0].copy(), box[1].copy()
    ext = max(abs(hi[axis] - off), abs(lo[axis] - off))
    lo[axis], hi[axis] = off - ext, off + ext
    return lo, hi


@operation("mirror", AXIS, P("offset", 0.0, *POS), exact=False, box=_mirror_box)
def Mirror(child, p, axis, off):
    """Mirror symmetry: the child's half at coordinate ``axis`` >= ``offset`` is reflected across the
    plane coordinate = offset (opSymX/Y/Z). Exact if the child lies on the kept side; otherwise a bound."""
    cols = list(p.unbind(-1))
    cols[axis] = (cols[axis] - off).abs() + off
    return child(stack_coords(cols))


def _repeat_box(box, axis, n, s):
    axis, half = int(axis), 0.5 * (int(n) - 1) * s
    lo, hi = box[0].copy(), box[1].copy()
    lo[axis] -= half
    hi[axis] += half
    return lo, hi


@operation("repeat", AXIS, Param("count", 3, 1, 64, "int"), P("spacing", 0.5, *LEN), exact=False, box=_repeat_box)
def Repeat(child, p, axis, n, s):
    """Finite repetition: ``count`` copies along ``axis`` spaced by ``spacing``, centered at the origin
    (opRepLim). Exact when the child fits inside its cell, otherwise a bound."""
    half = 0.5 * (n - 1)
    cols = list(p.unbind(-1))
    x = cols[axis]
    idx = torch.clamp(torch.round(x.detach() / s.detach() + half), 0, n - 1)
    cols[axis] = x - (idx - half) * s
    return child(stack_coords(cols))
