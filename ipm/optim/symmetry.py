"""Poses that look the same: the turns about the vertical axis that map a shape onto itself, the fit's
equivalent poses, and pose errors up to symmetry.

A fit's pose turns the shape about the world's vertical (yaw). Where the shape is a body of revolution (a
vase) every yaw gives the same picture and the yaw is free; where it has a cyclic symmetry of order n (a
rectangular block with a gabled roof: n = 2) the n yaws ``yaw + 360 k / n`` do. :func:`yaw_symmetry`
finds which, on the shape itself: surface samples turned about the vertical line through the shape's area
centroid (which any symmetry keeps) must land on the surface, within ``tol`` of the bounding-box diagonal,
everywhere (the largest distance counts, so a handle, 5 % of the surface, breaks it). Turns by 17, 53 and
131 degrees passing means a body of revolution; otherwise the largest order n <= 12 whose turn by 360 / n
passes, and lands at most half as far as the best of those three turns (a nearly round shape is not
given a cyclic order by its small turns).

Pose errors up to symmetry follow the BOP toolkit's MSSD (Hodaň et al., "BOP challenge 2020", ECCV
workshops 2020): the largest distance between the shape's vertices under the two poses, minimized over the
symmetries of the shape (a body of revolution: over turns in 1 degree steps)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

REVOLUTION_TESTS = (17.0, 53.0, 131.0)  # turns that no finite order <= 12 makes; all pass: a revolution
MAX_ORDER = 12
# largest distance of turned samples to the surface, share of the bounding-box diagonal: a vase fitted from one
# view keeps a pouring lip and an oval section one view cannot show (spout 0.03, aspect 0.98: 1.5 %)
TOL = 0.02


@dataclass(frozen=True)
class YawSymmetry:
    """Turns about a vertical axis that map a shape onto itself.

    kind: ``"none"`` (only the identity), ``"cyclic"`` (turns by ``360 k / order``) or ``"revolution"``
    (every turn); axis: the axis' (x, z) in the shape's own coordinates."""

    kind: Literal["none", "cyclic", "revolution"]
    order: int
    axis: tuple[float, float]

    def turns(self, step: float = 1.0) -> list[float]:
        """The symmetry's turns in degrees (a revolution: every ``step`` degrees)."""
        if self.kind == "revolution":
            return [step * k for k in range(int(round(360.0 / step)))]
        return [360.0 * k / self.order for k in range(self.order)]

    def to_json(self) -> dict:
        """``{"kind", "order", "axis_xz"}``, the axis rounded to 6 decimals."""
        return {"kind": self.kind, "order": self.order, "axis_xz": [round(v, 6) for v in self.axis]}


def _surface_points(V: np.ndarray, F: np.ndarray, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(``n`` area-weighted surface samples (n, 3), the area centroid (3,))."""
    from ipm.metrics import sample_surface

    tri = V[F]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    centroid = (tri.mean(1) * area[:, None]).sum(0) / max(area.sum(), 1e-300)
    return sample_surface(V, F, n, np.random.default_rng(seed)), centroid


def _turn(P: np.ndarray, deg: float, axis_xz: np.ndarray) -> np.ndarray:
    """``P (n, 3)`` turned by ``deg`` about the vertical line through ``axis_xz`` (right-handed about +Y)."""
    a = math.radians(deg)
    c, s = math.cos(a), math.sin(a)
    x, z = P[:, 0] - axis_xz[0], P[:, 2] - axis_xz[1]
    return np.stack([c * x + s * z + axis_xz[0], P[:, 1], -s * x + c * z + axis_xz[1]], 1)


def yaw_symmetry(V: np.ndarray, F: np.ndarray, tol: float = TOL, samples: int = 2000, seed: int = 0
                 ) -> YawSymmetry:
    """The turns about a vertical axis that map the surface ``V (N, 3), F (M, 3)`` (Y up) onto itself."""
    import igl

    V = np.ascontiguousarray(V, dtype=np.float64)
    F = np.ascontiguousarray(F, dtype=np.int64)
    P, centroid = _surface_points(V, F, samples, seed)
    axis = centroid[[0, 2]]
    limit = tol * float(np.linalg.norm(V.max(0) - V.min(0)))

    def gap(deg: float) -> float:
        d2, _, _ = igl.point_mesh_squared_distance(_turn(P, deg, axis), V, F)
        return float(np.sqrt(d2.max()))

    generic = [gap(t) for t in REVOLUTION_TESTS]
    if max(generic) <= limit:
        return YawSymmetry("revolution", 0, (float(axis[0]), float(axis[1])))
    for n in range(MAX_ORDER, 1, -1):
        # a nearly round shape passes small turns: a cyclic order needs its turn to fit clearly better
        # than the turns that no order makes
        g = gap(360.0 / n)
        if g <= limit and g <= 0.5 * min(generic):
            return YawSymmetry("cyclic", n, (float(axis[0]), float(axis[1])))
    return YawSymmetry("none", 1, (float(axis[0]), float(axis[1])))


def _rot_y(deg: float) -> np.ndarray:
    a = math.radians(deg)
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def equivalent_poses(sym: YawSymmetry, yaw: float, translation, step: float = 45.0) -> list[dict]:
    """The poses (``{"yaw_deg", "translation"}``) that place the shape exactly where the pose ``(yaw,
    translation)`` does, for ``sym`` found on the *posed* shape (its axis in world coordinates): turning the
    posed shape by a symmetry's turn about that axis changes the yaw by the turn and the translation ``t``
    to ``R (t - a) + a`` (a: the axis). One per turn (a revolution: every ``step`` degrees, as examples of a
    free yaw), the given pose first."""
    a = np.array([sym.axis[0], 0.0, sym.axis[1]])
    t = np.asarray(translation, dtype=np.float64)
    out = []
    for turn in sym.turns(step):
        y2 = (yaw + turn + 180.0) % 360.0 - 180.0
        t2 = _rot_y(turn) @ (t - a) + a
        out.append({"yaw_deg": round(y2, 9), "translation": [round(float(v), 9) for v in t2]})
    return out


def mssd(V: np.ndarray, pose_a: np.ndarray, pose_b: np.ndarray, sym: YawSymmetry) -> float:
    """Largest distance between the shape's vertices ``V (N, 3)`` placed by the 4 x 4 transforms ``pose_a``
    and ``pose_b``, minimized over the shape's symmetries ``sym`` (a revolution: turns in 1 degree steps)."""
    V = np.asarray(V, dtype=np.float64)
    a = (V @ pose_a[:3, :3].T) + pose_a[:3, 3]
    axis = np.array(sym.axis)
    best = math.inf
    for turn in sym.turns(1.0):
        b = (_turn(V, turn, axis) @ pose_b[:3, :3].T) + pose_b[:3, 3]
        best = min(best, float(np.linalg.norm(a - b, axis=1).max()))
    return best


def pose_matrix(yaw: float, translation, scale: float, center, size: float) -> np.ndarray:
    """The 4 x 4 transform of a fit's pose: a point p of the shape goes to ``scale (p - center) 2 / size
    R(yaw)^T + translation`` (:meth:`ipm.optim.problem.Problem._to_world`)."""
    M = np.eye(4)
    R = scale * (2.0 / size) * _rot_y(yaw)
    M[:3, :3] = R
    M[:3, 3] = np.asarray(translation, dtype=np.float64) - R @ np.asarray(center, dtype=np.float64)
    return M
