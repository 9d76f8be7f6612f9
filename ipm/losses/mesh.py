"""Mesh against mesh: Chamfer distance between surface samples drawn with fixed barycentric
coordinates, so that the samples move smoothly with the vertices."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from ipm.errors import InputError


@dataclass(frozen=True)
class SurfaceSampler:
    """Fixed samples on a mesh's faces: face indices ``(S,)`` and barycentric weights ``(S, 3)``.

    Drawn once (area-weighted at the mesh's initial shape); ``points(verts)`` then moves the samples
    with the vertices, differentiably.
    """

    faces: torch.Tensor
    bary: torch.Tensor

    @staticmethod
    def draw(verts: torch.Tensor, faces: torch.Tensor, n: int, generator: torch.Generator | None = None
             ) -> SurfaceSampler:
        """``n`` samples drawn area-weighted on the mesh as it is now, uniform within each face; ``InputError``
        for a mesh of zero area."""
        v = verts.detach()
        tri = v[faces]
        area = torch.linalg.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0], dim=-1).norm(dim=-1)
        if not torch.isfinite(area).all() or area.sum() <= 0:
            raise InputError("expected a mesh with positive area, got zero area")
        idx = torch.multinomial(area / area.sum(), n, replacement=True, generator=generator)
        uv = torch.rand(n, 2, generator=generator, dtype=v.dtype).to(v.device)
        flip = uv.sum(1) > 1
        uv[flip] = 1 - uv[flip]
        bary = torch.stack([1 - uv[:, 0] - uv[:, 1], uv[:, 0], uv[:, 1]], 1)
        return SurfaceSampler(faces[idx], bary)

    def points(self, verts: torch.Tensor) -> torch.Tensor:
        """``(S, 3)`` sample positions on the current vertices."""
        tri = verts[self.faces]
        return (tri * self.bary[..., None].to(verts.dtype)).sum(1)


def nearest(x: torch.Tensor, y: torch.Tensor, chunk: int = 4096) -> torch.Tensor:
    """Index into ``y: (M, 3)`` of the nearest point to each row of ``x: (N, 3)``, ``(N,)`` int64,
    without gradients: a k-d tree (scipy) on the CPU, chunked ``cdist`` on other devices."""
    with torch.no_grad():
        if x.device.type == "cpu":
            from scipy.spatial import cKDTree

            _, idx = cKDTree(y.detach().double().numpy()).query(x.detach().double().numpy())
            return torch.as_tensor(idx, dtype=torch.long)
        return torch.cat([torch.cdist(x[i:i + chunk], y).argmin(1) for i in range(0, len(x), chunk)])


def chamfer_loss(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Symmetric Chamfer distance (mean of squared nearest-neighbour distances, both ways) between
    point sets ``a: (N, 3)`` and ``b: (M, 3)``.

    The nearest neighbours are found without gradients (:func:`nearest`); the distances to them are
    then differentiable. Value and gradient equal those of the min over all pairs (the gradient of a
    min flows only through its argmin), at the cost of a k-d tree query instead of N x M distances.
    """
    ab = ((a - b[nearest(a, b)]) ** 2).sum(-1).mean()
    ba = ((b - a[nearest(b, a)]) ** 2).sum(-1).mean()
    return ab + ba
