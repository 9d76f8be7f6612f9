"""Small vectorized helpers shared by the node formulas.

All of them keep values *and* derivatives finite at singular points (zero vectors, ``sqrt`` at 0),
because torch.func evaluates derivatives everywhere, including at sphere centers and box corners.
"""

from __future__ import annotations

import math

import torch

# Added under square roots: moves values by at most 1e-10 and keeps d sqrt / dx finite at 0.
EPS2 = 1e-20


def safe_sqrt(x: torch.Tensor) -> torch.Tensor:
    """``sqrt(max(x, 0) + EPS2)``: finite value and gradient at 0."""
    return torch.sqrt(torch.clamp(x, min=0.0) + EPS2)


def length(v: torch.Tensor) -> torch.Tensor:
    """Euclidean norm over the last axis, ``(..., k) -> (...)``, with a finite gradient at 0."""
    return safe_sqrt((v * v).sum(-1))


def length2(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Norm of the 2-vector ``(x, y)`` given as two tensors (avoids stacking)."""
    return safe_sqrt(x * x + y * y)


def length3(x: torch.Tensor, y: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
    return safe_sqrt(x * x + y * y + z * z)


def relu(x: torch.Tensor) -> torch.Tensor:
    return torch.clamp(x, min=0.0)


def box_combine(*d: torch.Tensor) -> torch.Tensor:
    """Exact box-style combination of per-axis signed extents ``d_i``.

    ``length(max(d, 0)) + min(max_i d_i, 0)`` — the core of Quilez's ``sdBox`` (exact).
    """
    outside = safe_sqrt(sum(relu(di) ** 2 for di in d))
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
    d = (px - vx0) ** 2 + (py - vy0) ** 2
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
