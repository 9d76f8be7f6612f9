"""Mesh trees: a validated tree of mesh nodes with a flat, continuous parameter vector, its merged mesh,
its block-structured Jacobian, and its files.

Jacobians. Transforms are affine and act on every vertex alike, so their Jacobian with respect to
the vertices is block diagonal with one 3x3 block. :meth:`MeshTree.jacobian` uses that: each
primitive's own ``(V, 3, k)`` Jacobian and each ancestor transform's columns
``dA/dtheta v + db/dtheta`` are multiplied once by the composed 3x3 linear part of the transforms
above them (a batched 3x3 product per vertex) and written into their column block, instead of
pushing dense tangents for all parameters through every node. Tests compare it with ``jacfwd`` and
finite differences.

Files use the SDF trees' nested JSON form (:mod:`ipm.tree`), optionally wrapped as
``{"generator": "meshtree", "tree": {...}}``.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import torch

from ipm import tree as T
from ipm.errors import InputError
from ipm.generators import _meshkit as mk
from ipm.generators.meshtree.lod import MeshLod, resolve_lod
from ipm.generators.meshtree.node import MESH_NODES, MeshNode, Primitive, Transform
from ipm.types import TriMesh


@dataclass(frozen=True)
class _Prim:
    node: Primitive
    label: str
    sl: slice
    chain: tuple[int, ...]          # indices into MeshTree._transforms, outermost first


class MeshTree:
    """A validated tree of mesh nodes with a flat, continuous parameter vector.

    ``spec`` lists every parameter as ``<label>.<param>``; ``theta`` holds them in pre-order.
    """

    def __init__(self, root: MeshNode):
        if not isinstance(root, MeshNode):
            raise InputError(f"expected a mesh node as the tree root, got {type(root).__name__}")
        self.root = root
        visits = T.preorder(root)
        self.spec, self.labels, offsets = T.flat_spec(visits)
        self._topologies: dict[MeshLod, mk.Topology] = {}
        self._linear_jacobians: dict[tuple, torch.Tensor] = {}
        self._transforms: list[tuple[Transform, slice]] = []
        self._prims: list[_Prim] = []
        chain_of: dict[int, tuple[int, ...]] = {-1: ()}
        for i, v in enumerate(visits):
            node = v.node
            sl = slice(offsets[i], offsets[i] + len(node.param_defs()))
            chain = chain_of[v.parent]
            if isinstance(node, Transform):
                self._transforms.append((node, sl))
                chain = chain + (len(self._transforms) - 1,)
            elif isinstance(node, Primitive):
                self._prims.append(_Prim(node, self.labels[i], sl, chain))
            chain_of[i] = chain

    def __repr__(self) -> str:
        return f"MeshTree({len(self._prims)} primitives, {len(self.spec)} parameters)"

    @property
    def n_params(self) -> int:
        """Number of parameters of the whole tree (all nodes' parameters, flat)."""
        return len(self.spec)

    def theta(self, dtype=torch.float64, device=None) -> torch.Tensor:
        """The stored values, ``(n,)``."""
        return torch.tensor([float(p.default) for p in self.spec.params], dtype=dtype, device=device)

    def with_values(self, values: Mapping[str, object]) -> MeshTree:
        """A new tree with some parameters replaced by name (validated)."""
        full = self.spec.validate(values)
        return MeshTree(T.rebuild(self.root, iter(full[p.name] for p in self.spec.params)))

    # -- geometry ------------------------------------------------------------------------------
    def _check_theta(self, theta: torch.Tensor) -> None:
        if theta.ndim != 1 or theta.shape[0] != self.n_params:
            raise InputError(f"theta: expected shape ({self.n_params},), got {tuple(theta.shape)}")

    def _affines(self, theta: torch.Tensor) -> list[tuple[torch.Tensor, torch.Tensor]]:
        return [t.affine(theta[sl]) for t, sl in self._transforms]

    def _composed(self, aff, chain):
        """The composed affine map of a chain of transforms (outermost first)."""
        A, b = aff[chain[0]]
        for t in chain[1:]:
            At, bt = aff[t]
            A, b = A @ At, A @ bt + b
        return A, b

    def mesh(self, theta: torch.Tensor, lod=None) -> TriMesh:
        """The merged mesh for ``theta: (n,) float``; one face group per primitive (its label)."""
        self._check_theta(theta)
        L = resolve_lod(lod)
        aff = self._affines(theta)
        verts = []
        for pr in self._prims:
            v = pr.node.verts(theta[pr.sl], L)
            if pr.chain:
                A, b = self._composed(aff, pr.chain)
                v = v @ A.T + b                                     # one batched 3x3 map per primitive
            verts.append(v)
        return self._topology(L).mesh(verts)

    def _topology(self, L: MeshLod) -> mk.Topology:
        if L not in self._topologies:
            self._topologies[L] = mk.Topology.build([pr.node.faces(L) for pr in self._prims],
                                                    [pr.node.n_verts(L) for pr in self._prims],
                                                    [pr.label for pr in self._prims])
        return self._topologies[L]

    def _primitive_jacobian(self, index: int, pr: _Prim, theta: torch.Tensor, L: MeshLod) -> torch.Tensor:
        """A primitive's own ``(V, 3, k)`` Jacobian; constant (cached) for linear primitives."""
        if not pr.node.linear or mk._traced(theta):
            return pr.node.jacobian(theta[pr.sl], L)
        key = (index, L, theta.dtype, theta.device)
        if key not in self._linear_jacobians:
            self._linear_jacobians[key] = pr.node.jacobian(theta[pr.sl].detach(), L)
        return self._linear_jacobians[key]

    def jacobian(self, theta: torch.Tensor, lod=None) -> torch.Tensor:
        """``d verts / d theta``, ``(3V, n)`` (rows x0, y0, z0, x1, ...), from per-vertex 3x3 blocks.

        For a primitive under transforms ``T_1 .. T_m`` (outermost first) with linear parts ``A_i``:
        its own columns are ``A_1 .. A_m J_prim`` and the columns of ``T_i`` are
        ``A_1 .. A_{i-1} (dA_i v_i + db_i)`` with ``v_i`` the vertices in ``T_i``'s child frame.
        """
        self._check_theta(theta)
        L = resolve_lod(lod)
        aff = self._affines(theta)
        daff = [t.affine_jacobian(theta[sl]) for t, sl in self._transforms]
        n_rows = self._topology(L).n_verts
        J = theta.new_zeros((n_rows, 3, self.n_params))
        row = 0
        for pi, pr in enumerate(self._prims):
            v = pr.node.verts(theta[pr.sl], L)
            n = v.shape[0]
            # vertices in every transform's child frame, innermost first, and the linear parts of the
            # transforms outside each one, outermost first
            frames = [v]
            for t in reversed(pr.chain):
                A, b = aff[t]
                frames.append(frames[-1] @ A.T + b)
            outside = [None]
            for t in pr.chain:
                A = aff[t][0]
                outside.append(A if outside[-1] is None else outside[-1] @ A)
            for i, t in enumerate(pr.chain):
                dA, db = daff[t]
                if outside[i] is not None:            # fold the 3x3 block into the tiny derivatives
                    dA = torch.einsum("ab,bck->ack", outside[i], dA)
                    db = outside[i] @ db
                v_child = frames[len(pr.chain) - 1 - i]
                J[row:row + n, :, self._transforms[t][1]] = torch.einsum("abk,vb->vak", dA, v_child) + db
            J_p = self._primitive_jacobian(pi, pr, theta, L)                        # (V, 3, k)
            if outside[-1] is not None:
                J_p = torch.einsum("ab,vbk->vak", outside[-1], J_p)
            J[row:row + n, :, pr.sl] = J_p
            row += n
        return J.reshape(3 * n_rows, self.n_params)


# ----------------------------------------------------------------------------------------------
# Files
# ----------------------------------------------------------------------------------------------

def mesh_node_from_dict(d: object, path: str = "root") -> MeshNode:
    """A node tree from nested JSON data; errors name the node path."""
    return T.node_from_dict(d, MESH_NODES, path)


def mesh_node_to_dict(node: MeshNode) -> dict:
    """The nested JSON form of a mesh node tree."""
    return node.to_dict()


def mesh_tree_from_json(data: object) -> MeshTree:
    """A tree from ``{"node": ...}`` or ``{"tree": {...}}`` (optionally with ``"generator": "meshtree"``)."""
    if not isinstance(data, Mapping):
        raise InputError(f"mesh tree file: expected a JSON object, got {type(data).__name__}")
    gen = data.get("generator")
    if gen is not None and gen != "meshtree":
        raise InputError(f"mesh tree file: expected generator 'meshtree', got {gen!r}")
    if "tree" in data:
        data = data["tree"]
    return MeshTree(mesh_node_from_dict(data))


def mesh_tree_to_json(tree: MeshTree | MeshNode) -> dict:
    """``{"generator": "meshtree", "tree": nested}`` of a tree or node."""
    root = tree.root if isinstance(tree, MeshTree) else tree
    return {"generator": "meshtree", "tree": mesh_node_to_dict(root)}


def is_mesh_tree_file(path: str | Path) -> bool:
    """True if a JSON file declares ``"generator": "meshtree"`` (tells mesh trees from SDF trees)."""
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError, RecursionError):
        return False
    return isinstance(data, Mapping) and data.get("generator") == "meshtree"


def load_mesh_tree(path: str | Path) -> MeshTree:
    """Read a mesh tree file; :class:`InputError` with a one-line reason on failure."""
    return mesh_tree_from_json(T.read_json(path, "mesh tree file"))
