"""The slow, readable reference soft rasterizer: every pixel against every triangle, no culling.

The fast :func:`ipm.render.soft.soft_silhouette` must match it (tests/test_render_soft.py).
Same formula (SoftRas): D = sigmoid(s * d^2 / sigma), s = +1 inside the projected triangle and -1 outside,
d the distance from the pixel center to the triangle's boundary, silhouette = 1 - prod(1 - D).
"""

from __future__ import annotations

import torch

from ipm.render.camera import project
from ipm.types import Camera


def point_segment_dist2(p: torch.Tensor, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Squared distance from points p (P, 1, 2) to segments a-b (1, F, 2): (P, F)."""
    e = b - a
    t = ((p - a) * e).sum(-1) / (e * e).sum(-1).clamp_min(1e-300)
    t = t.clamp(0.0, 1.0)
    q = a + t[..., None] * e
    return ((p - q) ** 2).sum(-1)


def reference_soft_silhouette(verts: torch.Tensor, faces: torch.Tensor, camera: Camera, sigma: float,
                              near: float = 1e-3) -> torch.Tensor:
    """(H, W) soft silhouette; faces with a vertex nearer than ``near`` are ignored, like the fast one."""
    W, H = camera.width, camera.height
    xy, depth = project(verts, camera.to(dtype=verts.dtype))
    faces = faces[(depth[faces] >= near).all(1)]
    tri = xy[faces]  # (F, 3, 2)
    ys, xs = torch.meshgrid(torch.arange(H, dtype=verts.dtype) + 0.5, torch.arange(W, dtype=verts.dtype) + 0.5,
                            indexing="ij")
    p = torch.stack([xs, ys], -1).reshape(-1, 1, 2)  # (P, 1, 2)
    a, b, c = tri[None, :, 0], tri[None, :, 1], tri[None, :, 2]
    d2 = torch.minimum(torch.minimum(point_segment_dist2(p, a, b), point_segment_dist2(p, b, c)),
                       point_segment_dist2(p, c, a))

    def edge(u, v):  # 2D cross product (v - u) x (p - u)
        return (v - u)[..., 0] * (p - u)[..., 1] - (v - u)[..., 1] * (p - u)[..., 0]

    w0, w1, w2 = edge(a, b), edge(b, c), edge(c, a)
    # a triangle counts whichever way it faces; a degenerate one (zero area) covers its own segment only
    area2 = ((b - a)[..., 0] * (c - a)[..., 1] - (b - a)[..., 1] * (c - a)[..., 0])
    sgn = torch.where(area2 < 0, -1.0, 1.0).to(verts.dtype)
    inside = (w0 * sgn >= 0) & (w1 * sgn >= 0) & (w2 * sgn >= 0)
    s = torch.where(inside, 1.0, -1.0).to(verts.dtype)
    D = torch.sigmoid(s * d2 / sigma)
    one_minus = (1.0 - D).clamp_min(1e-300)  # 1 - D underflows for pixels deep inside a large triangle
    return (1.0 - torch.prod(one_minus, dim=1)).reshape(H, W)
