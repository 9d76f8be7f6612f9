"""Scores of a vectorized line drawing against its exact curves (``make table-curves``).

Conventions: points are ``(x, y)`` pixel coordinates (x right, y down, pixel centres at ``+0.5``); a curve is
a polyline ``(n, 2) float`` with a ``closed`` flag. Every method hands its result over as one
:class:`Traced` record, so one scorer serves all of them.

Metrics (:func:`score`), distances in pixels, exact point-to-polyline distances (:func:`distance_to_curves`):

* Chamfer: the mean of the two one-sided mean distances between the predicted curves, resampled every
  <= 0.25 px, and the true curves' dense samples; also as a share of the image diagonal.
* precision / recall / F-measure at thresholds of 0.5 %, 1 % and 2 % of the diagonal (the issue's), and at
  0.25 % (0.9 px on 256 x 256: the others are loose for clean 3 px strokes): precision is the share of
  predicted samples within the threshold of a true curve, recall the share of true samples within it of a
  predicted curve.
* junctions and endpoints: one-to-one matches (Hungarian assignment on the distances) within 2 % of the
  diagonal; counts are kept so that a table can pool them over drawings.
* the number of curves, predicted and true.
* IoU of the re-rendered strokes against the input's strokes (``ink > 0.5``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

SPACING = 0.25                       # px: the densest spacing of every sampled curve
THRESHOLDS = (0.0025, 0.005, 0.01, 0.02)   # F-measure thresholds, shares of the image diagonal
POINT_RADIUS = 0.02                  # junction / endpoint match radius, share of the diagonal
_FINE = 0.05                         # px: spacing of the search samples behind distance_to_curves


@dataclass(frozen=True)
class Traced:
    """One method's result on one drawing.

    curves: polylines ``(n_i, 2) float``; closed: one flag per curve; junctions ``(j, 2)``, endpoints
    ``(e, 2)`` float; strokes: the method's own re-rendering ``(H, W) bool`` (what its SVG shows), or None;
    seconds: the method's own time where it differs from the call's (a result shared by two variants).
    """

    curves: tuple[np.ndarray, ...]
    closed: tuple[bool, ...]
    junctions: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    endpoints: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    strokes: np.ndarray | None = None
    seconds: float | None = None


def resample(points: np.ndarray, closed: bool, spacing: float = SPACING) -> np.ndarray:
    """Points every <= ``spacing`` px along a polyline ``(n, 2)`` (uniform in arc length; an open curve
    keeps both ends, a closed one does not repeat its first point) -> ``(m, 2)``."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    if closed and len(p) > 1:
        p = np.concatenate([p, p[:1]])
    if len(p) < 2:
        return p.copy()
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
    if s[-1] <= 0:
        return p[:1].copy()
    n = max(1, math.ceil(s[-1] / spacing))
    t = np.linspace(0.0, s[-1], n + 1)
    if closed:
        t = t[:-1]
    return np.stack([np.interp(t, s, p[:, 0]), np.interp(t, s, p[:, 1])], axis=1)


def _densify(curves: Sequence[np.ndarray], closed: Sequence[bool]) -> tuple[np.ndarray, np.ndarray]:
    """Every polyline's own vertices plus points on its segments every <= ``_FINE`` px (the same geometry),
    all curves concatenated -> points ``(m, 2)`` and ``nxt (m,) int``: the index of the next point along
    the same curve, or -1 at an open curve's end."""
    pts, nxt, base = [], [], 0
    for c, cl in zip(curves, closed):
        p = np.asarray(c, dtype=np.float64).reshape(-1, 2)
        if cl and len(p) > 1:
            p = np.concatenate([p, p[:1]])
        if len(p) >= 2:
            seg = np.linalg.norm(np.diff(p, axis=0), axis=1)
            k = np.maximum(1, np.ceil(seg / _FINE).astype(int))
            t = np.concatenate([np.arange(n) / n for n in k])
            i = np.repeat(np.arange(len(seg)), k)
            d = p[i] + t[:, None] * (p[i + 1] - p[i])
            d = d if cl else np.concatenate([d, p[-1:]])
        else:
            d = p
        m = len(d)
        if m == 0:
            continue
        n = np.arange(1, m + 1) + base
        n[-1] = base if (cl and m > 1) else -1
        pts.append(d)
        nxt.append(n)
        base += m
    if not pts:
        return np.zeros((0, 2)), np.zeros(0, dtype=int)
    return np.concatenate(pts), np.concatenate(nxt)


def _segment_distance(q: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    L2 = (ab * ab).sum(-1)
    t = np.clip(((q - a) * ab).sum(-1) / np.where(L2 > 0, L2, 1.0), 0.0, 1.0)
    return np.linalg.norm(q - (a + t[..., None] * ab), axis=-1)


def distance_to_curves(query: np.ndarray, curves: Sequence[np.ndarray], closed: Sequence[bool],
                       upper: float = np.inf) -> np.ndarray:
    """Distance from each point ``query (q, 2)`` to the nearest of the polylines -> ``(q,) float``.

    Exact: the nearest of the fine search points (every <= 0.05 px) is found with a k-d tree, then the
    distance to the two segments beside it is taken. Points farther than ``upper`` get ``inf`` (faster);
    with no curves every distance is ``inf``."""
    from scipy.spatial import cKDTree

    q = np.asarray(query, dtype=np.float64).reshape(-1, 2)
    pts, nxt = _densify(curves, closed)
    if len(pts) == 0 or len(q) == 0:
        return np.full(len(q), np.inf)
    prv = np.full(len(pts), -1)
    has = nxt >= 0
    prv[nxt[has]] = np.nonzero(has)[0]
    d, i = cKDTree(pts).query(q, distance_upper_bound=upper + _FINE)
    ok = np.isfinite(d)
    out = np.full(len(q), np.inf)
    best = d[ok]
    for nb in (nxt, prv):
        j = i[ok]
        k = nb[j]
        valid = k >= 0
        seg = _segment_distance(q[ok][valid], pts[j[valid]], pts[k[valid]])
        best[valid] = np.minimum(best[valid], seg)
    out[ok] = best
    out[out > upper] = np.inf
    return out


def match_points(pred: np.ndarray, true: np.ndarray, radius: float) -> int:
    """Number of one-to-one matches between points ``pred (p, 2)`` and ``true (t, 2)`` within ``radius``
    (the assignment that maximizes the number of matches, then minimizes their total distance)."""
    from scipy.optimize import linear_sum_assignment

    pred = np.asarray(pred, dtype=np.float64).reshape(-1, 2)
    true = np.asarray(true, dtype=np.float64).reshape(-1, 2)
    if len(pred) == 0 or len(true) == 0:
        return 0
    d = np.linalg.norm(pred[:, None] - true[None], axis=-1)
    # a pair beyond the radius costs more than any set of pairs within it: the matching count comes first
    cost = np.where(d <= radius, d, 1e3 * radius * (len(pred) + len(true)) + 1.0)
    r, c = linear_sum_assignment(cost)
    return int((d[r, c] <= radius).sum())


def stroke_mask(curves: Sequence[np.ndarray], closed: Sequence[bool], size: tuple[int, int],
                half_width: float) -> np.ndarray:
    """Pixels ``(H, W) bool`` whose centre lies within ``half_width`` of a polyline."""
    H, W = size
    yy, xx = np.mgrid[0:H, 0:W]
    centres = np.stack([xx.ravel() + 0.5, yy.ravel() + 0.5], axis=1)
    return (distance_to_curves(centres, curves, closed, upper=half_width) <= half_width).reshape(H, W)


def fill_mask(curves: Sequence[np.ndarray], size: tuple[int, int]) -> np.ndarray:
    """Pixels ``(H, W) bool`` whose centre is inside the closed outlines under the even-odd rule (how an
    outline tracer's nested paths, holes included, fill)."""
    from matplotlib.path import Path as MplPath

    H, W = size
    yy, xx = np.mgrid[0:H, 0:W]
    centres = np.stack([xx.ravel() + 0.5, yy.ravel() + 0.5], axis=1)
    inside = np.zeros(H * W, dtype=bool)
    for c in curves:
        if len(c) >= 3:
            inside ^= MplPath(np.asarray(c, dtype=np.float64)).contains_points(centres)
    return inside.reshape(H, W)


def iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two boolean masks of one shape (1 when both are empty)."""
    union = np.logical_or(a, b).sum()
    return float(np.logical_and(a, b).sum() / union) if union else 1.0


def estimate_half_width(ink: np.ndarray, length: float) -> float:
    """A stroke's half-width from its binarized area and its centre-line length: area / (2 length)."""
    return float((np.asarray(ink) > 0.5).sum() / max(2.0 * length, 1e-9))


def curve_length(curves: Sequence[np.ndarray], closed: Sequence[bool]) -> float:
    """Total length of the polylines in px."""
    total = 0.0
    for c, cl in zip(curves, closed):
        p = np.asarray(c, dtype=np.float64).reshape(-1, 2)
        if cl and len(p) > 1:
            p = np.concatenate([p, p[:1]])
        total += float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum()) if len(p) > 1 else 0.0
    return total


def _ratio(a: int, b: int) -> float:
    return a / b if b else float("nan")


def score(pred: Traced, true_curves: Sequence[np.ndarray], true_closed: Sequence[bool],
          true_junctions: np.ndarray, true_endpoints: np.ndarray, ink: np.ndarray) -> dict:
    """Every metric of one method on one drawing -> a flat dict.

    ``true_curves``: the exact curves' dense samples (spacing <= 0.25 px), one array per curve of the
    drawing's curve network; ``ink (H, W)`` in [0, 1]. An empty prediction scores precision, recall and F
    0 and a Chamfer distance of one diagonal (the worst case, so that a failure never looks good).
    Junction and endpoint precision / recall are NaN where undefined (0 / 0); the counts beside them let a
    table pool them over drawings."""
    H, W = ink.shape
    diag = math.hypot(H, W)
    samples_true = np.concatenate([np.asarray(c, dtype=np.float64).reshape(-1, 2) for c in true_curves])
    samples_pred = [resample(c, cl) for c, cl in zip(pred.curves, pred.closed)]
    samples_pred = np.concatenate(samples_pred) if samples_pred else np.zeros((0, 2))
    row: dict = {"curves_pred": len(pred.curves), "curves_true": len(true_curves)}
    if len(samples_pred):
        d_pt = distance_to_curves(samples_pred, true_curves, true_closed)
        d_tp = distance_to_curves(samples_true, pred.curves, pred.closed)
        chamfer = 0.5 * (d_pt.mean() + d_tp.mean())
    else:
        d_pt, d_tp, chamfer = np.zeros(0), np.full(len(samples_true), np.inf), diag
    row["chamfer_px"] = float(chamfer)
    row["chamfer_diag"] = float(chamfer / diag)
    for th in THRESHOLDS:
        tau = th * diag
        p = float((d_pt <= tau).mean()) if len(d_pt) else 0.0
        r = float((d_tp <= tau).mean())
        row[f"f@{100 * th:g}%"] = 2 * p * r / (p + r) if p + r > 0 else 0.0
        row[f"p@{100 * th:g}%"] = p
        row[f"r@{100 * th:g}%"] = r
    radius = POINT_RADIUS * diag
    for kind, got, want in (("junction", pred.junctions, true_junctions), ("endpoint", pred.endpoints, true_endpoints)):
        got = np.asarray(got, dtype=np.float64).reshape(-1, 2)
        want = np.asarray(want, dtype=np.float64).reshape(-1, 2)
        tp = match_points(got, want, radius)
        row[f"{kind}_tp"], row[f"{kind}_pred"], row[f"{kind}_true"] = tp, len(got), len(want)
        row[f"{kind}_p"], row[f"{kind}_r"] = _ratio(tp, len(got)), _ratio(tp, len(want))
    row["iou"] = iou(pred.strokes, ink > 0.5) if pred.strokes is not None else float("nan")
    return row
