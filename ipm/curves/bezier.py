"""Cubic Bezier curves fitted to polylines, after P. J. Schneider, "An Algorithm for Automatically Fitting
Digitized Curves", Graphics Gems (1990): chord-length parameters, the two inner control points on the end
tangents by least squares, Newton-Raphson reparametrization, and a split at the worst point (with the
tangent there from its neighbours) until the largest distance is under the tolerance."""

from __future__ import annotations

import numpy as np


def bezier_points(ctrl: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Points of cubic Beziers: ctrl (..., 4, 2), t (n,) -> (..., n, 2)."""
    t = np.asarray(t, float)[:, None]
    s = 1.0 - t
    c = np.asarray(ctrl, float)
    return (s ** 3 * c[..., 0:1, :] + 3 * s * s * t * c[..., 1:2, :] + 3 * s * t * t * c[..., 2:3, :]
            + t ** 3 * c[..., 3:4, :])


def sample_beziers(beziers: np.ndarray, spacing: float = 0.25) -> np.ndarray:
    """Points along cubic Beziers (m, 4, 2) at most about ``spacing`` apart: (n, 2)."""
    out = []
    for b in np.asarray(beziers, float).reshape(-1, 4, 2):
        n = max(int(np.ceil(np.linalg.norm(np.diff(b, axis=0), axis=1).sum() / spacing)), 1)
        out.append(bezier_points(b, np.linspace(0.0, 1.0, n + 1)))
    return np.concatenate(out) if out else np.zeros((0, 2))


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v)
    return v / n if n > 1e-12 else np.zeros(2)


def _chord_params(pts: np.ndarray) -> np.ndarray:
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    return s / s[-1] if s[-1] > 0 else np.linspace(0.0, 1.0, len(pts))


def _fit_one(pts: np.ndarray, u: np.ndarray, t0: np.ndarray, t1: np.ndarray) -> np.ndarray:
    """Schneider's least-squares Bezier with end points fixed and inner points on the tangents t0 (at the
    start, pointing in) and t1 (at the end, pointing back)."""
    p0, p3 = pts[0], pts[-1]
    b0, b1, b2, b3 = (1 - u) ** 3, 3 * u * (1 - u) ** 2, 3 * u * u * (1 - u), u ** 3
    A1, A2 = b1[:, None] * t0, b2[:, None] * t1
    C = np.array([[np.sum(A1 * A1), np.sum(A1 * A2)], [np.sum(A1 * A2), np.sum(A2 * A2)]])
    tmp = pts - (b0 + b1)[:, None] * p0 - (b2 + b3)[:, None] * p3
    X = np.array([np.sum(A1 * tmp), np.sum(A2 * tmp)])
    det = C[0, 0] * C[1, 1] - C[0, 1] * C[1, 0]
    chord = np.linalg.norm(p3 - p0)
    a1 = a2 = 0.0
    if abs(det) > 1e-12:
        a1 = (X[0] * C[1, 1] - X[1] * C[0, 1]) / det
        a2 = (C[0, 0] * X[1] - C[1, 0] * X[0]) / det
    arc = float(np.linalg.norm(np.diff(pts, axis=0), axis=1).sum())
    if a1 < 1e-6 * chord or a2 < 1e-6 * chord or not np.isfinite(a1 + a2) or max(a1, a2) > arc:
        # Schneider's fallback (Wu and Barsky's heuristic), also for arms longer than the polyline (a
        # few points around a kink, whose least squares can throw a loop far out between the samples)
        a1 = a2 = chord / 3.0
    return np.array([p0, p0 + a1 * t0, p3 + a2 * t1, p3])


def _reparam(b: np.ndarray, pts: np.ndarray, u: np.ndarray) -> np.ndarray:
    """One Newton-Raphson step per point on (B(u) - p) . B'(u) = 0."""
    q = bezier_points(b, u)
    d1 = 3 * np.diff(b, axis=0)
    d2 = 2 * np.diff(d1, axis=0)
    uu = u[:, None]
    q1 = (1 - uu) ** 2 * d1[0] + 2 * (1 - uu) * uu * d1[1] + uu ** 2 * d1[2]
    q2 = (1 - uu) * d2[0] + uu * d2[1]
    num = np.sum((q - pts) * q1, axis=1)
    den = np.sum(q1 * q1, axis=1) + np.sum((q - pts) * q2, axis=1)
    step = np.where(np.abs(den) > 1e-12, num / np.where(np.abs(den) > 1e-12, den, 1.0), 0.0)
    return np.clip(u - step, 0.0, 1.0)


def _max_error(b: np.ndarray, pts: np.ndarray, u: np.ndarray) -> tuple[float, int]:
    d = np.sum((bezier_points(b, u) - pts) ** 2, axis=1)
    i = int(np.argmax(d[1:-1])) + 1 if len(d) > 2 else len(d) // 2
    return float(np.sqrt(d.max())), i


def fit_beziers(pts: np.ndarray, tol: float, closed: bool = False, depth: int = 0) -> np.ndarray:
    """Cubic Beziers (m, 4, 2) through a polyline (n, 2) within ``tol`` pixels of every point (at the
    Newton-refined parameters). ``closed``: the first and last points coincide and the tangents there
    are taken across the join."""
    pts = np.asarray(pts, float)
    if len(pts) < 2:
        return np.zeros((0, 4, 2))
    if closed and len(pts) > 4:
        t0 = _unit(pts[1] - pts[-2])
        return _fit(pts, t0, -t0, tol, depth)
    k = min(3, len(pts) - 1)
    return _fit(pts, _unit(pts[k] - pts[0]), _unit(pts[-1 - k] - pts[-1]), tol, depth)


def _fit(pts: np.ndarray, t0: np.ndarray, t1: np.ndarray, tol: float, depth: int) -> np.ndarray:
    if len(pts) == 2 or depth > 40:
        d = np.linalg.norm(pts[-1] - pts[0]) / 3.0
        return np.array([[pts[0], pts[0] + d * t0, pts[-1] + d * t1, pts[-1]]])
    u = _chord_params(pts)
    b = _fit_one(pts, u, t0, t1)
    err, split = _max_error(b, pts, u)
    if err <= tol:
        return b[None]
    if err <= 4.0 * tol:
        for _ in range(8):
            u = _reparam(b, pts, u)
            b = _fit_one(pts, u, t0, t1)
            err, split = _max_error(b, pts, u)
            if err <= tol:
                return b[None]
    split = min(max(split, 1), len(pts) - 2)
    tc = _unit(pts[split - 1] - pts[split + 1])
    left = _fit(pts[:split + 1], t0, tc, tol, depth + 1)
    right = _fit(pts[split:], -tc, t1, tol, depth + 1)
    return np.concatenate([left, right])
