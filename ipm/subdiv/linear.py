"""What a subdivision scheme is, the linear ones (a sparse matrix per level from the faces), and the
checks every scheme shares: a non-empty, edge-manifold triangle mesh and a level count in range."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
import scipy.sparse as sp
import torch

from ipm.errors import InputError
from ipm.subdiv.sparse import SparseOperator

MAX_LEVELS = 6
# the largest subdivided mesh made (vertices), about 1 GB of float64 positions with its faces
MAX_VERTICES = 20_000_000


class Scheme(Protocol):
    name: str
    boundary: bool   # whether meshes with boundary edges are accepted

    def subdivide(self, verts: torch.Tensor, faces: np.ndarray, levels: int) -> tuple[torch.Tensor, np.ndarray]:
        """``verts (V, 3)`` (any float dtype and device; differentiable), ``faces (F, 3)`` -> the mesh
        subdivided ``levels`` times."""


def clean(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A mesh ready for :func:`check_mesh`: vertices welded where they coincide (an STL stores every
    triangle on its own), degenerate faces dropped, unused vertices removed."""
    W, inv = np.unique(np.asarray(V, dtype=np.float64), axis=0, return_inverse=True)
    F = inv.reshape(-1)[np.asarray(F, dtype=np.int64)]
    F = F[(F[:, 0] != F[:, 1]) & (F[:, 1] != F[:, 2]) & (F[:, 0] != F[:, 2])]
    used = np.unique(F)
    remap = np.full(len(W), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return W[used], remap[F]


def check_levels(levels: int) -> int:
    """``levels`` if it is an int from 1 to :data:`MAX_LEVELS`, else ``InputError``."""
    if isinstance(levels, bool) or not isinstance(levels, int) or not 1 <= levels <= MAX_LEVELS:
        raise InputError(f"levels: expected an integer from 1 to {MAX_LEVELS}, got {levels!r}")
    return levels


def check_mesh(faces: np.ndarray, n_verts: int, scheme: Scheme, levels: int) -> np.ndarray:
    """The faces as int64 ``(F, 3)`` if ``scheme`` can subdivide them ``levels`` times, else
    :class:`InputError` naming what is wrong: no faces, indices out of range, vertices on no face, a
    degenerate face, an edge
    shared by more than two faces (non-manifold), an edge two faces orient the same way, boundary edges for
    a scheme without boundary rules, or an output too large."""
    check_levels(levels)
    F = np.asarray(faces)
    if F.ndim != 2 or F.shape[1] != 3:
        raise InputError(f"mesh: expected triangle faces (F, 3), got shape {F.shape}")
    if len(F) == 0 or n_verts == 0:
        raise InputError("mesh: expected at least one triangle, got an empty mesh")
    F = F.astype(np.int64)
    if F.min() < 0 or F.max() >= n_verts:
        raise InputError(f"mesh: face indices must lie in [0, {n_verts - 1}], got {F.min()}..{F.max()}")
    unused = n_verts - len(np.unique(F))
    if unused:  # libigl's matrices assume every vertex is on a face (it crashes otherwise)
        raise InputError(f"mesh: {unused} vertex(es) on no face; remove unreferenced vertices first")
    if ((F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 0] == F[:, 2])).any():
        raise InputError("mesh: a face repeats a vertex (degenerate triangle); remove it first")
    directed = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    und = np.sort(directed, axis=1)
    _, counts = np.unique(und, axis=0, return_counts=True)
    if (counts > 2).any():
        raise InputError(f"mesh: {int((counts > 2).sum())} edge(s) shared by more than two faces (non-manifold); "
                         f"{scheme.name} subdivision needs an edge-manifold mesh")
    _, dcounts = np.unique(directed, axis=0, return_counts=True)
    if (dcounts > 1).any():
        raise InputError(f"mesh: {int((dcounts > 1).sum())} edge(s) where two faces disagree on orientation; "
                         "orient the faces consistently first")
    if not scheme.boundary and (counts == 1).any():
        raise InputError(f"mesh: {int((counts == 1).sum())} boundary edge(s); {scheme.name} subdivision "
                         "expects a closed mesh")
    # each level: V' = V + E, F' = 4F (E ~ 1.5 F on closed meshes)
    v, e, f = n_verts, len(counts), len(F)
    for _ in range(levels):
        v, e, f = v + e, 2 * e + 3 * f, 4 * f
    if v > MAX_VERTICES:
        raise InputError(f"levels: {levels} levels of a mesh with {n_verts} vertices would make {v} vertices; "
                         f"at most {MAX_VERTICES} are made (use fewer levels)")
    return F


@dataclass
class LinearScheme:
    """A scheme whose every level is ``V' = S V``, ``S`` from ``matrix(faces, n) -> (S, new faces)``.
    The composed operator of all levels is cached per face array (a fit renders the same faces again)."""

    name: str
    matrix: Callable[[np.ndarray, int], tuple[sp.spmatrix, np.ndarray]]
    boundary: bool = True
    _cache: dict = field(default_factory=dict, repr=False)
    CACHE_SIZE = 16

    def operator(self, faces: np.ndarray, n_verts: int, levels: int) -> tuple[SparseOperator, np.ndarray]:
        """The checked mesh's composed operator ``S (V_L, V)`` and its faces after ``levels`` levels."""
        check_levels(levels)
        F = np.ascontiguousarray(faces)
        key = (n_verts, levels, F.shape, F.dtype.str, F.tobytes())
        hit = self._cache.get(key)
        if hit is not None:  # checked when it was made (the check costs more than the product)
            return hit
        F = check_mesh(F, n_verts, self, levels)
        S, n = sp.identity(n_verts, format="csr"), n_verts
        for _ in range(levels):
            Si, F = self.matrix(F, n)
            S, n = sp.csr_matrix(Si) @ S, Si.shape[0]
        if len(self._cache) >= self.CACHE_SIZE:
            self._cache.pop(next(iter(self._cache)))
        self._cache[key] = (SparseOperator(S), np.ascontiguousarray(F, dtype=np.int64))
        return self._cache[key]

    def subdivide(self, verts: torch.Tensor, faces: np.ndarray, levels: int) -> tuple[torch.Tensor, np.ndarray]:
        """One cached sparse operator for all ``levels`` applied to ``verts`` (differentiable), and the final faces."""
        op, F = self.operator(faces, verts.shape[0], levels)
        return op(verts), F


def subdivide(verts: torch.Tensor, faces, scheme: str, levels: int) -> tuple[torch.Tensor, np.ndarray]:
    """``verts (V, 3)``, ``faces (F, 3)`` subdivided ``levels`` times by the registered ``scheme``."""
    from ipm.subdiv import SCHEMES

    F = faces.cpu().numpy() if isinstance(faces, torch.Tensor) else np.asarray(faces)
    return SCHEMES.get(scheme).subdivide(verts, F, levels)
