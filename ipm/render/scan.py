"""Scan conversion of projected triangles: which pixel centers lie within a distance of each triangle.

Shared by both rasterizers: the hard z-buffer (:mod:`ipm.render.raster`, distance 0: the triangle's own
span on each row) and the soft silhouette (:mod:`ipm.render.soft`, distance = the blur radius).

For every image row a triangle's box (expanded by the distance) crosses, the *run* of pixel centers
within that distance of the triangle is computed exactly (offset edges and vertex disks,
:func:`_line_extents`); triangles fully outside the image have no runs. Runs are cut into pieces and
grouped by length, each group padded to one size ``K`` (:data:`PIECE_SIZES`), so a renderer does a few
dense ``(K, pieces)`` evaluations and no Python loop per triangle (:class:`PixelRows`). Pieces may run
past the right image edge: renderers pad their pixel buffers to ``width + K`` columns.

Also here: the input check of mesh tensors and the projection of the triangles in front of a camera,
which both rasterizers start with.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch

from ipm.errors import InputError
from ipm.render.camera import project
from ipm.types import Camera

# Piece lengths: every run of pixels is cut into pieces of at most the largest size, and each piece is
# padded to the smallest size that holds it; sizes with few pairs are merged into the next larger one.
PIECE_SIZES = (4, 6, 8, 10, 12, 14, 16, 20, 24, 32, 48, 64)
MERGE_BELOW = 0.03  # a size class with less than this share of the pairs joins the next larger class


@dataclass(frozen=True)
class PixelRows:
    """Pieces of ``k`` consecutive pixels on one image row, each tied to one triangle.

    tri: (R,) int64 index of the piece's triangle (into the kept triangles); j: (R,) int64 image row;
    i: (R,) int64 first column (the piece covers columns i .. i + k - 1, possibly past the image's right
    edge: callers pad their pixel buffers to ``width + k`` columns); n: (R,) int64 pixels of the piece
    inside its run (<= k); k: pixels per piece.
    """

    tri: torch.Tensor
    j: torch.Tensor
    i: torch.Tensor
    n: torch.Tensor
    k: int

    @property
    def n_rows(self) -> int:
        return int(self.tri.shape[0])

    @property
    def n_pairs(self) -> int:
        """Evaluated (pixel, triangle) pairs, padding included."""
        return self.n_rows * self.k


DENSE_LINES = (8, 12, 16)  # triangles crossing at most this many image rows use a dense layout


def _line_extents(edge: torch.Tensor, yc: torch.Tensor, pad: torch.Tensor, push: torch.Tensor):
    """Exact x-extent, on the lines ``y = yc``, of the triangles dilated by a disk of radius ``pad``.

    The boundary of a triangle dilated by a disk is made of its edges offset by ``pad`` along their
    normals and of arcs around its vertices, so the extent on a line is the extreme of the offset edges
    (both sides: the inner offset also lies in the dilated set) and the vertex disks that the line
    crosses. With ``pad = 0`` this is the triangle's own span.

    edge: (N, 1, 3, 7) per triangle and edge: start x, start y, dx, dy, 1/dy (0 for flat edges),
    pad * unit normal (x, y); yc: (N, M) row centers; pad, push: 0-dim, the radius and a distance larger
    than any coordinate. Returns (xmin, xmax), (N, M) each (xmin > xmax where the line misses)."""
    px, py, dx, dy, inv_dy, nx, ny = edge.unbind(-1)  # (N, 1, 3)
    y = yc[..., None]  # (N, M, 1)
    # vertex disks
    dv = py - y
    h2 = pad * pad - dv * dv
    miss = (h2 < 0).to(yc.dtype) * push
    h = h2.clamp_min(0.0).sqrt_()
    xmin = (px - h + miss).amin(-1)
    xmax = (px + h - miss).amax(-1)
    # offset edges (flat ones are covered by their end points' disks)
    flat = (dy == 0).to(yc.dtype) * push
    for sgn in (1.0, -1.0):
        s = (y - (py + sgn * ny)) * inv_dy
        miss = ((s < 0) | (s > 1)).to(yc.dtype) * push + flat
        x = torch.addcmul(px + sgn * nx, s.clamp_(0.0, 1.0), dx)
        xmin = torch.minimum(xmin, (x + miss).amin(-1))
        xmax = torch.maximum(xmax, (x - miss).amax(-1))
    return xmin, xmax


def span_rows(tri_xy: torch.Tensor, pad: float, width: int, height: int,
              backend: str = "eager") -> tuple[list[PixelRows], torch.Tensor]:
    """The pixel centers within ``pad`` pixels of each projected triangle, as runs along image rows.

    For every image row that the triangle's box (expanded by ``pad``) crosses, the run spans the pixel
    centers within distance ``pad`` of the triangle on that row, exactly (see :func:`_line_extents`).
    With ``pad = 0`` it is the triangle's span on that row (for hard rasterization). Runs are cut into
    pieces grouped by padded length (PIECE_SIZES).

    tri_xy: (F, 3, 2) float screen coordinates. Returns ``(groups, kept)``: one :class:`PixelRows` per
    piece size, and ``kept`` (F,) bool marking the triangles with at least one piece (``tri`` in the
    groups indexes the kept triangles). backend: "eager" or "compiled" (see :func:`soft_silhouette`).
    """
    with torch.no_grad():
        t = tri_xy.detach()
        dev, dt = t.device, t.dtype
        extents = _extents(backend)
        big = float(max(width, height) + 2) + pad
        # only guard non-finite values: clamping vertices would move edges that cross the image border
        far = 1e3 * big
        pad_t = torch.tensor(pad, dtype=dt, device=dev)
        push = torch.tensor(4 * far, dtype=dt, device=dev)
        t = t.nan_to_num(far, far, -far).clamp(-far, far)
        xs, ys = t[..., 0], t[..., 1]
        j0 = torch.ceil(ys.amin(1) - pad - 0.5).long().clamp_min(0)
        j1 = torch.floor(ys.amax(1) + pad - 0.5).long().clamp_max(height - 1)
        inx = (xs.amax(1) + pad >= 0.5) & (xs.amin(1) - pad <= width - 0.5)
        nlines = (j1 - j0 + 1).clamp_min(0) * inx
        # per edge (start p, end q): its y-range, and x as p + s (q - p) with s = (y - py) / dy (stable for
        # nearly flat edges; flat edges take s = 0: their end point is the next edge's start, still seen)
        d = t.roll(-1, dims=1) - t
        dx, dy = d[..., 0], d[..., 1]
        inv_dy = 1.0 / torch.where(dy == 0, torch.ones_like(dy), dy) * (dy != 0)
        scale = pad / torch.linalg.vector_norm(d, dim=-1).clamp_min(1e-30)
        edge = torch.stack([xs, ys, dx, dy, inv_dy, dy * scale, -dx * scale], -1)[:, None]  # (F, 1, 3, 7)
        lines = []  # (triangle, row, first column, last column + 1) per line, (L,) each
        # small triangles: dense (F1, M) layouts, no per-line gathers
        lo = 0
        for m_lines in DENSE_LINES:
            small = torch.nonzero((nlines > lo) & (nlines <= m_lines)).squeeze(1)
            lo = m_lines
            if small.numel():
                m = torch.arange(m_lines, device=dev)
                rows = j0[small, None] + m  # (F1, M)
                xmin, xmax = extents(edge[small], rows.to(dt) + 0.5, pad_t, push)
                ok = (m < nlines[small, None])
                lines.append(_runs(small[:, None].expand_as(rows), rows, xmin, xmax, ok, width, big))
        large = torch.nonzero(nlines > DENSE_LINES[-1]).squeeze(1)
        if large.numel():
            nl = nlines[large]
            lsel = torch.repeat_interleave(torch.arange(large.shape[0], device=dev), nl)
            first = torch.cumsum(nl, 0) - nl
            lj = (j0[large] - first).index_select(0, lsel) + torch.arange(lsel.shape[0], device=dev)
            yc = (lj.to(dt) + 0.5)[:, None]
            xmin, xmax = extents(edge[large].index_select(0, lsel), yc, pad_t, push)
            tri_l = large.index_select(0, lsel)[:, None]
            lines.append(_runs(tri_l, lj[:, None], xmin, xmax, None, width, big))
        line = torch.cat(lines, 1) if lines else torch.zeros(4, 0, dtype=torch.long, device=dev)
        kept = torch.zeros(t.shape[0], dtype=torch.bool, device=dev)
        kept[line[0]] = True
        remap = torch.cumsum(kept.long(), 0) - 1
        line[0] = remap[line[0]]
        line = _pieces(line)
        cls = torch.bucketize(line[3], torch.tensor(PIECE_SIZES, device=dev))  # smallest size that holds it
        groups = []
        for (c0, c1), k in _merged_classes(cls):
            pick = torch.nonzero((cls >= c0) & (cls <= c1)).squeeze(1)
            g = line.index_select(1, pick)
            groups.append(PixelRows(g[0], g[1], g[2], g[3], int(k)))
    return groups, kept


def _pieces(line: torch.Tensor) -> torch.Tensor:
    """The runs ``line`` (4, L) (triangle, row, first column, end column) cut into pieces of at most the
    largest piece size, as (4, L') triangle, row, first column, piece length."""
    # runs longer than the largest piece are cut (rare: big triangles)
    dev = line.device
    kmax = PIECE_SIZES[-1]
    n = line[3] - line[2]
    long_ = n > kmax
    if bool(long_.any()):
        lng = line[:, long_]
        per = (lng[3] - lng[2] + kmax - 1) // kmax
        r = torch.repeat_interleave(torch.arange(lng.shape[1], device=dev), per)
        piece = torch.arange(r.shape[0], device=dev) - (torch.cumsum(per, 0) - per)[r]
        lng = lng[:, r]
        lng[2] += piece * kmax
        line = torch.cat([line[:, ~long_], lng], 1)
    line[3] = (line[3] - line[2]).clamp_max(kmax)  # piece length
    return line


def _runs(tri, rows, xmin, xmax, ok, width: int, big: float) -> torch.Tensor:
    """(4, L) triangle, row, first column, end column of the non-empty runs among (N, M) candidates."""
    i0 = torch.ceil(xmin.clamp(-2.0, big) - 0.5).long().clamp_min(0)
    i1 = torch.floor(xmax.clamp(-2.0, big) - 0.5).long().clamp_max(width - 1)
    keep = i1 >= i0 if ok is None else (i1 >= i0) & ok
    idx = torch.nonzero(keep.view(-1)).squeeze(1)
    return torch.stack([tri.expand_as(i0).reshape(-1), rows.expand_as(i0).reshape(-1), i0.view(-1),
                        i1.view(-1) + 1]).index_select(1, idx)


def _merged_classes(cls: torch.Tensor) -> list[tuple]:
    """Size classes to evaluate: ``((lo, hi), k)`` merges classes lo..hi into padded size k, so that no
    class holds less than MERGE_BELOW of the pairs (fewer, larger kernel calls)."""
    counts = torch.bincount(cls, minlength=len(PIECE_SIZES)).tolist()
    pairs = [c * k for c, k in zip(counts, PIECE_SIZES)]
    total = sum(pairs)
    out, lo, acc = [], None, 0
    for c in range(len(PIECE_SIZES)):
        if counts[c] == 0:
            continue
        lo = c if lo is None else lo
        acc += pairs[c]
        last = all(x == 0 for x in counts[c + 1:])
        if acc >= MERGE_BELOW * total or last:
            out.append(((lo, c), PIECE_SIZES[c]))
            lo, acc = None, 0
    return out


_EXTENTS: dict[str, Callable] = {"eager": _line_extents}


def _extents(backend: str) -> Callable:
    if backend not in _EXTENTS:
        _EXTENTS[backend] = torch.compile(_line_extents, dynamic=True)
    return _EXTENTS[backend]


def check_mesh_tensors(verts: torch.Tensor, faces: torch.Tensor) -> None:
    """``InputError`` unless verts is a float (V, 3) tensor and faces an integer (F, 3) tensor indexing it."""
    if not torch.is_tensor(verts) or verts.ndim != 2 or verts.shape[-1] != 3 or not verts.is_floating_point():
        raise InputError(f"verts: expected a float tensor (V, 3), got "
                         f"{tuple(verts.shape) if torch.is_tensor(verts) else type(verts).__name__}")
    if not torch.is_tensor(faces) or faces.ndim != 2 or faces.shape[-1] != 3 or faces.is_floating_point():
        raise InputError(f"faces: expected an integer tensor (F, 3), got "
                         f"{tuple(faces.shape) if torch.is_tensor(faces) else type(faces).__name__}")
    if faces.numel() and (int(faces.min()) < 0 or int(faces.max()) >= verts.shape[0]):
        raise InputError(f"faces: expected vertex indices in [0, {verts.shape[0]}), got "
                         f"[{int(faces.min())}, {int(faces.max())}]")


def visible_triangles(verts: torch.Tensor, faces: torch.Tensor, camera: Camera, near: float):
    """Projected triangles in front of the camera.

    Returns ``(tri_xy (F', 3, 2), tri_depth (F', 3), face_index (F',) int64)`` for the faces whose three
    vertices are at depth >= ``near`` (dtype and device of ``verts``; differentiable).
    """
    xy, depth = project(verts, camera.to(dtype=verts.dtype, device=verts.device))
    front = (depth[faces] >= near).all(1)
    fidx = torch.nonzero(front).squeeze(1)
    f = faces[fidx]
    return xy[f], depth[f], fidx

