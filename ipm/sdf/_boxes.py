"""Axis-aligned bounding boxes ``(lo (d,), hi (d,))`` of SDF nodes, as float64 NumPy arrays."""

from __future__ import annotations

import itertools

import numpy as np


def sym(*half: float) -> tuple[np.ndarray, np.ndarray]:
    """The box ``[-h, h]`` for half extents ``h`` (one per axis)."""
    h = np.array(half, dtype=np.float64)
    return -h, h


def corners(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The 2^d corners of a box, ``(2^d, d)``."""
    return np.array(list(itertools.product(*zip(lo, hi))), dtype=np.float64)


def grow(box, r: float):
    """The box grown by ``r`` on every side."""
    lo, hi = box
    return lo - r, hi + r


def points_box(xs, ys) -> tuple[np.ndarray, np.ndarray]:
    """The box of 2D points given as coordinate lists."""
    return np.array([min(xs), min(ys)]), np.array([max(xs), max(ys)])


def union(boxes):
    """The box of a union of boxes."""
    return np.min([b[0] for b in boxes], 0), np.max([b[1] for b in boxes], 0)


def intersection(boxes):
    """The box of an intersection of boxes (empty ones collapse to a point)."""
    lo, hi = np.max([b[0] for b in boxes], 0), np.min([b[1] for b in boxes], 0)
    return lo, np.maximum(hi, lo)
