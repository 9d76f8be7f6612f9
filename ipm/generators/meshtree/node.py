"""The mesh node base, its two kinds (primitives and affine transforms) and its registry.

Mesh node types live one topic per module in :mod:`ipm.generators.meshtree.nodes`; the registry
:data:`MESH_NODES` imports that package on first use, so a new node type is one new module (or class)
there. Sizes are full extents like the SDF nodes; all parameters are continuous.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import torch
from torch.func import jacfwd, vmap

from ipm.generators.meshtree.lod import MeshLod
from ipm.params import Param
from ipm.registry import Registry
from ipm.tree import TreeNode

LEN = (1e-3, 20.0)
POS = (-20.0, 20.0)
ANGLE = (-360.0, 360.0)

MESH_NODES: Registry = Registry("mesh node type", packages=["ipm.generators.meshtree.nodes"])
register = MESH_NODES.register()


def P(name: str, default: float, lo: float = LEN[0], hi: float = LEN[1], doc: str = "") -> Param:
    """A continuous parameter (bounds default to a positive length)."""
    return Param(name, default, lo, hi, "float", doc)


def mesh_node_type(name: str) -> type[MeshNode]:
    """A mesh node type by name; :class:`~ipm.errors.InputError` lists the known names."""
    return MESH_NODES.get(name)


@dataclass(frozen=True, eq=False)
class MeshNode(TreeNode):
    """A mesh node instance (see :class:`~ipm.tree.TreeNode`); variadic nodes take one or more children."""

    min_children: ClassVar[int] = 1


class Primitive(MeshNode, ABC):
    """A leaf: vertices from its own parameters ``th: (k,)`` and a fixed face list."""

    arity = 0

    #: True when the vertices are a linear function of the parameters (no constant term): then the
    #: Jacobian is the vertices of the unit parameter vectors, one batched evaluation.
    linear: ClassVar[bool] = False

    @abstractmethod
    def verts(self, th: torch.Tensor, lod: MeshLod) -> torch.Tensor:
        """Vertices ``(V, 3)`` in the node's frame."""

    @abstractmethod
    def faces(self, lod: MeshLod) -> np.ndarray:
        """Faces ``(F, 3) int64`` NumPy array (outward, counter-clockwise seen from outside)."""

    def n_verts(self, lod: MeshLod) -> int:
        """Number of vertices at this level of detail (default: from the faces; subclasses override it cheaper)."""
        return int(self.faces(lod).max()) + 1

    def jacobian(self, th: torch.Tensor, lod: MeshLod) -> torch.Tensor:
        """``d verts / d th``: ``(V, 3, k)``."""
        if self.linear:
            eye = torch.eye(th.shape[0], dtype=th.dtype, device=th.device)
            return vmap(lambda e: self.verts(e, lod), out_dims=2)(eye)
        return jacfwd(lambda t: self.verts(t, lod))(th)


class Transform(MeshNode, ABC):
    """One child, whose vertices are mapped by an affine map ``v -> A v + b``."""

    arity = 1

    @abstractmethod
    def affine(self, th: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``A: (3, 3)``, ``b: (3,)`` from the node's parameters ``th: (k,)``."""

    def affine_jacobian(self, th: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``dA/dth: (3, 3, k)``, ``db/dth: (3, k)``."""
        return jacfwd(self.affine)(th)


__all__ = ["ANGLE", "LEN", "MESH_NODES", "POS", "MeshNode", "P", "Primitive", "Transform", "mesh_node_type",
           "register"]
