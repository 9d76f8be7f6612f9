"""Exact CSG meshes of SDF trees (issue #31): every node with a polyhedral counterpart built by manifold3d.

Marching cubes (:mod:`ipm.sdf.meshing`) rounds every sharp edge of a tree by about one grid cell. Here the tree
is walked with its stored values and each node becomes a ``manifold3d.Manifold`` (3D) or ``CrossSection`` (2D):
primitives as polyhedra whose vertices lie on the node's zero set (curved ones with ``segments`` straight
pieces per full circle), transforms as affine maps, the hard booleans as manifold's exact booleans. Macro nodes
are expanded into their definitions. Edges where two surfaces meet stay sharp.

A 3D node without a counterpart here (``round``, ``shell``, ``elongate``, the smooth booleans, a node type
added later) is meshed by marching cubes of its own subtree over its own bounds and enters the booleans as
that mesh; its label is reported in :attr:`ExactMesh.fallback`. A 2D node without one makes the lift above
it (``extrude``, ``revolve``) fall back. Should manifold refuse such a mesh (not an oriented 2-manifold), the
whole tree is meshed by marching cubes instead (:attr:`ExactMesh.grid_only`).

Where the solid differs from the SDF's zero set: ``repeat`` is the union of its copies, which is the zero set
only when the child fits inside its cell (the node's own condition for being exact); ``plane`` is kept finite
as the part of its bounding cube (side 40) below the plane, except under ``intersection`` and as the cut of a
``subtraction``, where it trims the other child exactly.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
import torch

from ipm import tree as T
from ipm.errors import InputError
from ipm.sdf import _exact_shapes as shapes
from ipm.sdf.complex import MacroNode
from ipm.sdf.meshing import check_resolution, mesh_sdf
from ipm.sdf.node import Node
from ipm.sdf.tree import Tree
from ipm.types import TriMesh

log = logging.getLogger(__name__)

MIN_SEGMENTS, MAX_SEGMENTS = 3, 1024


@dataclass(frozen=True)
class ExactMesh:
    """An exact CSG mesh of a tree.

    mesh: float64 vertices ``(V, 3)``, int64 faces ``(F, 3)``, counter-clockwise seen from outside;
    fallback: labels of the nodes meshed by marching cubes (``<label>`` or ``<macro label>/<inner label>``; for a
    2D node, ``<lift label> (<2D label>)``), in pre-order; empty when every node was exact;
    grid_only: True when manifold refused a fallback mesh and the whole tree was meshed by marching cubes;
    segments: straight pieces per full circle of the curved primitives.
    """

    mesh: TriMesh
    fallback: tuple[str, ...] = ()
    grid_only: bool = False
    segments: int = 64


class _GridRefused(Exception):
    """Manifold refused a marching-cubes mesh of a subtree (not an oriented 2-manifold)."""


@dataclass
class _Walk:
    """The state of one walk: settings, node labels by ``id``, and the fallbacks met so far."""

    segments: int
    resolution: int
    labels: dict[int, str]
    fallback: list[str] = field(default_factory=list)

    def shape(self, node: Node):
        """The ``Manifold`` (3D node) or ``CrossSection`` (2D node) of ``node``'s subtree; a 2D node without
        a counterpart raises :class:`shapes.NoExact` naming it."""
        if isinstance(node, MacroNode):  # walk its definition
            inner = node.expand()
            self._label_inner(node, inner)
            return self.shape(inner)
        build = shapes.BUILDERS.get(node.type_name)
        if node.out_dim == 2:
            if build is None:
                raise shapes.NoExact(self.label(node))
            return build(self, node, node.values)
        try:
            if build is not None:
                return build(self, node, node.values)
            missing = self.label(node)
        except shapes.NoExact as e:
            missing = f"{self.label(node)} ({e})"
        self.fallback.append(missing)
        return self.grid(node)

    def label(self, node: Node) -> str:
        """The node's label in the tree's parameter names (``n3_box`` or its name)."""
        return self.labels.get(id(node), node.name or node.type_name)

    def _label_inner(self, macro: Node, inner: Node) -> None:
        outer = self.label(macro)
        for i, visit in enumerate(T.preorder(inner)):
            self.labels.setdefault(id(visit.node), f"{outer}/{T.node_label(visit.node, i)}")

    def grid(self, node: Node):
        """Marching cubes of ``node``'s own SDF over its own bounds, as a Manifold (:class:`_GridRefused` if
        manifold will not take it)."""
        import manifold3d as m3d

        try:
            sub = Tree(node)
            lo, hi = sub.bounds()
            check_resolution(self.resolution, lo, hi)
        except InputError as e:  # a macro's inner node whose computed values leave their bounds
            raise _GridRefused(str(e)) from None
        mesh = mesh_sdf(lambda p: sub.sdf(None, p), lo, hi, self.resolution, dtype=torch.float64)
        if mesh.n_faces == 0:
            return m3d.Manifold()
        m = m3d.Mesh64(np.ascontiguousarray(mesh.verts.numpy()), np.ascontiguousarray(mesh.faces.numpy(), np.uint64))
        m.merge()
        solid = m3d.Manifold(m)
        if solid.status() != m3d.Error.NoError:
            raise _GridRefused(f"{self.label(node)}: {solid.status()}")
        return solid


def check_segments(segments: int) -> None:
    """``InputError`` unless ``segments`` is an int from :data:`MIN_SEGMENTS` to :data:`MAX_SEGMENTS`."""
    if isinstance(segments, bool) or not isinstance(segments, (int, np.integer)) \
            or not MIN_SEGMENTS <= segments <= MAX_SEGMENTS:
        raise InputError(f"segments: expected an integer from {MIN_SEGMENTS} to {MAX_SEGMENTS}, got {segments!r}")


def exact_mesh(tree: Tree | Node, *, segments: int = 64, resolution: int = 128) -> ExactMesh:
    """The exact CSG mesh of a 3D tree (or node) at its stored values.

    segments: straight pieces per full circle of curved primitives (3 to 1024); resolution: marching-cubes
    samples along the longest side of a fallback subtree (see the module docstring). Returns an
    :class:`ExactMesh` (its mesh empty if the solid is). ``InputError`` on bad settings or a 2D tree.
    """
    check_segments(segments)
    tree = tree if isinstance(tree, Tree) else Tree(tree)
    check_resolution(resolution, *tree.bounds())
    labels = {id(v.node): T.node_label(v.node, i) for i, v in enumerate(T.preorder(tree.root))}
    walk = _Walk(segments, resolution, labels)
    try:
        solid = walk.shape(tree.root)
    except _GridRefused as e:
        log.debug("exact mesh: a fallback mesh was refused (%s); meshing the whole tree by marching cubes", e)
        lo, hi = tree.bounds()
        mesh = mesh_sdf(lambda p: tree.sdf(None, p), lo, hi, resolution)
        return ExactMesh(mesh, tuple(dict.fromkeys(walk.fallback)), True, segments)
    return ExactMesh(to_trimesh(solid), tuple(dict.fromkeys(walk.fallback)), False, segments)


def to_trimesh(solid) -> TriMesh:
    """A ``manifold3d.Manifold`` as a :class:`TriMesh` (float64 vertices, int64 faces, outward)."""
    out = solid.to_mesh64()
    verts = np.asarray(out.vert_properties, dtype=np.float64)[:, :3].reshape(-1, 3)
    faces = np.asarray(out.tri_verts, dtype=np.int64).reshape(-1, 3)
    return TriMesh(torch.from_numpy(verts.copy()), torch.from_numpy(faces.copy()))


__all__ = ["MAX_SEGMENTS", "MIN_SEGMENTS", "ExactMesh", "check_segments", "exact_mesh", "to_trimesh"]
