"""A tiny mesh generator for fitting tests that should run in seconds: n boxes side by side, and one
32-pixel silhouette of two of them."""

from __future__ import annotations

import torch

from ipm.generators.base import Generator
from ipm.optim.targets import MaskTarget
from ipm.params import Param, ParamSpec
from ipm.render import camera
from ipm.render import soft as render
from ipm.types import TriMesh

CUBE_V = torch.tensor([[x, y, z] for x in (-0.5, 0.5) for y in (0.0, 1.0) for z in (-0.5, 0.5)], dtype=torch.float64)
CUBE_F = torch.tensor([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                       [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])

class Boxes(Generator):
    """n boxes of width w and height h side by side (a test-only generator)."""

    name = "test_boxes"
    kind = "mesh"
    spec = ParamSpec((Param("width", 0.6, 0.3, 1.0), Param("height", 1.0, 0.5, 2.0), Param("count", 1, 1, 3, "int")))
    presets = {}

    def mesh(self, theta, discrete, lod=None):
        w, h = theta[0], theta[1]
        parts = [TriMesh(CUBE_V.to(theta.dtype) * torch.stack([w, h, 0.5 + 0 * w]) +
                         torch.stack([1.5 * i * w, 0 * w, 0 * w]), CUBE_F) for i in range(int(discrete["count"]))]
        return TriMesh.concat(parts)

    def to_mesh(self, values, *, resolution=None, lod=None):
        return self.mesh(*self.split(values))


def boxes_target() -> MaskTarget:
    """One 32-pixel view of two boxes."""
    g = Boxes()
    m = g.mesh(*g.split(g.spec.validate({"width": 0.5, "height": 1.2, "count": 2})))
    v = (m.verts - m.verts.mean(0)) * 0.8
    cams = [camera.orbit_camera(20.0, 20.0, 3.2, width=32).to(torch.float32)]
    masks = torch.stack([(render.soft_silhouette(v.float(), m.faces, c, sigma=0.05) > 0.5).float() for c in cams])
    return MaskTarget(masks, cams)
