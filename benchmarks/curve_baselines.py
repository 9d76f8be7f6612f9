"""Baselines for ``make table-curves``: what a user gets today from a skeleton and from potrace.

* :func:`skeleton_trace`: binarize (``ink > 0.5``), thin with ``skimage.morphology.skeletonize``, and walk
  the 8-connected skeleton as a graph (not ``find_contours``, whose contour of a one-pixel skeleton is a
  loop around both of its sides). A diagonal step is dropped where a 4-connected path covers it, so a
  pixel's degree means what it says: 1 at an endpoint, >= 3 at a junction. Junction pixels within
  :data:`JUNCTION_MERGE` px of each other are one junction (at their centroid); spurs shorter than
  :data:`SPUR` px that end freely are pruned (a junction left with two curves joins them); each curve's
  staircase is smoothed by a moving average over 5 pixels (ends kept). That is the baseline's fair chance.
* :func:`potrace_outline`: the ``potracer`` package (a pure-Python port of potrace 1.16) with its default
  settings traces the *outlines* of the binarized strokes as closed Bezier paths -- what potrace gives a
  user; it finds no junctions or endpoints. Its re-rendering is the even-odd fill of the outlines.

Both return a :class:`~benchmarks.curve_metrics.Traced` record (curves as point arrays).
"""

from __future__ import annotations

import math

import numpy as np

from benchmarks.curve_metrics import Traced, curve_length, estimate_half_width, fill_mask, stroke_mask

JUNCTION_MERGE = 3.0     # px
SPUR = 6.0               # px
SMOOTH = 5               # pixels in the moving average


def _neighbours(sk: np.ndarray) -> dict[tuple[int, int], list[tuple[int, int]]]:
    """The skeleton's pixels and their neighbours: 4-neighbours, and diagonal ones not already reached
    through a 4-neighbour that both share."""
    H, W = sk.shape

    def on(r, c):
        return 0 <= r < H and 0 <= c < W and sk[r, c]

    nb = {}
    for r, c in zip(*np.nonzero(sk)):
        r, c = int(r), int(c)
        out = [(r + dr, c + dc) for dr, dc in ((-1, 0), (1, 0), (0, -1), (0, 1)) if on(r + dr, c + dc)]
        out += [(r + dr, c + dc) for dr, dc in ((-1, -1), (-1, 1), (1, -1), (1, 1))
                if on(r + dr, c + dc) and not on(r + dr, c) and not on(r, c + dc)]
        nb[(r, c)] = out
    return nb


def _clusters(points: list[tuple[int, int]], radius: float) -> dict[tuple[int, int], int]:
    """Single-linkage clusters of pixels within ``radius`` -> pixel: cluster id."""
    from scipy.spatial import cKDTree

    parent = list(range(len(points)))

    def find(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    if points:
        for i, j in cKDTree(np.array(points, dtype=float)).query_pairs(radius):
            parent[find(i)] = find(j)
    roots = {}
    return {p: roots.setdefault(find(i), len(roots)) for i, p in enumerate(points)}


def _smooth(p: np.ndarray, closed: bool, window: int = SMOOTH) -> np.ndarray:
    if len(p) < window:
        return p
    k = np.ones(window) / window
    h = window // 2
    if closed:
        q = np.concatenate([p[-h:], p, p[:h]])
        return np.stack([np.convolve(q[:, i], k, "valid") for i in range(2)], axis=1)
    out = p.copy()
    out[h:-h] = np.stack([np.convolve(p[:, i], k, "valid") for i in range(2)], axis=1)
    return out


def _length(path: list) -> float:
    a = np.asarray(path, dtype=float)
    return float(np.linalg.norm(np.diff(a, axis=0), axis=1).sum()) if len(a) > 1 else 0.0


def skeleton_graph(binary: np.ndarray) -> tuple[list, list, dict]:
    """The skeleton of ``binary (H, W) bool`` as a graph -> (edges, loops, junction centres).

    edges: ``(a, b, pixels)`` with ``a``, ``b`` node keys (``("j", k)`` for junction cluster k, ``("e",
    pixel)`` for an endpoint) and ``pixels`` the (row, col) path between them; loops: pixel cycles with no
    node; junction centres: ``k -> (row, col)`` float."""
    from skimage.morphology import skeletonize

    nb = _neighbours(skeletonize(binary))
    junction_px = [p for p, n in nb.items() if len(n) >= 3]
    cluster = _clusters(junction_px, JUNCTION_MERGE)
    centres = {}
    for p, k in cluster.items():
        centres.setdefault(k, []).append(p)
    centres = {k: tuple(np.mean(v, axis=0)) for k, v in centres.items()}

    def key(p):
        if p in cluster:
            return ("j", cluster[p])
        return ("e", p) if len(nb[p]) != 2 else None

    used, seen, edges = set(), set(), []
    for start in nb:
        if key(start) is None:
            continue
        for first in nb[start]:
            if (start, first) in used:
                continue
            path, prev, cur = [start, first], start, first
            used.add((start, first))
            while key(cur) is None:
                seen.add(cur)
                nxt = [q for q in nb[cur] if q != prev]
                if not nxt:
                    break
                prev, cur = cur, nxt[0]
                path.append(cur)
            used.add((cur, prev))
            a, b = key(start), key(cur)
            if a == b and a is not None and a[0] == "j" and _length(path) < 4 * JUNCTION_MERGE:
                continue                     # a step inside one junction cluster
            edges.append([a, b, path])
    loops = []
    for p in nb:
        if key(p) is None and p not in seen:
            loop, prev, cur = [p], None, p
            seen.add(p)
            while True:
                nxt = [q for q in nb[cur] if q != prev and q not in seen]
                if not nxt:
                    break
                prev, cur = cur, nxt[0]
                seen.add(cur)
                loop.append(cur)
            if len(loop) > 2:
                loops.append(loop)
    return _prune(edges), loops, centres


def _prune(edges: list) -> list:
    """Drop short free-ended spurs at junctions, then join the two curves at a junction left with two."""
    def degree(node):
        return sum((e[0] == node) + (e[1] == node) for e in edges)

    edges = [e for e in edges if not (
        _length(e[2]) < SPUR and ((e[0][0] == "j" and e[1][0] == "e") or (e[1][0] == "j" and e[0][0] == "e"))
        and degree(e[0] if e[0][0] == "j" else e[1]) >= 3)]
    changed = True
    while changed:
        changed = False
        for node in {e[0] for e in edges} | {e[1] for e in edges}:
            if node[0] != "j" or degree(node) != 2:
                continue
            two = [e for e in edges if node in (e[0], e[1])]
            if len(two) != 2 or two[0] is two[1]:
                continue
            a, b = two
            pa = a[2] if a[1] == node else a[2][::-1]        # ... -> node
            pb = b[2] if b[0] == node else b[2][::-1]        # node -> ...
            ea = a[0] if a[1] == node else a[1]
            eb = b[1] if b[0] == node else b[0]
            edges = [e for e in edges if e is not a and e is not b] + [[ea, eb, pa + pb[1:]]]
            changed = True
            break
    return edges


def skeleton_trace(ink: np.ndarray) -> Traced:
    """Skeleton + graph tracing baseline on ``ink (H, W) float`` in [0, 1]."""
    binary = np.asarray(ink) > 0.5
    edges, loops, centres = skeleton_graph(binary)

    def xy(rc):
        return np.array([rc[1] + 0.5, rc[0] + 0.5])

    def node_xy(node, pixel):
        return xy(centres[node[1]]) if node[0] == "j" else xy(pixel)

    curves, closed, ends = [], [], []
    for a, b, path in edges:
        p = np.array([xy(q) for q in path])
        if a == b and a[0] == "j":           # a loop through one junction
            p[0] = p[-1] = node_xy(a, path[0])
        else:
            p[0], p[-1] = node_xy(a, path[0]), node_xy(b, path[-1])
        curves.append(_smooth(p, False))
        closed.append(False)
        ends += [node_xy(n, q) for n, q in ((a, path[0]), (b, path[-1])) if n[0] == "e"]
    for loop in loops:
        curves.append(_smooth(np.array([xy(q) for q in loop]), True))
        closed.append(True)
    used = {n[1] for e in edges for n in e[:2] if n[0] == "j"}
    junctions = np.array([xy(centres[k]) for k in sorted(used)]).reshape(-1, 2)
    ends_arr = np.unique(np.array(ends).reshape(-1, 2), axis=0)
    hw = estimate_half_width(ink, curve_length(curves, closed))
    strokes = stroke_mask(curves, closed, binary.shape, hw)
    return Traced(tuple(curves), tuple(closed), junctions, ends_arr, strokes)


def _cubic(p0, p1, p2, p3, step: float = 0.1) -> np.ndarray:
    c = np.array([p0, p1, p2, p3], dtype=float)
    n = max(2, math.ceil(np.linalg.norm(np.diff(c, axis=0), axis=1).sum() / step))
    t = np.linspace(0.0, 1.0, n + 1)[1:, None]
    return (1 - t) ** 3 * c[0] + 3 * (1 - t) ** 2 * t * c[1] + 3 * (1 - t) * t ** 2 * c[2] + t ** 3 * c[3]


def potrace_outline(ink: np.ndarray) -> Traced:
    """potrace (``potracer``, default settings) on the binarized strokes: closed outline curves."""
    import potrace

    binary = np.asarray(ink) > 0.5
    # potracer's Bitmap inverts what it is given (dark = foreground): hand it the background
    path = potrace.Bitmap(~binary).trace()
    curves = []
    for curve in path:
        pts = [np.array([curve.start_point.x, curve.start_point.y])]
        for seg in curve:
            end = np.array([seg.end_point.x, seg.end_point.y])
            if seg.is_corner:
                pts += [np.array([seg.c.x, seg.c.y]), end]
            else:
                pts += list(_cubic(pts[-1], (seg.c1.x, seg.c1.y), (seg.c2.x, seg.c2.y), end))
        p = np.array(pts)
        if len(p) > 1 and np.allclose(p[0], p[-1]):
            p = p[:-1]
        curves.append(p)
    strokes = fill_mask(curves, binary.shape)
    return Traced(tuple(curves), (True,) * len(curves), np.zeros((0, 2)), np.zeros((0, 2)), strokes)
