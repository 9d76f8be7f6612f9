"""From the fitted field to a curve network: zero set, ink check, joining, crossings, junctions.

1. Each cell's own bicubic is sampled on a grid of ``samples`` points per pixel (on a border shared by
   cells whose copies differ: their mean) and the zero set traced by marching squares
   (``skimage.measure.find_contours``; Lorensen and Cline 1987).
2. Pieces are kept only where the image has ink along them (bilinear ink >= 1/2): zero crossings the fit
   left away from strokes are dropped, and a curve ends where its stroke ends. They are also cut where
   they run through a torn cell border (the copies there differ in sign): the fit ends curves by such
   sign flips, and inside a stroke they leave hooks along the border, not zeros of the field.
3. Piece ends are matched within ``join`` pixels and chained into polylines; open polylines whose ends
   point at each other (turning by at most 60 degrees) across a gap of up to two cells are joined by the
   cubic Hermite curve along their end directions, if it runs on ink (where the fit's field only touches
   zero, e.g. at the top of an arc, and leaves no zero crossing). Then free ends within two cells of each
   other are joined whatever their turn where ink connects them (:func:`join_corners`: a sharp corner of
   an outline, where the fit ends both sides short of the corner), and crumbs shorter than 2 r beside
   other curves are dropped.
4. The polylines become a graph: wherever two of them (or distant parts of one) come close (within 1.5 r,
   or within 2 r + 2 with ink all the way between them: the two branches of a crossing's saddle, which
   marching squares separates) every stretch of curve there is cut and shares one node; a free end
   within 2 r + 1 of another curve is snapped onto it (a T), else one that runs into another curve when
   extended by up to 4 r + 4 within 45 degrees of its direction, on ink (a T whose stem the fit ended
   short of the bar); nodes closer than r are merged; short spurs (< 2 r + 2, the overshoot of a T's stem
   through its bar) are pruned; junctions joined by an edge shorter than 2 r + 2 are merged into one.
5. Junctions are nodes of degree >= 3, placed where their arms' lines meet (a crossing: then at the
   centre of its ink), the arms redrawn straight near them; endpoints are nodes of degree 1 away from the
   image border, moved to r before the ink's end (a round cap inks r beyond its centreline). Curves run
   on through a junction along its most opposite pairs of arms: at an X both strokes stay whole curves
   that cross at the junction (as drawn by hand), at a T the bar stays one curve and the stem ends there.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ipm.curves.hermite import sample_cells_np


def global_samples(data: np.ndarray, cell: int, samples: int,
                   torn: float | None = None) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """The field on the whole grid at ``samples`` points per pixel, (Ny h s + 1, Nx h s + 1), each cell's
    own bicubic inside it and the mean of the cells that share a border point on it. With ``torn``: also
    where the grid is torn (bool, same shape): border points whose copies differ in sign by more than
    ``torn`` (a sign flip at a cell border, which the fit uses to end a curve, is no zero of the field)."""
    ny, nx = data.shape[:2]
    hs = cell * samples
    vals = sample_cells_np(data, hs + 1)
    total = np.zeros((ny * hs + 1, nx * hs + 1))
    count = np.zeros_like(total)
    hi = np.full_like(total, -np.inf)
    lo = np.full_like(total, np.inf)
    for cy in range(ny):
        for cx in range(nx):
            win = (slice(cy * hs, cy * hs + hs + 1), slice(cx * hs, cx * hs + hs + 1))
            total[win] += vals[cy, cx]
            count[win] += 1.0
            hi[win] = np.maximum(hi[win], vals[cy, cx])
            lo[win] = np.minimum(lo[win], vals[cy, cx])
    if torn is None:
        return total / count
    return total / count, (hi > 0) & (lo < 0) & (hi - lo > torn)


def on_ink(ink: np.ndarray, pts: np.ndarray, level: float = 0.5) -> np.ndarray:
    """Whether the bilinear ink at points (n, 2) (pixel coordinates) is >= ``level``: (n,) bool."""
    from scipy.ndimage import map_coordinates

    pts = np.asarray(pts, float).reshape(-1, 2)
    return map_coordinates(ink, [pts[:, 1] - 0.5, pts[:, 0] - 0.5], order=1, mode="nearest") >= level


def zero_pieces(data: np.ndarray, cell: int, samples: int, ink: np.ndarray, level: float = 0.5,
                torn: float | None = None) -> list[np.ndarray]:
    """The zero set of the field (marching squares on :func:`global_samples`, so that a curve running
    along a cell border is traced once), cut to where ``ink`` (H, W) >= ``level`` and, with ``torn``,
    cut where it runs through a torn cell border (:func:`global_samples`): a list of (n, 2) float64
    polylines in pixel coordinates; closed ones repeat their first point."""
    from skimage.measure import find_contours

    H, W = ink.shape
    if torn is None:
        grid = global_samples(data, cell, samples)
        bad = np.zeros(grid.shape, bool)
    else:
        grid, bad = global_samples(data, cell, samples, torn)
    grid, bad = grid[: H * samples + 1, : W * samples + 1], bad[: H * samples + 1, : W * samples + 1]
    pieces = []
    for c in find_contours(grid, 0.0):
        pts = np.stack([c[:, 1] / samples, c[:, 0] / samples], axis=1)
        good = on_ink(ink, pts, level)
        if bad.any():  # a contour point lies on a grid edge: torn if either end of the edge is
            r0, c0 = np.floor(c).astype(int).T
            r1, c1 = np.minimum(r0 + 1, grid.shape[0] - 1), np.minimum(c0 + 1, grid.shape[1] - 1)
            exact_r, exact_c = c[:, 0] == r0, c[:, 1] == c0
            good &= ~(bad[r0, c0] | (bad[r1, c0] & ~exact_r) | (bad[r0, c1] & ~exact_c))
        if len(pts) > 2 and np.allclose(pts[0], pts[-1]) and good.all():
            pieces.append(pts)
            continue
        edges = np.flatnonzero(np.diff(np.concatenate([[0], good.astype(np.int8), [0]])))
        for a, b in zip(edges[::2], edges[1::2], strict=True):
            if b - a >= 2:
                pieces.append(pts[a:b])
    return pieces


def _is_closed(p: np.ndarray) -> bool:
    return len(p) > 3 and bool(np.allclose(p[0], p[-1]))


def chain(pieces: list[np.ndarray], join: float) -> list[tuple[np.ndarray, bool]]:
    """Pieces joined end to end where ends lie within ``join`` pixels (closest pairs first):
    [(points (n, 2), closed)]."""
    from scipy.spatial import cKDTree

    curves: list[tuple[np.ndarray, bool]] = [(p, True) for p in pieces if _is_closed(p)]
    open_ = [p for p in pieces if not _is_closed(p)]
    if not open_:
        return curves
    ends = np.array([p[k] for p in open_ for k in (0, -1)])  # end 2i: start of piece i, 2i+1: its end
    pairs = sorted(cKDTree(ends).query_pairs(join, output_type="ndarray").tolist(),
                   key=lambda ab: float(np.sum((ends[ab[0]] - ends[ab[1]]) ** 2)))
    mate = -np.ones(len(ends), int)
    for a, b in pairs:
        if mate[a] < 0 and mate[b] < 0 and a // 2 != b // 2:
            mate[a], mate[b] = b, a
    seen = np.zeros(len(open_), bool)

    def walk(end: int) -> list[np.ndarray]:
        """Pieces from the piece of ``end`` onwards, leaving it through its other end."""
        out = []
        while True:
            i = end // 2
            if seen[i]:
                break
            seen[i] = True
            p = open_[i] if end % 2 == 0 else open_[i][::-1]
            out.append(p if not out else p[1:])
            nxt = mate[end ^ 1]
            if nxt < 0:
                break
            end = nxt
        return out

    for i in range(len(open_)):
        if seen[i]:
            continue
        fwd = walk(2 * i)
        closed = mate[2 * i] >= 0 and seen[mate[2 * i] // 2] and mate[2 * i] // 2 == _last(fwd, open_)
        back = [] if closed or mate[2 * i] < 0 else walk(mate[2 * i])
        parts = [q[::-1] for q in reversed(back)] + fwd
        pts = np.concatenate(parts) if parts else fwd[0]
        if closed:
            pts = np.concatenate([pts, pts[:1]])
        curves.append((pts, bool(closed)))
    return curves


def _last(parts: list[np.ndarray], open_: list[np.ndarray]) -> int:
    """Index of the piece the last of ``parts`` came from (matched by its final point)."""
    last = parts[-1][-1]
    for i, p in enumerate(open_):
        if np.array_equal(p[0], last) or np.array_equal(p[-1], last):
            return i
    return -1


def _hermite_bridge(qa: np.ndarray, ta: np.ndarray, qb: np.ndarray, tb: np.ndarray) -> np.ndarray:
    """The cubic Hermite curve from ``qa`` leaving along ``ta`` to ``qb`` arriving against ``tb`` (both
    outward unit directions of the ends it joins), tangents scaled by the gap: (n, 2), ends included,
    samples about 0.25 pixel apart."""
    d = float(np.linalg.norm(qb - qa))
    t = np.linspace(0.0, 1.0, max(int(np.ceil(d / 0.25)), 1) + 1)[:, None]
    h00, h01, h10, h11 = 2 * t**3 - 3 * t**2 + 1, -2 * t**3 + 3 * t**2, t**3 - 2 * t**2 + t, t**3 - t**2
    return h00 * qa + h01 * qb + h10 * (d * ta) - h11 * (d * tb)


def _free_ends(curves: list[tuple[np.ndarray, bool]],
               direction: Callable[[np.ndarray], np.ndarray]) -> list[tuple[int, int, np.ndarray, np.ndarray]]:
    """The ends of the open curves of two points or more: (curve, side (0 its first point, 1 its last),
    the end point (2,), ``direction(q)``: the outward unit direction (2,) of the polyline ``q`` (n, 2) that
    ends there)."""
    ends = []
    for k, (p, closed) in enumerate(curves):
        if closed or len(p) < 2:
            continue
        for side in (0, 1):
            q = p if side == 1 else p[::-1]
            ends.append((k, side, q[-1], direction(q)))
    return ends


def _chord_direction(q: np.ndarray) -> np.ndarray:
    """The outward unit direction (2,) at the end q[-1] of a polyline: from its point about 3 pixels back."""
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(q[::-1], axis=0), axis=1))])
    j = min(int(np.searchsorted(s, 3.0)), len(q) - 1)
    out = q[-1] - q[::-1][j]
    return out / (np.linalg.norm(out) + 1e-12)


def _closest_pair(ends: list[tuple], curves: list[tuple[np.ndarray, bool]], reach: float, refused: set[tuple],
                  fits: Callable[[tuple, tuple, np.ndarray, float], bool] | None = None) -> tuple | None:
    """The closest pair of free ``ends`` (:func:`_free_ends`) less than ``reach`` apart that ``fits(end x,
    end y, gap vector y - x, distance)`` accepts, whose points are not ``refused`` and which are not the
    two ends of one curve shorter than 4 ``reach``: (distance, end x, end y), or None."""
    best = None
    for x in range(len(ends)):
        for y in range(x + 1, len(ends)):
            v = ends[y][2] - ends[x][2]
            d = float(np.linalg.norm(v))
            if not d < reach or (fits is not None and not fits(ends[x], ends[y], v, d)):
                continue
            if ends[x][0] == ends[y][0] and _length(curves[ends[x][0]][0]) < 4.0 * reach:
                continue
            if (tuple(ends[x][2]), tuple(ends[y][2])) in refused:
                continue
            if best is None or d < best[0]:
                best = (d, ends[x], ends[y])
    return best


def bridge_gaps(curves: list[tuple[np.ndarray, bool]], bridge: float,
                ink: np.ndarray | None = None) -> list[tuple[np.ndarray, bool]]:
    """Open curves whose ends lie within ``bridge`` pixels and point at each other (outward directions
    within 60 degrees of the gap) joined, closest pairs first; a curve joined to itself is closed. Without
    ``ink`` the join is a straight segment; with ``ink`` (H, W) it is the cubic Hermite curve along both
    end directions, and only gaps it crosses on ink (>= 1/2) between ends that turn by at most 60 degrees
    are joined (where the fit left a stroke's zero crossing out, e.g. a cell whose field only touches
    zero, not the arms of a junction)."""
    curves = [(np.asarray(p, float), c) for p, c in curves]
    refused: set[tuple] = set()

    def fits(ex: tuple, ey: tuple, v: np.ndarray, d: float) -> bool:
        if ink is not None and ex[3] @ ey[3] > -0.5:
            return False  # a turn of over 60 degrees: rather the two sides of a T or a corner
        return 0 < d and ex[3] @ v > 0.5 * d and ey[3] @ -v > 0.5 * d

    while True:
        best = _closest_pair(_free_ends(curves, _chord_direction), curves, bridge, refused, fits)
        if best is None:
            return curves
        _, (ka, sa, qa, ta), (kb, sb, qb, tb) = best
        link = np.zeros((0, 2))
        if ink is not None:
            link = _hermite_bridge(qa, ta, qb, tb)
            if not on_ink(ink, link).all():
                refused.add((tuple(qa), tuple(qb)))
                continue
            link = link[1:-1]
        curves = _joined(curves, ka, sa, kb, sb, link)


def _end_direction(q: np.ndarray, r: float) -> np.ndarray:
    """The outward unit direction at the end q[-1] of a polyline: the chord between its points about 1
    and 1 + 3 r pixels back (past the hook a torn cell border may leave at the very end)."""
    back = q[::-1]
    s = _arc(back)
    a, b = _at(back, s, min(1.0, 0.2 * s[-1])), _at(back, s, min(1.0 + 3.0 * r, 0.6 * s[-1]))
    d = a - b
    return d / (np.linalg.norm(d) + 1e-12)


def _polyline(*pts: np.ndarray, step: float = 0.25) -> np.ndarray:
    """Straight segments through ``pts``, sampled about ``step`` apart (ends included)."""
    out = [np.asarray(pts[0], float)[None]]
    for a, b in zip(pts[:-1], pts[1:], strict=True):
        n = max(int(np.ceil(np.linalg.norm(b - a) / step)), 1)
        t = np.linspace(0.0, 1.0, n + 1)[1:, None]
        out.append(a * (1 - t) + b * t)
    return np.concatenate(out)


def join_corners(curves: list[tuple[np.ndarray, bool]], reach: float, r: float,
                 ink: np.ndarray) -> list[tuple[np.ndarray, bool]]:
    """Free ends within ``reach`` pixels of each other joined where ink connects them, whatever their
    turn (after :func:`bridge_gaps`, which joins ends that point at each other): a sharp corner of an
    outline, where the fit ends both sides a little before the corner (a kink of the zero set, or a sign
    flip at a cell border), or the top of an arc whose field only touches zero. The join is the first
    of these that runs on ink (>= 1/2): the two end directions extended to where they meet (a corner),
    the cubic Hermite curve along them (a smooth turn), the straight segment; closest pairs first, a
    curve joined to itself is closed. Before that, open curves shorter than 2 r lying within 2 r + 1 of
    other curves are dropped (crumbs of the zero set at a corner or junction, not strokes)."""
    from scipy.spatial import cKDTree

    curves = [(np.asarray(p, float), c) for p, c in curves]
    dropped: set[int] = set()
    for k, (p, closed) in enumerate(curves):
        others = [q for j, (q, _) in enumerate(curves) if j != k and j not in dropped]
        if not closed and others and _length(p) < 2.0 * r:
            if cKDTree(np.concatenate(others)).query(p)[0].max() <= 2.0 * r + 1.0:
                dropped.add(k)
    curves = [c for k, c in enumerate(curves) if k not in dropped]
    refused: set[tuple] = set()
    while True:
        best = _closest_pair(_free_ends(curves, lambda q: _end_direction(q, r)), curves, reach, refused)
        if best is None:
            return curves
        d, (ka, sa, qa, ta), (kb, sb, qb, tb) = best
        options = []
        m = np.stack([ta, -tb], axis=1)
        if abs(np.linalg.det(m)) > 0.1:
            ua, ub = np.linalg.solve(m, qb - qa)
            if 0.0 < ua <= d + 2.0 * r and 0.0 < ub <= d + 2.0 * r:
                options.append(_polyline(qa, qa + ua * ta, qb))
        options += [_hermite_bridge(qa, ta, qb, tb), _polyline(qa, qb)]
        link = next((o for o in options if on_ink(ink, o).all()), None)
        if link is None:
            refused.add((tuple(qa), tuple(qb)))
            continue
        link = link[1:-1]
        curves = _joined(curves, ka, sa, kb, sb, link)


def _joined(curves: list, ka: int, sa: int, kb: int, sb: int, link: np.ndarray) -> list:
    """``curves`` with the end ``sa`` of curve ``ka`` joined through the points ``link`` to the end ``sb`` of
    curve ``kb`` (0: its first point, 1: its last); one curve's two ends joined close it."""
    pa = curves[ka][0] if sa == 1 else curves[ka][0][::-1]
    if ka == kb:
        out = list(curves)
        out[ka] = (np.concatenate([pa, link, pa[:1]]), True)
        return out
    pb = curves[kb][0] if sb == 0 else curves[kb][0][::-1]
    return [c for i, c in enumerate(curves) if i not in (ka, kb)] + [(np.concatenate([pa, link, pb]), False)]


def resample(pts: np.ndarray, spacing: float, closed: bool = False) -> np.ndarray:
    """A polyline (n, 2) resampled at equal arc length of about ``spacing`` pixels (ends kept)."""
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    if s[-1] <= 1e-9:
        return pts[:1].copy()
    m = max(int(np.ceil(s[-1] / spacing)), 3 if closed else 1)
    t = np.linspace(0.0, s[-1], m + 1)
    return np.stack([np.interp(t, s, pts[:, 0]), np.interp(t, s, pts[:, 1])], axis=1)


def _length(p: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())


class _Nodes:
    """Union-find over node ids with a position each."""

    def __init__(self) -> None:
        self.parent: list[int] = []
        self.pos: list[np.ndarray] = []

    def add(self, xy: np.ndarray) -> int:
        """A new node at ``xy``, its own set; returns its id."""
        self.parent.append(len(self.parent))
        self.pos.append(np.asarray(xy, float))
        return len(self.parent) - 1

    def find(self, a: int) -> int:
        """The set's root of node ``a`` (with path halving)."""
        while self.parent[a] != a:
            self.parent[a] = self.parent[self.parent[a]]
            a = self.parent[a]
        return a

    def union(self, a: int, b: int) -> None:
        """Join the sets of ``a`` and ``b`` (``a``'s root stays the root)."""
        a, b = self.find(a), self.find(b)
        if a != b:
            self.parent[b] = a


def network(curves: list[tuple[np.ndarray, bool]], half_width: float, size: tuple[int, int],
            spacing: float = 0.5, ink: np.ndarray | None = None
            ) -> tuple[list[tuple[np.ndarray, bool]], np.ndarray, np.ndarray]:
    """The graph of step 4-5 of the module docstring: (curves [(points, closed)], junctions (j, 2),
    endpoints (e, 2)). With ``ink`` (H, W): two curves (or distant parts of one) also touch where they
    come within 2 r + 2 with ink all the way between them (the two branches of a crossing's saddle),
    junctions are placed where their arms' lines meet, and free ends are trimmed to the ink's end."""
    from scipy.spatial import cKDTree

    r = half_width
    touch, snap, merge, spur = max(1.0, 1.5 * r), 2.0 * r + 1.0, max(1.5, r), 2.0 * r + 2.0
    extend = 4.0 * r + 4.0
    reach = touch if ink is None else max(touch, 2.0 * r + 2.0)
    curves = [(resample(p, spacing, c), c) for p, c in curves if _length(p) > spacing]
    if not curves:
        return [], np.zeros((0, 2)), np.zeros((0, 2))
    smp = _Samples(curves, spacing)
    nodes = _Nodes()
    cuts: list[dict[int, int]] = [{} for _ in curves]  # per curve: sample index -> node id
    _cut_crossings(smp, _close_pairs(smp, reach, touch, r, ink), nodes, cuts, reach)
    _cut_free_ends(smp, nodes, cuts, snap, extend, r, ink)
    if len(nodes.pos) > 1:
        for a, b in cKDTree(np.array(nodes.pos)).query_pairs(merge):
            nodes.union(a, b)
    edges, loops = _cut_edges(curves, cuts, nodes)
    pos = _node_positions(nodes)
    for e in edges:
        e[2] = e[2].copy()
        e[2][0], e[2][-1] = pos[e[0]], pos[e[1]]
    edges = [e for e in edges if not (e[0] == e[1] and _length(e[2]) < 2.0 * merge)]
    edges = _contract(_prune(edges, spur), pos, spur)
    deg = _degrees(edges)
    junctions, endpoints = _place_nodes(edges, pos, deg, size, reach, r, ink)
    out = [(q, True) for q in loops] + _through(edges, pos, deg, r)
    return out, junctions, endpoints


class _Samples:
    """The samples of all curves in one array: ``allpts`` (n, 2) float64 with their KD-tree, and per
    sample its curve (``owner``, (n,) int) and its index along that curve (``index``, (n,) int)."""

    def __init__(self, curves: list[tuple[np.ndarray, bool]], spacing: float) -> None:
        from scipy.spatial import cKDTree

        self.curves, self.spacing = curves, spacing
        self.owner = np.concatenate([np.full(len(p), k) for k, (p, _) in enumerate(curves)])
        self.index = np.concatenate([np.arange(len(p)) for p, _ in curves])
        self.allpts = np.concatenate([p for p, _ in curves])
        self.tree = cKDTree(self.allpts)

    def apart(self, a, b, gap: float):
        """Samples a and b lie on different curves, or more than ``gap`` apart along one (the short way
        round a closed one): bool, for arrays of sample indices or ints."""
        curves, owner, index = self.curves, self.owner, self.index
        a, b = np.asarray(a), np.asarray(b)
        d = np.abs(index[a] - index[b])
        n = np.array([len(curves[k][0]) - 1 if curves[k][1] else 0 for k in range(len(curves))])[owner[a]]
        d = np.where(n > 0, np.minimum(d, n - d), d)
        return (owner[a] != owner[b]) | (d * self.spacing > gap)


def _close_pairs(smp: _Samples, reach: float, touch: float, r: float,
                 ink: np.ndarray | None) -> list[tuple[int, int]]:
    """Pairs of samples within ``reach`` of each other that lie apart (:meth:`_Samples.apart`, by more than
    4 reach + 2 r): with ``ink``, those farther than ``touch`` only where ink runs all the way between them
    (a crossing's saddle, not two strokes passing close)."""
    allpts = smp.allpts
    pairs = smp.tree.query_pairs(reach, output_type="ndarray").reshape(-1, 2)
    pairs = pairs[smp.apart(pairs[:, 0], pairs[:, 1], 4.0 * reach + 2.0 * r)]
    if len(pairs) and ink is not None:
        gap = np.linalg.norm(allpts[pairs[:, 0]] - allpts[pairs[:, 1]], axis=1)
        f = np.linspace(0.0, 1.0, 7)[None, :, None]
        seg = allpts[pairs[:, 0]][:, None] * (1 - f) + allpts[pairs[:, 1]][:, None] * f
        inked = on_ink(ink, seg.reshape(-1, 2)).reshape(len(pairs), -1).all(axis=1)
        pairs = pairs[(gap <= touch) | inked]
    return [tuple(ab) for ab in pairs.tolist()]


def _cut_crossings(smp: _Samples, pairs: list[tuple[int, int]], nodes: _Nodes, cuts: list[dict[int, int]],
                   reach: float) -> None:
    """Crossings and touchings: the close ``pairs`` clustered (linked by a shared sample), one node per
    cluster at the midpoint of its closest pair, and every stretch of curve in the cluster cut there
    (``cuts`` updated: curve -> {sample index: node id})."""
    if not pairs:
        return
    allpts, owner, index = smp.allpts, smp.owner, smp.index
    uf = _Nodes()
    ids: dict[int, int] = {}
    for a, b in pairs:
        for t in (a, b):
            if t not in ids:
                ids[t] = uf.add(allpts[t])
        uf.union(ids[a], ids[b])
    best: dict[int, tuple[float, int, int]] = {}
    for a, b in pairs:
        root = uf.find(ids[a])
        d = float(np.linalg.norm(allpts[a] - allpts[b]))
        if root not in best or d < best[root][0]:
            best[root] = (d, a, b)
    members: dict[int, list[int]] = {}
    for t, i in ids.items():
        members.setdefault(uf.find(i), []).append(t)
    for root, (_, a, b) in best.items():
        # every stretch of curve in the cluster is cut at its sample nearest the node (a crossing's
        # saddle may leave three or four pieces there, not two)
        at = 0.5 * (allpts[a] + allpts[b])
        nid = nodes.add(at)
        group = np.array(sorted(members[root], key=lambda t: (owner[t], index[t])))
        split = np.flatnonzero((np.diff(owner[group]) != 0) | (np.diff(index[group]) * smp.spacing > 2.0 * reach))
        for run in np.split(group, split + 1):
            t = run[np.argmin(np.linalg.norm(allpts[run] - at, axis=1))]
            cuts[owner[t]][int(index[t])] = nid


def _cut_free_ends(smp: _Samples, nodes: _Nodes, cuts: list[dict[int, int]], snap: float, extend: float,
                   r: float, ink: np.ndarray | None) -> None:
    """Free ends not cut yet: a node each, moved onto the nearest sample of another curve within ``snap``
    (or, with ``ink``, onto the one it runs into when extended: :func:`_ray_hit`), which is cut there
    and shares the node."""
    allpts, owner, index = smp.allpts, smp.owner, smp.index
    for k, (p, closed) in enumerate(smp.curves):
        if closed:
            continue
        first = int(np.flatnonzero(owner == k)[0])
        for i in (0, len(p) - 1):
            if i in cuts[k]:
                continue
            nid = nodes.add(p[i])
            cuts[k][i] = nid
            near = [s for s in smp.tree.query_ball_point(p[i], snap) if smp.apart(first + i, s, 2.0 * snap)]
            s = None
            if near:
                s = min(near, key=lambda s: float(np.sum((allpts[s] - p[i]) ** 2)))
            elif ink is not None:
                s = _ray_hit(p if i else p[::-1], first + i, smp.tree, allpts, smp.apart, extend, r, ink)
            if s is not None:
                ko, io = int(owner[s]), int(index[s])
                nodes.pos[nid] = allpts[s].copy()
                if io in cuts[ko]:
                    nodes.union(cuts[ko][io], nid)
                else:
                    cuts[ko][io] = nid


def _cut_edges(curves: list[tuple[np.ndarray, bool]], cuts: list[dict[int, int]],
               nodes: _Nodes) -> tuple[list[list], list[np.ndarray]]:
    """The curves cut at their ``cuts``: edges [node a, node b, points (n, 2)] between consecutive cuts
    (around a closed curve: also from its last cut to its first), and the closed curves without a cut
    (loops, their points)."""
    edges: list[list] = []
    loops: list[np.ndarray] = []
    for k, (p, closed) in enumerate(curves):
        q = p
        cut = {i: nodes.find(n) for i, n in cuts[k].items()}
        idx = sorted(cut)
        if not idx:
            loops.append(q)
            continue
        if closed:
            body = q[:-1]
            m = len(body)
            for a, b in zip(idx, idx[1:] + [idx[0] + m], strict=True):
                seg = body[np.arange(a, b + 1) % m]
                edges.append([cut[a], cut[b % m], seg])
        else:
            for a, b in zip(idx[:-1], idx[1:], strict=True):
                edges.append([cut[a], cut[b], q[a:b + 1]])
    return edges, loops


def _node_positions(nodes: _Nodes) -> dict[int, np.ndarray]:
    """Each merged node (its root) at the mean of the positions merged into it: {root: (2,) float64}."""
    pos = {nodes.find(i): None for i in range(len(nodes.pos))}
    for root in pos:
        members = [np.asarray(nodes.pos[i]) for i in range(len(nodes.pos)) if nodes.find(i) == root]
        pos[root] = np.mean(members, axis=0)
    return pos


def _prune(edges: list[list], spur: float) -> list[list]:
    """Short spurs (shorter than ``spur``) hanging off junctions removed, and the shorter of two short edges
    joining the same nodes (a bubble: the zero set touching a cell border twice), up to four passes."""
    for _ in range(4):
        deg = _degrees(edges)
        keep = [e for e in edges if not (_length(e[2]) < spur and (
            (deg[e[0]] == 1 and deg[e[1]] >= 3) or (deg[e[1]] == 1 and deg[e[0]] >= 3)))]
        by_pair: dict[frozenset, list] = {}
        for e in keep:
            by_pair.setdefault(frozenset((e[0], e[1])), []).append(e)
        drop = set()
        for group in by_pair.values():
            if len(group) > 1:
                group = sorted(group, key=lambda e: _length(e[2]))
                drop.update(id(e) for e in group[:-1] if _length(e[2]) < 2.0 * spur)
        keep = [e for e in keep if id(e) not in drop]
        if len(keep) == len(edges):
            break
        edges = keep
    return edges


def _place_nodes(edges: list[list], pos: dict, deg: dict[int, int], size: tuple[int, int], reach: float,
                 r: float, ink: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """With ``ink``: junctions placed where their arms meet (:func:`_place_junction`) and free ends away
    from the image border trimmed to the ink (:func:`_trim_end`), ``pos`` and ``edges`` updated. Returns
    the junctions (j, 2) (degree >= 3) and the endpoints (e, 2) (degree 1, farther than r + 1.5 from the
    border), float64."""
    H, W = size
    border = r + 1.5
    if ink is not None:
        for n, dn in deg.items():
            if dn >= 3:
                pos[n] = _place_junction(edges, n, pos[n], reach, r, ink)
            elif dn == 1 and border < pos[n][0] < W - border and border < pos[n][1] < H - border:
                pos[n] = _trim_end(edges, n, ink, r)
    junctions = [pos[n] for n, d in deg.items() if d >= 3]
    endpoints = [pos[n] for n, d in deg.items() if d == 1 and border < pos[n][0] < W - border
                 and border < pos[n][1] < H - border]
    return np.array(junctions).reshape(-1, 2), np.array(endpoints).reshape(-1, 2)


def _ray_hit(q: np.ndarray, end: int, tree, allpts: np.ndarray, apart, extend: float, r: float,
             ink: np.ndarray) -> int | None:
    """The sample of another curve (or of a distant part of this one) that the free end q[-1] (sample
    ``end``) runs into when extended straight by up to ``extend`` pixels within 45 degrees of its
    direction (the zero set of a stem often bends along the bar before it ends), on ink all the way (a T
    whose stem the fit ended short of the bar): the nearest such sample, or None."""
    out = _end_direction(q, r)
    cand = np.array([s for s in tree.query_ball_point(q[-1], extend) if apart(end, s, 2.0 * extend)], int)
    if not len(cand):
        return None
    v = allpts[cand] - q[-1]
    along = v @ out
    across = np.abs(v[:, 0] * out[1] - v[:, 1] * out[0])
    ok = (along > 0) & (across <= np.maximum(0.5, along))
    for s in cand[ok][np.argsort(np.hypot(along[ok], across[ok]))]:
        if on_ink(ink, _polyline(q[-1], allpts[s])).all():
            return int(s)
    return None


def _contract(edges: list[list], pos: dict, short: float) -> list[list]:
    """Junctions joined by an edge shorter than ``short`` merged into one (at their mean), shortest
    first: where several strokes meet, their ends snap onto each other at points a pixel or two apart,
    which are one junction of the drawing, not a cluster of junctions of degree 3."""
    while True:
        deg = _degrees(edges)
        short_ = [e for e in edges if e[0] != e[1] and deg[e[0]] >= 3 and deg[e[1]] >= 3
                  and _length(e[2]) < short]
        if not short_:
            return edges
        a, b, _ = min(short_, key=lambda e: _length(e[2]))
        pos[a] = 0.5 * (pos[a] + pos[b])
        out = []
        for e in edges:
            if {e[0], e[1]} == {a, b} and _length(e[2]) < short:
                continue
            e = [a if e[0] == b else e[0], a if e[1] == b else e[1], e[2].copy()]
            out.append(e)
        for e in out:
            if e[0] == a:
                e[2][0] = pos[a]
            if e[1] == a:
                e[2][-1] = pos[a]
        edges = [e for e in out if not (e[0] == e[1] and _length(e[2]) < short)]


def _arms(edges: list[list], n: int) -> list[tuple[list, int]]:
    """The edge ends at node ``n``: [(edge, 0 start | 1 end)] (a loop at n counts twice)."""
    return [(e, side) for e in edges for side in (0, 1) if e[side] == n]


def _outward(e: list, side: int) -> np.ndarray:
    return e[2] if side == 0 else e[2][::-1]


def _set_outward(e: list, side: int, pts: np.ndarray) -> None:
    e[2] = pts if side == 0 else pts[::-1]


def _arc(p: np.ndarray) -> np.ndarray:
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])


def _at(p: np.ndarray, s: np.ndarray, t: float) -> np.ndarray:
    return np.array([np.interp(t, s, p[:, 0]), np.interp(t, s, p[:, 1])])


def _place_junction(edges: list[list], n: int, guess: np.ndarray, reach: float, r: float,
                    ink: np.ndarray) -> np.ndarray:
    """A junction where the lines of its arms meet (least squares; the arms' directions are read
    between ``reach`` and ``reach`` + 2 r + 3 from the node, beyond the bend of a saddle's branches),
    kept within ``reach`` of ``guess``; where four arms meet (a crossing, point-symmetric) it then moves
    to the centre of the ink within ``reach`` (mean shift), which the arms' bends do not bias. Each arm
    long enough is then redrawn as a straight segment from the junction to its point at ``reach``."""
    arms = _arms(edges, n)
    lines = []
    for e, side in arms:
        p = _outward(e, side)
        s = _arc(p)
        if s[-1] > 2.0 * reach + 1.0:
            a, b = _at(p, s, reach), _at(p, s, min(reach + 2.0 * r + 3.0, s[-1] - reach))
            d = b - a
            if np.linalg.norm(d) > 1e-6:
                lines.append((a, d / np.linalg.norm(d)))
    at = np.asarray(guess, float)
    if len(lines) >= 2:
        M, rhs = np.zeros((2, 2)), np.zeros(2)
        for a, d in lines:
            proj = np.eye(2) - np.outer(d, d)
            M += proj
            rhs += proj @ a
        if np.linalg.eigvalsh(M)[0] > 0.1 * len(lines):
            x = np.linalg.solve(M, rhs)
            if np.linalg.norm(x - at) < reach:
                at = x
    if len(arms) == 4:
        at = _ink_centre(ink, at, reach, np.asarray(guess, float))
    for e, side in arms:
        p = _outward(e, side)
        s = _arc(p)
        if s[-1] > 2.0 * reach + 1.0:
            k = int(np.searchsorted(s, reach))
            p = np.concatenate([[at], p[k:]])
        else:
            p = p.copy()
            p[0] = at
        _set_outward(e, side, p)
    return at


def _ink_centre(ink: np.ndarray, start: np.ndarray, radius: float, anchor: np.ndarray) -> np.ndarray:
    """Mean shift of the ink (pixel values as weights) in a disk of ``radius`` from ``start``; ``start``
    if it wanders more than ``radius`` from ``anchor``."""
    H, W = ink.shape
    at = start.copy()
    for _ in range(20):
        x0, x1 = max(int(at[0] - radius), 0), min(int(at[0] + radius) + 2, W)
        y0, y1 = max(int(at[1] - radius), 0), min(int(at[1] + radius) + 2, H)
        yy, xx = np.mgrid[y0:y1, x0:x1] + 0.5
        wgt = ink[y0:y1, x0:x1] * ((xx - at[0]) ** 2 + (yy - at[1]) ** 2 <= radius * radius)
        if wgt.sum() <= 0:
            return start
        new = np.array([(wgt * xx).sum(), (wgt * yy).sum()]) / wgt.sum()
        done = np.linalg.norm(new - at) < 1e-3
        at = new
        if done:
            break
    return at if np.linalg.norm(at - anchor) < radius else start


def _trim_end(edges: list[list], n: int, ink: np.ndarray, r: float) -> np.ndarray:
    """A free end moved to where its stroke's centreline ends: r before the ink (>= 1/2) ends along the
    end's direction (a round cap of half-width r inks r beyond its centreline), cutting the curve back
    (by at most half its length) or extending it straight."""
    (e, side), = _arms(edges, n)
    p = _outward(e, side)
    s = _arc(p)
    if s[-1] < 1.0:
        return p[0]
    out = p[0] - _at(p, s, min(3.0 * r, s[-1]))
    out = out / (np.linalg.norm(out) + 1e-12)
    u = np.arange(0.0, 3.0 * r + 3.0, 0.1)
    line = p[0] + u[:, None] * out
    H, W = ink.shape
    inside = (line[:, 0] > 0) & (line[:, 0] < W) & (line[:, 1] > 0) & (line[:, 1] < H)
    off = np.flatnonzero(~on_ink(ink, line) | ~inside)
    if not len(off) or not inside[off[0]]:
        return p[0]  # the ink runs on (or off the image): leave the end
    move = u[off[0]] - r  # > 0: extend, < 0: cut back
    if move >= 0:
        p = np.concatenate([[p[0] + move * out], p])
    else:
        cut = min(-move, 0.5 * s[-1])
        k = int(np.searchsorted(s, cut))
        p = np.concatenate([[_at(p, s, cut)], p[k:]]) if k < len(p) else p[-2:]
    _set_outward(e, side, p)
    return p[0]


def _degrees(edges: list[list]) -> dict[int, int]:
    deg: dict[int, int] = {}
    for a, b, _ in edges:
        deg[a] = deg.get(a, 0) + 1
        deg[b] = deg.get(b, 0) + 1
    return deg


def _through(edges: list[list], pos: dict, deg: dict[int, int], r: float) -> list[tuple[np.ndarray, bool]]:
    """Edges merged into curves through nodes of degree 2, and through nodes of degree 4 along the most
    opposite pairs of arms."""
    ends: dict[int, list[tuple[int, int]]] = {}  # node -> [(edge, 0 start | 1 end)]
    for k, (a, b, _) in enumerate(edges):
        ends.setdefault(a, []).append((k, 0))
        ends.setdefault(b, []).append((k, 1))

    def direction(k: int, side: int) -> np.ndarray:
        p = edges[k][2] if side == 0 else edges[k][2][::-1]
        s = np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))
        j = min(int(np.searchsorted(s, 3.0 * r)) + 1, len(p) - 1)
        v = p[j] - p[0]
        return v / (np.linalg.norm(v) + 1e-12)

    link: dict[tuple[int, int], tuple[int, int]] = {}
    for arms in ends.values():
        if len(arms) == 2:
            link[arms[0]], link[arms[1]] = arms[1], arms[0]
        elif len(arms) == 3:  # a T: the bar runs on through the junction, the stem ends there
            d = [direction(*a) for a in arms]
            i, j = min(((0, 1), (0, 2), (1, 2)), key=lambda o: float(d[o[0]] @ d[o[1]]))
            if float(d[i] @ d[j]) < -0.85:
                link[arms[i]], link[arms[j]] = arms[j], arms[i]
        elif len(arms) == 4:
            d = [direction(*a) for a in arms]
            options = [((0, 1), (2, 3)), ((0, 2), (1, 3)), ((0, 3), (1, 2))]
            best = min(options, key=lambda o: sum(float(d[i] @ d[j]) for i, j in o))
            for i, j in best:
                link[arms[i]], link[arms[j]] = arms[j], arms[i]
    used = np.zeros(len(edges), bool)
    out = []

    def follow(k: int, side: int) -> tuple[list[np.ndarray], bool]:
        """Walk from edge k entered at ``side``; (pieces, closed)."""
        parts = []
        start = (k, side)
        while True:
            used[k] = True
            p = edges[k][2] if side == 0 else edges[k][2][::-1]
            parts.append(p if not parts else p[1:])
            nxt = link.get((k, 1 - side))
            if nxt is None:
                return parts, False
            if nxt == start:
                return parts, True
            if used[nxt[0]]:
                return parts, False
            k, side = nxt
    # open chains start at ends without a link; what is left are loops
    for k in range(len(edges)):
        for side in (0, 1):
            if not used[k] and (k, side) not in link:
                parts, _ = follow(k, side)
                out.append((np.concatenate(parts), False))
    for k in range(len(edges)):
        if not used[k]:
            parts, closed = follow(k, 0)
            out.append((np.concatenate(parts), closed))
    return out
