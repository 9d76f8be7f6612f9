"""The plane an object stands on, measured in a depth photo, and the camera tilt it gives.

An object photographed on a table stands on the table: the camera's elevation above the table plane is
then known from the depth around the object, while a single silhouette hardly determines it (the
ClearGrasp mug's fit with the elevation free settled at 36 degrees against the table's 45.8, and its
depth error then stayed above 6 mm whatever the weights: see ``docs/architecture.md``, photo fits).

:func:`support_plane` back-projects the valid depth pixels of a ring around the object's mask with the
photo's intrinsics, fits a plane by RANSAC (numpy, seeded: the same photo gives the same plane) and
refines it by least squares on the inliers. The plane is kept only if it is well supported and faces up
in the image (a wall behind the object does not qualify). :class:`Plane` gives the camera's elevation
above it and its roll (the orbit cameras of a fit have none: a large roll is reported, not corrected).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

RING = (0.1, 0.6)         # the ring around the mask: from/to this share of the mask's larger side
INLIER = 0.01             # RANSAC inlier distance, as a share of the median depth of the ring
MIN_SHARE = 0.5           # the plane must hold this share of the ring's points
MIN_POINTS = 200          # ... and at least this many
MIN_UP = 0.5              # its normal must point up in the image by at least this much (cos of 60 degrees)
TRIALS = 256


@dataclass(frozen=True)
class Plane:
    """A plane in camera coordinates (x right, y down, z forward, metres): ``normal . p = offset``, the
    normal pointing up in the image (towards -y); ``share``: the ring's points within the inlier
    distance; ``residual``: their median distance from it (metres)."""

    normal: tuple[float, float, float]
    offset: float
    share: float
    points: int
    residual: float

    @property
    def elevation_deg(self) -> float:
        """The camera's optical axis's angle below the plane, in degrees (the orbit elevation)."""
        return math.degrees(math.asin(max(-1.0, min(1.0, -self.normal[2]))))

    @property
    def roll_deg(self) -> float:
        """The plane's tilt across the image, in degrees (0: the horizon is level in the photo)."""
        return math.degrees(math.atan2(self.normal[0], -self.normal[1]))


def ring_pixels(mask: np.ndarray) -> np.ndarray:
    """(H, W) bool: the pixels of a ring around the foreground of ``mask`` (> 0.5), from
    ``RING[0]`` to ``RING[1]`` of the mask's larger side away from it."""
    import cv2

    fg = (mask > 0.5).astype(np.uint8)
    ys, xs = np.nonzero(fg)
    side = max(xs.max() - xs.min() + 1, ys.max() - ys.min() + 1)
    dist = cv2.distanceTransform(1 - fg, cv2.DIST_L2, 5)
    return (dist > RING[0] * side) & (dist <= RING[1] * side)


def back_project(depth: np.ndarray, pixels: np.ndarray, fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """(N, 3) camera-frame points of the ``pixels`` (H, W bool) whose ``depth`` (H, W, view-axis metres,
    NaN or <= 0: none) is valid; pixel centers at +0.5."""
    ys, xs = np.nonzero(pixels & np.isfinite(depth) & (np.nan_to_num(depth) > 0))
    z = depth[ys, xs]
    return np.stack([(xs + 0.5 - cx) / fx * z, (ys + 0.5 - cy) / fy * z, z], 1)


def fit_plane(points: np.ndarray, tol: float, seed: int = 0) -> tuple[np.ndarray, float, np.ndarray]:
    """RANSAC (:data:`TRIALS` triples) then least squares on the inliers: (unit normal (3,), offset,
    inlier mask (N,)) with ``normal . p = offset`` for the plane's points."""
    rng = np.random.default_rng(seed)
    n = len(points)
    best = np.zeros(n, dtype=bool)
    for _ in range(TRIALS):
        a, b, c = points[rng.choice(n, 3, replace=False)]
        nrm = np.cross(b - a, c - a)
        norm = np.linalg.norm(nrm)
        if norm < 1e-12:
            continue
        nrm /= norm
        inl = np.abs(points @ nrm - nrm @ a) <= tol
        if inl.sum() > best.sum():
            best = inl
    for _ in range(2):  # least squares on the inliers, then the inliers of that plane
        p = points[best]
        c = p.mean(0)
        nrm = np.linalg.svd(p - c, full_matrices=False)[2][2]
        best = np.abs((points - c) @ nrm) <= tol
    return nrm, float(nrm @ c), best


def support_plane(depth: np.ndarray, mask: np.ndarray, fx: float, fy: float, cx: float, cy: float
                  ) -> Plane | None:
    """The plane the object of ``mask`` (H, W, > 0.5) stands on, from ``depth`` (H, W, metres, NaN: no
    reading) and the intrinsics in pixels; None where the ring around the object holds no plane that is
    well supported (:data:`MIN_SHARE`, :data:`MIN_POINTS`) and faces up (:data:`MIN_UP`)."""
    pts = back_project(depth, ring_pixels(mask), fx, fy, cx, cy)
    if len(pts) < MIN_POINTS:
        return None
    tol = INLIER * float(np.median(pts[:, 2]))
    nrm, off, inl = fit_plane(pts, tol)
    if nrm[1] > 0:  # point up in the image (camera y is down)
        nrm, off = -nrm, -off
    share = float(inl.mean())
    if share < MIN_SHARE or int(inl.sum()) < MIN_POINTS or -nrm[1] < MIN_UP:
        return None
    res = float(np.median(np.abs(pts[inl] @ nrm - off)))
    return Plane(tuple(float(v) for v in nrm), off, share, int(inl.sum()), res)
