"""Small vectorized helpers shared by the node formulas.

All of them keep values *and* derivatives finite at singular points (zero vectors, ``sqrt`` at 0),
because torch.func evaluates derivatives everywhere, including at sphere centers and box corners.
"""

from __future__ import annotations

import math

import torch

# Added under square roots: moves values by at most 1e-10 and keeps d sqrt / dx finite at 0.
EPS2 = 1e-20


def coord_major(p: torch.Tensor) -> torch.Tensor:
    """The same points ``(..., k)`` stored coordinate by coordinate (each ``p[..., i]`` contiguous).

    Node formulas work per coordinate; contiguous coordinates make each elementwise op about 3x
    faster than slicing interleaved ``(N, 3)`` rows.
    """
    if p.dim() < 2 or p.movedim(-1, 0).is_contiguous():
        return p
    return p.movedim(-1, 0).contiguous().movedim(0, -1)


def stack_coords(cols) -> torch.Tensor:
    """Inverse of unbinding the last axis, keeping the coordinate-major layout."""
    return torch.stack(list(cols), 0).movedim(0, -1)


def rotate_points(p: torch.Tensor, R: torch.Tensor) -> torch.Tensor:
    """``p @ R`` for points ``(..., 3)``, computed as ``R^T @ p^T`` to keep the coordinate-major layout."""
    pc = p.movedim(-1, 0)
    flat = pc.reshape(3, -1)
    return (R.T @ flat).reshape(pc.shape).movedim(0, -1)


def safe_sqrt(x: torch.Tensor) -> torch.Tensor:
    """``sqrt(x + EPS2)`` for ``x >= 0`` (sums of squares): finite value and gradient at 0."""
    return torch.sqrt(x + EPS2)


def length(v: torch.Tensor) -> torch.Tensor:
    """Euclidean norm over the last axis, ``(..., k) -> (...)``, with a finite gradient at 0.

    One fused kernel; torch's norm derivatives are defined as 0 at the zero vector.
    """
    return torch.linalg.vector_norm(v, dim=-1)


def length2(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Norm of the 2-vector ``(x, y)`` given as two tensors (avoids stacking)."""
    return safe_sqrt(torch.addcmul(x * x, y, y))


def length3(x: torch.Tensor, y: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
    """Norm of the 3-vector ``(x, y, z)`` given as three tensors, with a finite gradient at 0 (:func:`safe_sqrt`)."""
    return safe_sqrt(torch.addcmul(torch.addcmul(x * x, y, y), z, z))


def relu(x: torch.Tensor) -> torch.Tensor:
    """``max(x, 0)``."""
    return torch.clamp(x, min=0.0)


def box_combine(*d: torch.Tensor) -> torch.Tensor:
    """Exact box-style combination of per-axis signed extents ``d_i``.

    ``length(max(d, 0)) + min(max_i d_i, 0)`` — the core of Quilez's ``sdBox`` (exact).
    """
    r = [relu(di) for di in d]
    sq = r[0] * r[0]
    for ri in r[1:]:
        sq = torch.addcmul(sq, ri, ri)
    outside = safe_sqrt(sq)
    inside = d[0]
    for di in d[1:]:
        inside = torch.maximum(inside, di)
    return outside + torch.clamp(inside, max=0.0)


def like(x: torch.Tensor, value: float) -> torch.Tensor:
    """A 0-dim constant with ``x``'s dtype and device.

    Multiplying a 0-dim tensor by a Python float gives a float64 *tangent* under torch's forward-mode
    AD even for float32 inputs (seen with torch 2.13), which then breaks dtype-strict ops such as
    matmul. Constants made with this helper keep tangents in the input's dtype.
    """
    return torch.tensor(value, dtype=x.dtype, device=x.device)


def deg2rad(a):
    """Degrees to radians, for a tensor (constant in its dtype, see :func:`like`) or a Python number."""
    return a * like(a, math.pi / 180.0) if torch.is_tensor(a) else a * (math.pi / 180.0)


def axis_from_tilt(tilt_deg, azimuth_deg):
    """Unit axis: +Y tilted by ``tilt`` towards the XZ direction at ``azimuth`` (degrees)."""
    t, a = deg2rad(tilt_deg), deg2rad(azimuth_deg)
    return torch.sin(t) * torch.cos(a), torch.cos(t), torch.sin(t) * torch.sin(a)


def rotation_matrix(axis, angle_deg) -> torch.Tensor:
    """Rodrigues rotation about a unit axis (three scalar tensors) by an angle in degrees: (3, 3)."""
    x, y, z = axis
    a = deg2rad(angle_deg)
    c, s = torch.cos(a), torch.sin(a)
    C = like(c, 1.0) - c
    return torch.stack([
        torch.stack([c + x * x * C, x * y * C - z * s, x * z * C + y * s]),
        torch.stack([y * x * C + z * s, c + y * y * C, y * z * C - x * s]),
        torch.stack([z * x * C - y * s, z * y * C + x * s, c + z * z * C]),
    ])


def polygon_sdf(px: torch.Tensor, py: torch.Tensor, verts: list[tuple]) -> torch.Tensor:
    """Exact signed distance to a closed simple polygon (Quilez, "2D distance functions": sdPolygon).

    px, py: (...) point coordinates; verts: list of (x, y) scalar tensors, any orientation.
    Negative inside. Zero-length edges are harmless (their projection parameter is guarded).
    """
    n = len(verts)
    vx0, vy0 = verts[0]
    dx0, dy0 = px - vx0, py - vy0
    d = dx0 * dx0 + dy0 * dy0
    s = torch.ones_like(px)
    for i in range(n):
        j = (i - 1) % n
        vix, viy = verts[i]
        vjx, vjy = verts[j]
        ex, ey = vjx - vix, vjy - viy
        wx, wy = px - vix, py - viy
        ee = torch.clamp(ex * ex + ey * ey, min=1e-24)
        t = torch.clamp((wx * ex + wy * ey) / ee, 0.0, 1.0)
        bx, by = wx - ex * t, wy - ey * t
        d = torch.minimum(d, bx * bx + by * by)
        c1 = py >= viy
        c2 = py < vjy
        c3 = ex * wy > ey * wx
        flip = (c1 & c2 & c3) | (~c1 & ~c2 & ~c3)
        s = torch.where(flip, -s, s)
    return s * safe_sqrt(d)
