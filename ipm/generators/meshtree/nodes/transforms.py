"""Mesh transforms (one child, an affine map of its vertices) and ``merge`` (children side by side).

``translate``, ``rotate`` (the SDF node's angle / tilt / azimuth), ``scale`` (uniform), ``scale3``.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from ipm.generators import _meshkit as mk
from ipm.generators._meshkit import smul, ssub
from ipm.generators.meshtree.node import ANGLE, POS, MeshNode, P, Transform, register


@register
class Translate(Transform):
    """Move the child by ``(x, y, z)``."""

    type_name = "translate"
    params = (P("x", 0.0, *POS), P("y", 0.0, *POS), P("z", 0.0, *POS))

    def affine(self, th):
        """Identity ``A`` and ``b = (x, y, z)``."""
        return mk.const(np.eye, 3, like=th), th

    def affine_jacobian(self, th):
        """Closed form: ``dA = 0``, ``db = I``."""
        return mk.const(np.zeros, (3, 3, 3), like=th), mk.const(np.eye, 3, like=th)


def rotation(angle: torch.Tensor, tilt: torch.Tensor, azimuth: torch.Tensor) -> torch.Tensor:
    """Rodrigues rotation ``(3, 3)`` by ``angle`` degrees about +Y tilted by ``tilt`` degrees towards
    the XZ direction at ``azimuth`` degrees (each ``(1,)``): the SDF ``rotate`` node's convention."""
    a, t, z = smul(angle, math.pi / 180), smul(tilt, math.pi / 180), smul(azimuth, math.pi / 180)
    st = torch.sin(t)
    x, y, w = st * torch.cos(z), torch.cos(t), st * torch.sin(z)
    c, s = torch.cos(a), torch.sin(a)
    C = ssub(1.0, c)
    return torch.cat([c + x * x * C, x * y * C - w * s, x * w * C + y * s,
                      y * x * C + w * s, c + y * y * C, y * w * C - x * s,
                      w * x * C - y * s, w * y * C + x * s, c + w * w * C]).reshape(3, 3)


def _cross(k: torch.Tensor) -> torch.Tensor:
    """``[k]x``: the ``(3, 3)`` matrix of ``v -> k x v`` for ``k: (3,)``."""
    x, y, w = k.split(1)
    zero = torch.zeros_like(x)
    return torch.cat([zero, -w, y, w, zero, -x, -y, x, zero]).reshape(3, 3)


@register
class Rotate(Transform):
    """Rotate the child by ``angle`` degrees about +Y tilted by ``tilt`` towards ``azimuth`` (the
    SDF ``rotate`` node's parameters and convention)."""

    type_name = "rotate"
    params = (P("angle", 0.0, *ANGLE), P("tilt", 0.0, *ANGLE), P("azimuth", 0.0, *ANGLE))

    def affine(self, th):
        """The rotation matrix (:func:`rotation`) and ``b = 0``."""
        a, t, z = th.split(1)
        return rotation(a, t, z), torch.zeros_like(th)

    def affine_jacobian(self, th):
        """Rodrigues ``R = c I + s [k]x + (1 - c) k k^T`` differentiated in closed form."""
        d = math.pi / 180
        a, t, z = (smul(x, d) for x in th.split(1))
        st, ct, sz, cz = torch.sin(t), torch.cos(t), torch.sin(z), torch.cos(z)
        c, s = torch.cos(a), torch.sin(a)
        C = ssub(1.0, c)
        zero = torch.zeros_like(st)
        k = torch.cat([st * cz, ct, st * sz])
        k_t = torch.cat([ct * cz, -st, ct * sz])
        k_z = torch.cat([-(st * sz), zero, st * cz])
        eye = mk.const(np.eye, 3, like=th)
        kk = k[:, None] * k[None, :]
        d_angle = -s * eye + c * _cross(k) + s * kk

        def d_axis(dk):
            return s * _cross(dk) + C * (dk[:, None] * k[None, :] + k[:, None] * dk[None, :])

        dA = smul(torch.stack([d_angle, d_axis(k_t), d_axis(k_z)], -1), d)
        return dA, mk.const(np.zeros, (3, 3), like=th)


@register
class Scale(Transform):
    """Uniform scale by ``factor`` about the origin."""

    type_name = "scale"
    params = (P("factor", 1.0, 1e-3, 100.0),)

    def affine(self, th):
        """``A = factor * I``, ``b = 0``."""
        return th * mk.const(np.eye, 3, like=th), torch.zeros_like(th).expand(3)

    def affine_jacobian(self, th):
        """Closed form: ``dA/dfactor = I``, ``db = 0``."""
        return mk.const(np.eye, 3, like=th)[..., None], mk.const(np.zeros, (3, 1), like=th)


def _diag_basis() -> np.ndarray:
    """``(3, 3, 3)``: d diag(s) / d s_k."""
    out = np.zeros((3, 3, 3))
    out[[0, 1, 2], [0, 1, 2], [0, 1, 2]] = 1.0
    return out


@register
class Scale3(Transform):
    """Non-uniform scale by ``(sx, sy, sz)`` about the origin."""

    type_name = "scale3"
    params = (P("sx", 1.0, 1e-3, 100.0), P("sy", 1.0, 1e-3, 100.0), P("sz", 1.0, 1e-3, 100.0))

    def affine(self, th):
        """``A = diag(sx, sy, sz)``, ``b = 0``."""
        return torch.diag_embed(th), torch.zeros_like(th)

    def affine_jacobian(self, th):
        """Closed form: ``dA/ds_k`` is the k-th diagonal unit matrix, ``db = 0``."""
        return mk.const(_diag_basis, like=th), mk.const(np.zeros, (3, 3), like=th)


@register
class Merge(MeshNode):
    """The children's meshes together (concatenation; overlapping parts are not fused)."""

    type_name = "merge"
    arity = None
