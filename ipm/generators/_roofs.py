"""Roof solids of the building generator: flat, gable, hipped and mansard, each one closed part.

Every roof is built in its own frame: centered on the Y axis, its eaves a rectangle of half-sizes
``rx`` (along X, the ridge's direction) and ``rz`` (along Z) at height ``base``, its highest point at
``top``. :func:`roof_verts` returns the vertices ``(k, 3)`` (differentiable in every size), and
:func:`roof_faces` the faces (NumPy, cached), which depend on the roof type only. The building turns
a wing's roof a quarter turn about Y where its ridge runs along Z (a rotation keeps the faces
outward) and moves it into place.

Shape fractions come from the parameter dict ``p`` (tensors of shape (1,)):
``roof_ridge`` (hipped and mansard: the ridge's length as a fraction of the length below it),
``mansard_break`` (mansard: the height of the slope break as a fraction of the roof height) and
``mansard_inset`` (mansard: how far the break line lies inside the eaves, as a fraction of the
smaller half-size). Each stays a closed, outward solid with no degenerate face for every value in
the parameters' bounds: the fractions are strictly between 0 and 1.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

import numpy as np
import torch

from ipm.generators import _meshkit as mk

ROOF_TYPES = ("flat", "gable", "hipped", "mansard")

# hipped roof: base loop (counter-clockwise about +Y) then the ridge (+X end, -X end)
_HIP_FACES = ((0, 2, 1), (0, 3, 2), (0, 1, 4), (1, 2, 5), (1, 5, 4), (2, 3, 5), (3, 0, 4), (3, 4, 5))
# the hipped roof's upper faces (all but the base) on a loop at 4..7 and a ridge at 8, 9
_MANSARD_TOP = tuple(tuple(i + 4 for i in f) for f in _HIP_FACES[2:])

Params = Mapping[str, torch.Tensor]


def boxes(x, y, z) -> tuple[torch.Tensor, torch.Tensor]:
    """Box corners from per-axis ``(lo, hi)`` pairs of broadcastable tensors: ``lo, hi: (B, 3)``."""
    lo = torch.stack(torch.broadcast_tensors(x[0], y[0], z[0]), -1).reshape(-1, 3)
    hi = torch.stack(torch.broadcast_tensors(x[1], y[1], z[1]), -1).reshape(-1, 3)
    return lo, hi


def _flat(rx, rz, base, top, p: Params) -> torch.Tensor:
    """A slab: one box."""
    return mk.box_verts(*boxes((-rx, rx), (base, top), (-rz, rz)))


def _gable(rx, rz, base, top, p: Params) -> torch.Tensor:
    """A triangular prism along X: the loop (front eave, back eave, ridge) runs counter-clockwise
    about +X and is extruded from -rx to +rx."""
    zero = torch.zeros_like(rz)
    x = torch.cat([-rx, -rx, -rx, rx, rx, rx])
    y = torch.cat([base, base, top]).repeat(2)
    z = torch.cat([rz, -rz, zero]).repeat(2)
    return torch.stack([x, y, z], -1)


def _hipped(rx, rz, base, top, p: Params) -> torch.Tensor:
    """The base rectangle (counter-clockwise about +Y) and a ridge along X, ``roof_ridge`` of the
    roof's length."""
    zero = torch.zeros_like(rz)
    ridge = rx * p["roof_ridge"]
    x = torch.cat([rx, rx, -rx, -rx, ridge, -ridge])
    y = torch.cat([base, base, base, base, top, top])
    z = torch.cat([rz, -rz, -rz, rz, zero, zero])
    return torch.stack([x, y, z], -1)


def _mansard(rx, rz, base, top, p: Params) -> torch.Tensor:
    """Two slopes on every side: the eaves rectangle, the break rectangle ``mansard_inset * min(rx,
    rz)`` inside it at ``mansard_break`` of the roof height (the steep lower slopes), and a hipped top
    over the break rectangle with a ridge along X of ``roof_ridge`` of its length. Loops run
    counter-clockwise about +Y; the lower part is a frustum (a loft of two loops), the upper one the
    hipped roof's upper faces."""
    zero = torch.zeros_like(rz)
    inset = torch.minimum(rx, rz) * p["mansard_inset"]
    bx, bz = rx - inset, rz - inset
    yb = base + (top - base) * p["mansard_break"]
    ridge = bx * p["roof_ridge"]
    x = torch.cat([rx, rx, -rx, -rx, bx, bx, -bx, -bx, ridge, -ridge])
    y = torch.cat([base, base, base, base, yb, yb, yb, yb, top, top])
    z = torch.cat([rz, -rz, -rz, rz, bz, -bz, -bz, bz, zero, zero])
    return torch.stack([x, y, z], -1)


def _mansard_faces() -> np.ndarray:
    lower = mk.loft_faces_np(2, 4, "fan", "none")
    return np.concatenate([lower, np.asarray(_MANSARD_TOP, dtype=np.int64)])


# roof type -> (vertices from (rx, rz, base, top, params), faces (NumPy))
ROOFS: dict[int, tuple[Callable[..., torch.Tensor], Callable[[], np.ndarray]]] = {
    0: (_flat, lambda: mk.repeat_faces_np(None, 8, 1, 2, 4)),
    1: (_gable, lambda: mk.loft_faces_np(2, 3, "fan", "fan")),
    2: (_hipped, lambda: np.asarray(_HIP_FACES, dtype=np.int64)),
    3: (_mansard, _mansard_faces),
}
ROOF_VERTS = {0: 8, 1: 6, 2: 6, 3: 10}      # vertices per roof type


def roof_verts(kind: int, rx: torch.Tensor, rz: torch.Tensor, base: torch.Tensor, top: torch.Tensor,
               p: Params) -> torch.Tensor:
    """Vertices ``(ROOF_VERTS[kind], 3)`` of a roof of type ``kind`` in its own frame; ``rx, rz, base,
    top: (1,)`` tensors (``rx, rz > 0``, ``top > base``), ``p`` the shape fractions (module docstring)."""
    return ROOFS[kind][0](rx, rz, base, top, p)


def roof_faces(kind: int) -> np.ndarray:
    """Faces ``(F, 3) int64`` of a roof of type ``kind`` (indexing its own vertices from 0)."""
    return ROOFS[kind][1]()
