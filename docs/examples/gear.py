"""A spur gear: the generator that docs/plugins.md builds, loaded with ``ipm --plugin docs/examples/gear.py``.

The gear stands on its rim with its axle along Z (Y is up, as everywhere in ipm). Its outline has four
points per tooth (two at the root circle, two at the tip circle); the faces are quads between the outline and
the bore at the front and the back, and around the rim and the bore: a closed, watertight mesh whose vertices
move smoothly with the continuous parameters, while the tooth count sets the faces.
"""

import math

import torch

from ipm.generators.custom import MeshGenerator, Param


class Gear(MeshGenerator):
    """A spur gear with a bore: tip radius, tooth depth, tooth taper, thickness, bore and a tooth count."""

    name = "gear"
    description = "spur gear with a bore (the plug-in tutorial, docs/plugins.md)"
    params = (
        Param("radius", 0.5, 0.2, 1.0, doc="tip radius"),
        Param("depth", 0.25, 0.05, 0.5, doc="tooth depth, as a share of the tip radius"),
        Param("taper", 0.6, 0.2, 1.0, doc="tooth width at the tip, as a share of its width at the root"),
        Param("thickness", 0.2, 0.05, 0.8, doc="along the axle"),
        Param("bore", 0.3, 0.05, 0.8, doc="bore radius, as a share of the root radius"),
        Param("teeth", 12, 5, 40, "int", doc="tooth count"),
    )
    presets = {"small": {"radius": 0.35, "teeth": 8}, "fine": {"depth": 0.12, "teeth": 30}}

    def build(self, p):
        n = p["teeth"]
        root = p["radius"] * (1 - p["depth"])
        # four angles per tooth: root, tip, tip, root; each tooth takes half of its pitch at the root
        half = math.pi / n / 2
        centre = torch.arange(n, dtype=p["radius"].dtype) * (2 * math.pi / n)
        offsets = torch.stack([-half * torch.ones(()), -half * p["taper"], half * p["taper"], half * torch.ones(())])
        angle = (centre[:, None] + offsets[None, :]).reshape(-1)
        rim = torch.stack([root, p["radius"], p["radius"], root]).repeat(n)
        bore = (root * p["bore"]).expand(4 * n)
        rings = []
        for radius in (rim, bore):  # outline, then bore; each at the front (z > 0) and the back
            for z in (p["thickness"] / 2, -p["thickness"] / 2):
                rings.append(torch.stack([radius * torch.cos(angle), radius * torch.sin(angle), z.expand(4 * n)], -1))
        verts = torch.cat(rings)  # rings: 0 front rim, 1 back rim, 2 front bore, 3 back bore
        return verts, _faces(4 * n)


def _faces(m):
    """Quads (as two triangles each) between rings of m points: rim, bore, front and back faces."""
    i = torch.arange(m)
    j = (i + 1) % m
    ring = [k * m for k in range(4)]

    def quads(a, b, c, d):  # counter-clockwise a, b, c, d seen from outside
        return torch.cat([torch.stack([a, b, c], -1), torch.stack([a, c, d], -1)])

    return torch.cat([
        quads(ring[1] + i, ring[1] + j, ring[0] + j, ring[0] + i),  # rim, facing out
        quads(ring[2] + i, ring[2] + j, ring[3] + j, ring[3] + i),  # bore, facing the axle
        quads(ring[0] + i, ring[0] + j, ring[2] + j, ring[2] + i),  # front (+z)
        quads(ring[3] + i, ring[3] + j, ring[1] + j, ring[1] + i),  # back (-z)
    ])
