"""Half-flaps (Liu et al. 2020): the two triangles on either side of a directed edge ``a -> b``, with the
opposite corners ``c`` (in the triangle ``a b c``) and ``d`` (in the twin triangle ``b a d``); and the
topology of one level of Loop (or midpoint) subdivision. Pure NumPy, on closed edge-manifold meshes with
consistently oriented faces (:func:`ipm.subdiv.linear.check_mesh` with ``boundary = False``)."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np


@dataclass(frozen=True)
class Flaps:
    """Half-flaps of a closed mesh: ``abcd (H, 4)`` (one row per directed edge, H = 3F), ``edge (H,)``
    the undirected edge of each (index into ``edges (E, 2)``, E = H / 2), ``vertex (H,)`` = column a."""

    abcd: np.ndarray
    edge: np.ndarray
    edges: np.ndarray
    n_verts: int


def flaps(faces: np.ndarray, n_verts: int) -> Flaps:
    """The half-flaps of ``faces (F, 3)``, its undirected edges numbered as :func:`next_level` inserts
    their vertices (cached per face array)."""
    F = np.ascontiguousarray(faces, dtype=np.int64)
    return _flaps(F.tobytes(), F.shape[0], n_verts)


@lru_cache(maxsize=32)
def _flaps(key: bytes, n_faces: int, n_verts: int) -> Flaps:
    F = np.frombuffer(key, dtype=np.int64).reshape(n_faces, 3)
    a = F.reshape(-1)
    b = F[:, [1, 2, 0]].reshape(-1)
    c = F[:, [2, 0, 1]].reshape(-1)
    code = a * n_verts + b
    order = np.argsort(code)
    twin_code = b * n_verts + a
    pos = np.searchsorted(code[order], twin_code)
    pos = np.minimum(pos, len(code) - 1)
    twin = order[pos]
    if not np.array_equal(code[twin], twin_code):
        raise ValueError("half-flaps need a closed mesh with consistently oriented faces")
    d = c[twin]
    edges, _ = next_level(F, n_verts)
    ecode = np.minimum(a, b) * n_verts + np.maximum(a, b)
    e_sorted = np.argsort(edges[:, 0] * n_verts + edges[:, 1])
    edge = e_sorted[np.searchsorted((edges[:, 0] * n_verts + edges[:, 1])[e_sorted], ecode)]
    return Flaps(np.stack([a, b, c, d], 1), edge, edges, n_verts)


def next_level(faces: np.ndarray, n_verts: int) -> tuple[np.ndarray, np.ndarray]:
    """One level of Loop topology: ``(edges (E, 2), new faces (4F, 3))``. The new mesh's vertices are the
    ``n_verts`` old ones followed by one per edge, in the order of ``edges`` (libigl's, shared by its Loop
    and midpoint matrices; each row sorted)."""
    F = np.ascontiguousarray(faces, dtype=np.int64)
    return _next_level(F.tobytes(), F.shape[0], n_verts)


@lru_cache(maxsize=32)
def _next_level(key: bytes, n_faces: int, n_verts: int) -> tuple[np.ndarray, np.ndarray]:
    import igl
    import scipy.sparse as sp

    F = np.frombuffer(key, dtype=np.int64).reshape(n_faces, 3)
    S, NF = igl.upsample_matrix(F, n_verts)
    S = sp.csr_matrix(S)[n_verts:]
    S.sort_indices()
    cols = S.indices.reshape(-1, 2)           # each new vertex: the mean of its edge's two ends
    return np.sort(cols, axis=1), np.asarray(NF, dtype=np.int64)
