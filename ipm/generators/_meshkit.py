"""Shared building blocks of the mesh generators: lofts (revolved profiles, swept tubes, boxes,
prisms), their face templates, and a differentiable Catmull-Rom spline.

Topology and geometry are kept apart. Face arrays depend only on counts (discrete values and the
level of detail) and are built once with NumPy and cached; vertex positions are vectorized torch
expressions of the continuous parameters, so ``torch.func.jacfwd`` and ``vmap`` work through them.

The loft is the one solid every part here is made of: ``L`` loops of ``k`` vertices each, optionally
closed by a *pole* (one extra vertex, a triangle fan) or a *fan* (the loop's own vertex 0) at either
end. Convention: every loop runs counter-clockwise about one axis ``a`` (right-hand rule); the faces
then point outwards when consecutive loops advance along ``+a`` on the outside of the solid and
along ``-a`` on the inside of a cavity, the first loop's cap faces ``-a`` and the last loop's ``+a``.
A revolved profile (axis +Y, loops = rings), a swept tube (axis = tangent), a box (axis +Y, two
loops) and a pocketed window (axis +Z, four loops) are all instances.

Speed under forward-mode AD. With torch 2.13, a binary op between a dual tensor (one carrying a
tangent inside ``jvp``/``jacfwd``) and a plain one - a constant tensor or a Python number, which
``x * 0.5`` wraps into a tensor - computes the missing tangent through Python reference
implementations: about 1 ms per op instead of ~20 us. Generators therefore scale and shift by numbers
with :func:`smul`, :func:`sadd` and :func:`ssub` (scalar overloads, no tangent needed), and turn
constant tensors into duals once with :func:`lift` before using them. Plain evaluation is unaffected.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Literal

import numpy as np
import torch
import torch.autograd.forward_ad as fwAD

from ipm.types import TriMesh

Cap = Literal["pole", "fan", "none"]
_aten = torch.ops.aten

# Catmull-Rom basis (uniform): p(t) = sum_i w_i(t) P_i over four consecutive control points.
_CR = 0.5 * np.array([[0.0, 2.0, 0.0, 0.0],
                      [-1.0, 0.0, 1.0, 0.0],
                      [2.0, -5.0, 4.0, -1.0],
                      [-1.0, 3.0, -3.0, 1.0]])        # rows: coefficients of 1, t, t^2, t^3


# ----------------------------------------------------------------------------------------------
# Arithmetic with constants that stays fast under forward-mode AD (see the module docstring)
# ----------------------------------------------------------------------------------------------

def smul(x: torch.Tensor, s: float) -> torch.Tensor:
    """``x * s`` for a Python number ``s``."""
    return _aten.mul.Scalar(x, s)


def sadd(x: torch.Tensor, s: float) -> torch.Tensor:
    """``x + s`` for a Python number ``s``."""
    return _aten.add.Scalar(x, s)


def ssub(s: float, x: torch.Tensor) -> torch.Tensor:
    """``s - x`` for a Python number ``s``."""
    return _aten.rsub.Scalar(x, s)


# private torch hooks; without them every constant is lifted (correct, a little slower)
_IS_WRAPPED = getattr(getattr(torch._C, "_functorch", None), "is_functorch_wrapped_tensor", None)


def _traced(like: torch.Tensor) -> bool:
    """True inside torch.func transforms or a torch.autograd.forward_ad dual level."""
    if _IS_WRAPPED is None:
        return True
    return _IS_WRAPPED(like) or getattr(fwAD, "_current_level", 0) >= 0


def lift(c: torch.Tensor, like: torch.Tensor) -> torch.Tensor:
    """The constant ``c`` (any shape) in ``like``'s dtype and device; inside torch.func transforms
    (or a forward-AD level) also a dual of ``like``'s level with a zero tangent, so that later ops
    with duals take the fast path. Outside them ``c`` itself may be returned: do not modify in place."""
    if c.dtype != like.dtype or c.device != like.device:
        c = c.to(dtype=like.dtype, device=like.device)
    if not _traced(like):
        return c
    return torch.cat([like.reshape(-1)[:0], c.reshape(-1)]).reshape(c.shape)


_NP_DTYPES = {torch.float32: np.float32, torch.float64: np.float64}


@lru_cache(maxsize=1024)
def _np_const(builder, args: tuple, dtype) -> np.ndarray:
    return np.ascontiguousarray(builder(*args), dtype=dtype)


def const(builder, *args, like: torch.Tensor) -> torch.Tensor:
    """A constant array ``builder(*args)`` (built once per dtype with NumPy and cached) as a tensor in
    ``like``'s dtype and device, lifted to its AD level (see :func:`lift`). ``builder`` must be a
    module-level function (it is part of the cache key). Do not modify the result in place."""
    t = torch.from_numpy(_np_const(builder, args, _NP_DTYPES.get(like.dtype, np.float64)))
    return lift(t, like)


def _plain(builder, args: tuple, dtype, device) -> torch.Tensor:
    """A cached constant as a plain tensor (not lifted): for matmuls, which take the fast path."""
    t = torch.from_numpy(_np_const(builder, args, _NP_DTYPES.get(dtype, np.float64)))
    if t.dtype == dtype and t.device == torch.device(device or "cpu"):
        return t
    return t.to(dtype=dtype, device=device)


def _cr_basis() -> np.ndarray:
    return _CR


def half_steps(n: int, scale: float = 1.0) -> np.ndarray:
    """``(i + 0.5) * scale`` for i < n."""
    return (np.arange(n) + 0.5) * scale


def steps(start: int, stop: int, scale: float = 1.0) -> np.ndarray:
    """``i * scale`` for start <= i < stop."""
    return np.arange(start, stop) * scale


def circle(segments: int) -> np.ndarray:
    """``(2, segments)``: cos and sin of ``segments`` evenly spaced angles from 0."""
    a = np.arange(segments) * (2.0 * math.pi / segments)
    return np.stack([np.cos(a), np.sin(a)])


def ring_dirs(segments: int) -> np.ndarray:
    """``(segments, 3)``: the unit directions ``(cos, 0, -sin)`` of a ring about +Y (counter-clockwise)."""
    c, s = circle(segments)
    return np.stack([c, np.zeros_like(c), -s], -1)


def unit(axis: int, n: int = 3) -> np.ndarray:
    """The ``axis``-th unit vector of length ``n``."""
    return np.eye(n)[axis]


# ----------------------------------------------------------------------------------------------
# Faces (NumPy, cached): depend on counts only
# ----------------------------------------------------------------------------------------------

def loft_faces(n_loops: int, k: int, start: Cap = "pole", end: Cap = "pole") -> torch.Tensor:
    """Faces ``(F, 3) int64`` of a loft of ``n_loops`` closed loops of ``k`` vertices.

    Vertex layout: ``[start pole] + loop 0 (k) + ... + loop L-1 (k) + [end pole]`` (poles only when
    the cap is ``"pole"``). ``"fan"`` closes a loop with a fan from its vertex 0 (the loop must be
    star-shaped from that vertex); ``"none"`` leaves it open. See the module docstring for the
    orientation convention. The returned tensor shares a cached array: do not modify it in place.
    """
    return torch.from_numpy(_loft_faces_np(n_loops, k, start, end))


@lru_cache(maxsize=256)
def _loft_faces_np(n_loops: int, k: int, start: Cap, end: Cap) -> np.ndarray:
    # NumPy arrays are cached, not tensors: a tensor first made inside a torch.func transform
    # cannot be reused outside it
    if n_loops < 1 or k < 3:
        raise ValueError(f"loft: expected at least 1 loop of at least 3 vertices, got {n_loops} x {k}")
    off = 1 if start == "pole" else 0
    j = np.arange(k)
    jn = (j + 1) % k
    tris = []
    if n_loops > 1:
        i = np.arange(n_loops - 1)[:, None]
        a = off + i * k + j                     # (L-1, k)
        b = off + i * k + jn
        c = off + (i + 1) * k + jn
        d = off + (i + 1) * k + j
        quads = np.stack([np.stack([a, b, c], -1), np.stack([a, c, d], -1)], 2)   # (L-1, k, 2, 3)
        tris.append(quads.reshape(-1, 3))
    first, last = off, off + (n_loops - 1) * k
    if start == "pole":
        tris.append(np.stack([np.zeros(k, dtype=np.int64), first + jn, first + j], -1))
    elif start == "fan":
        m = np.arange(1, k - 1)
        tris.append(np.stack([np.full(k - 2, first), first + m + 1, first + m], -1))
    if end == "pole":
        pole = off + n_loops * k
        tris.append(np.stack([np.full(k, pole), last + j, last + jn], -1))
    elif end == "fan":
        m = np.arange(1, k - 1)
        tris.append(np.stack([np.full(k - 2, last), last + m, last + m + 1], -1))
    out = np.concatenate(tris).astype(np.int64)
    return out


def loft_faces_np(n_loops: int, k: int, start: Cap = "pole", end: Cap = "pole") -> np.ndarray:
    """:func:`loft_faces` as a (cached, shared) NumPy array: safe to call inside torch.func transforms,
    where tensors made from NumPy cannot be turned back into arrays."""
    return _loft_faces_np(n_loops, k, start, end)


def loft_n_verts(n_loops: int, k: int, start: Cap = "pole", end: Cap = "pole") -> int:
    """Number of vertices of :func:`loft_faces`' layout."""
    return n_loops * k + (start == "pole") + (end == "pole")


def repeat_faces(template: tuple[tuple[int, int, int], ...] | None, n_verts: int, count: int,
                 n_loops: int = 0, k: int = 0, start: Cap = "fan", end: Cap = "fan") -> torch.Tensor:
    """Faces of ``count`` copies of one part with ``n_verts`` vertices each (copy i's vertices at
    ``i * n_verts``). The part is either an explicit ``template`` or a loft ``(n_loops, k, start, end)``.
    Returns ``(count * F, 3) int64`` (shares a cached array: do not modify in place)."""
    return torch.from_numpy(_repeat_faces_np(template, n_verts, count, n_loops, k, start, end))


@lru_cache(maxsize=256)
def _repeat_faces_np(template, n_verts, count, n_loops, k, start, end) -> np.ndarray:
    if template is not None:
        base = np.asarray(template, dtype=np.int64)
    else:
        base = _loft_faces_np(n_loops, k, start, end)
    offs = (np.arange(count, dtype=np.int64) * n_verts)[:, None, None]
    out = (base[None] + offs).reshape(-1, 3)
    return out


# ----------------------------------------------------------------------------------------------
# Vertices (torch, differentiable)
# ----------------------------------------------------------------------------------------------

def angles(segments: int, like: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``cos, sin`` of ``segments`` evenly spaced angles from 0, each ``(segments,)``, as constants
    like ``like`` (see :func:`const`)."""
    cs = const(circle, segments, like=like)
    return cs[0], cs[1]


def revolve_parts(r: torch.Tensor, y: torch.Tensor, segments: int, *, bottom: torch.Tensor | None = None,
                  top: torch.Tensor | None = None,
                  bulge: tuple[torch.Tensor, torch.Tensor] | None = None) -> list[torch.Tensor]:
    """Vertices of a profile revolved about +Y, in :func:`loft_faces` layout, as the list
    ``[bottom pole (1, 3)], rings (L * S, 3), [top pole (1, 3)]`` (concatenate them, or several
    parts' lists at once: one copy).

    r, y: (L,) float — profile points (radius > 0, height), ordered so that the outside of the
    solid is met going up (the loops run counter-clockwise about +Y: angle phi maps to
    ``(r cos phi, y, -r sin phi)``). bottom, top: (1,) heights of the pole vertices on the axis
    before and after the profile (None: no pole). bulge: optional ``(q (L,), w (S,))``: ring vertex
    (i, j) moves out by ``q_i * w_j``.
    """
    cs = const(ring_dirs, segments, like=r)                                # (S, 3)
    ey = const(unit, 1, like=r)
    rr = r[:, None] if bulge is None else torch.addcmul(r[:, None], bulge[0][:, None], bulge[1][None, :])
    ring = (rr[..., None] * cs + (y[:, None] * ey)[:, None, :]).reshape(-1, 3)
    parts = []
    if bottom is not None:
        parts.append(bottom[:, None] * ey)
    parts.append(ring)
    if top is not None:
        parts.append(top[:, None] * ey)
    return parts


def revolve(r: torch.Tensor, y: torch.Tensor, segments: int, **kw) -> torch.Tensor:
    """:func:`revolve_parts` concatenated: ``(L * S [+ poles], 3)``."""
    return torch.cat(revolve_parts(r, y, segments, **kw))


def tube(centers: torch.Tensor, normals: torch.Tensor, binormals: torch.Tensor, a: torch.Tensor,
         b: torch.Tensor, segments: int) -> torch.Tensor:
    """Vertices of a closed tube with elliptic sections, :func:`loft_faces` layout with poles.

    centers, normals, binormals: (S, 3) — section centers and unit axes, with
    ``normal x binormal = tangent`` (so the rings run counter-clockwise about the tangent);
    a, b: (S,) semi-axes along normal and binormal. Returns ``(S * segments + 2, 3)``; the end poles
    are the first and last centers.
    """
    c, s = angles(segments, a)
    ring = (centers[:, None, :] + (a[:, None] * c)[..., None] * normals[:, None, :]
            + (b[:, None] * s)[..., None] * binormals[:, None, :])
    return torch.cat([centers[:1], ring.reshape(-1, 3), centers[-1:]])


def box_verts(lo: torch.Tensor, hi: torch.Tensor) -> torch.Tensor:
    """Vertices of axis-aligned boxes ``[lo, hi]``, ``lo, hi: (B, 3)`` -> ``(8B, 3)``.

    Layout per box: bottom loop then top loop (a loft about +Y with fan caps; faces from
    :func:`box_faces`).
    """
    x0, y0, z0 = lo.unbind(-1)
    x1, y1, z1 = hi.unbind(-1)
    xs = torch.stack([x1, x1, x0, x0], -1)          # counter-clockwise about +Y
    zs = torch.stack([z1, z0, z0, z1], -1)
    ys = torch.stack([y0, y1], -1)                  # (B, 2)
    v = torch.stack([xs[:, None, :].expand(-1, 2, -1), ys[:, :, None].expand(-1, -1, 4),
                     zs[:, None, :].expand(-1, 2, -1)], -1)
    return v.reshape(-1, 3)


def box_faces(count: int) -> torch.Tensor:
    """Faces of ``count`` boxes from :func:`box_verts`, ``(12 count, 3) int64``."""
    return repeat_faces(None, 8, count, 2, 4, "fan", "fan")


def repeat_faces_np(template, n_verts: int, count: int, n_loops: int = 0, k: int = 0, start: Cap = "fan",
                    end: Cap = "fan") -> np.ndarray:
    """:func:`repeat_faces` as a (cached, shared) NumPy array."""
    return _repeat_faces_np(template, n_verts, count, n_loops, k, start, end)


# ----------------------------------------------------------------------------------------------
# Splines
# ----------------------------------------------------------------------------------------------

def catmull_rom(ctrl: torch.Tensor, u: torch.Tensor, *, start: torch.Tensor | None = None,
                end: torch.Tensor | None = None, derivative: bool = False):
    """Uniform Catmull-Rom spline through ``ctrl: (k, ...)`` at parameters ``u: (m,)`` in [0, 1].

    Control point i sits at ``u = i / (k - 1)`` and the curve passes through it. The phantom points
    before the first and after the last control point default to linear extrapolation
    (``2 P0 - P1``), which makes the spline reproduce straight lines exactly; ``start``/``end``
    override them. ``u`` may depend on parameters (the segment index is piecewise constant, the
    curve C1). Returns ``(m, ...)``, and with ``derivative`` also ``d/du`` of the same shape.
    """
    k = ctrl.shape[0]
    p0 = smul(ctrl[:1], 2.0) - ctrl[1:2] if start is None else start[None]
    pk = smul(ctrl[-1:], 2.0) - ctrl[-2:-1] if end is None else end[None]
    pad = torch.cat([p0, ctrl, pk])                                    # (k + 2, ...)
    s = smul(u, float(k - 1))
    seg = torch.clamp(torch.floor(s.detach()), 0, k - 2).long()        # (m,)
    t = s - lift(seg, s)
    idx = seg[:, None] + torch.arange(4, device=u.device)              # (m, 4) int64
    pts = pad[idx]                                                     # (m, 4, ...)
    basis = _plain(_cr_basis, (), u.dtype, u.device)                  # (4 powers, 4 points)
    tp = torch.stack([torch.ones_like(t), t, t * t, t * t * t], -1)    # (m, 4)
    w = tp @ basis                                                     # (m, 4)
    extra = (1,) * (pts.dim() - 2)
    val = (w.reshape(w.shape + extra) * pts).sum(1)
    if not derivative:
        return val
    dtp = torch.stack([torch.zeros_like(t), torch.ones_like(t), smul(t, 2.0), smul(t * t, 3.0)], -1)
    dw = smul(dtp @ basis, float(k - 1))
    return val, (dw.reshape(dw.shape + extra) * pts).sum(1)


@lru_cache(maxsize=64)
def _cr_pad_np(k: int, m: int, derivative: bool) -> np.ndarray:
    u = np.linspace(0.0, 1.0, m)
    s = u * (k - 1)
    seg = np.clip(np.floor(s), 0, k - 2).astype(int)
    t = s - seg
    if derivative:
        w = np.stack([np.zeros_like(t), np.ones_like(t), 2 * t, 3 * t * t], -1) @ _CR * (k - 1)
    else:
        w = np.stack([np.ones_like(t), t, t * t, t * t * t], -1) @ _CR
    M = np.zeros((m, k + 2))
    for q in range(4):
        np.add.at(M, (np.arange(m), seg + q), w[:, q])
    return M


def catmull_rom_pad_matrix(k: int, m: int, derivative: bool = False, dtype=torch.float64,
                           device=None) -> torch.Tensor:
    """``(m, k + 2)`` matrix evaluating the spline (or ``d/du`` with ``derivative``) at ``m`` evenly
    spaced parameters from 0 to 1 from the *padded* control points ``[phantom, P_0 .. P_k-1, phantom]``:
    ``values = M @ pad``. Fixed samples make the spline one matmul."""
    return _plain(_cr_pad_np, (k, m, derivative), dtype, device)


@lru_cache(maxsize=64)
def _cr_matrix_np(k: int, m: int) -> np.ndarray:
    E = np.zeros((k + 2, k))          # pad = E @ ctrl with the linear-extrapolation phantoms
    E[1:k + 1] = np.eye(k)
    E[0, 0], E[0, 1] = 2.0, -1.0
    E[k + 1, k - 1], E[k + 1, k - 2] = 2.0, -1.0
    return _cr_pad_np(k, m, False) @ E


def catmull_rom_matrix(k: int, m: int, dtype=torch.float64, device=None) -> torch.Tensor:
    """``(m, k)`` matrix evaluating :func:`catmull_rom` (default phantoms) at ``m`` evenly spaced
    parameters from 0 to 1: ``values = M @ ctrl``."""
    return _plain(_cr_matrix_np, (k, m), dtype, device)


def signed_volume(verts: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    """Signed volume ``()`` enclosed by a closed mesh (positive when faces point outwards)."""
    a, b, c = verts[faces[:, 0]], verts[faces[:, 1]], verts[faces[:, 2]]
    return smul((a * torch.linalg.cross(b, c)).sum(), 1.0 / 6.0)


@dataclass(frozen=True)
class Topology:
    """The faces of a generator's mesh for one set of discrete values and level of detail: built
    once, cached by the generator, reused for every parameter vector.

    faces: (F, 3) int64 and groups: (F,) int64 NumPy arrays; names: the group names; n_verts: the
    number of vertices the faces index.
    """

    faces: np.ndarray
    groups: np.ndarray
    names: tuple[str, ...]
    n_verts: int

    @staticmethod
    def build(faces: list, counts: list[int], names: list[str]) -> Topology:
        """From per-group faces (each indexing its group's vertices from 0; NumPy arrays inside
        torch.func transforms) and vertex counts."""
        out_f, out_g, off = [], [], 0
        for g, (f, n) in enumerate(zip(faces, counts)):
            f = f.numpy() if torch.is_tensor(f) else np.asarray(f, dtype=np.int64)
            out_f.append(f.reshape(-1, 3) + off)
            out_g.append(np.full(len(out_f[-1]), g, dtype=np.int64))
            off += n
        return Topology(np.concatenate(out_f), np.concatenate(out_g), tuple(names), off)

    def mesh(self, verts: list[torch.Tensor]) -> TriMesh:
        """A TriMesh from vertex pieces (concatenated once, in order)."""
        v = torch.cat(verts) if len(verts) > 1 else verts[0]
        if v.shape[0] != self.n_verts:
            raise ValueError(f"topology: expected {self.n_verts} vertices, got {v.shape[0]}")
        dev = v.device
        faces, groups = torch.from_numpy(self.faces).to(dev), torch.from_numpy(self.groups).to(dev)
        return TriMesh(v, faces, groups, self.names)


def assemble(verts: list[torch.Tensor], faces: list[torch.Tensor], counts: list[int],
             names: list[str]) -> TriMesh:
    """One TriMesh from vertex pieces and per-group faces (see :meth:`Topology.build`)."""
    return Topology.build(faces, counts, names).mesh(verts)
