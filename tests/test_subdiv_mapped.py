"""Issue #14, pairs from any closed mesh (ipm.subdiv.mapped): QEM decimation, the two maps back to the
original surface, and training on such pairs."""

from __future__ import annotations

import igl
import numpy as np
import pytest
import torch
import trimesh

from ipm.errors import InputError
from ipm.subdiv import clean
from ipm.subdiv.mapped import RAY_REACH, decimate, map_points, map_quality, mapped_pair
from ipm.subdiv.train import TrainSettings, train


def _ellipsoid(level: int = 4) -> tuple[np.ndarray, np.ndarray]:
    m = trimesh.creation.icosphere(level)
    V = np.asarray(m.vertices) * np.array([0.9, 0.5, 0.7])
    return V, np.asarray(m.faces, dtype=np.int64)


def test_decimation_reaches_about_the_target_and_stays_closed():
    V, F = _ellipsoid()
    CV, CF = decimate(V, F, 300)
    assert 250 <= len(CV) <= 350
    e = np.sort(np.concatenate([CF[:, [0, 1]], CF[:, [1, 2]], CF[:, [2, 0]]]), 1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    assert (counts == 2).all()


@pytest.mark.parametrize("method", ["closest", "normal"])
def test_mapped_points_lie_on_the_original_surface(method):
    V, F = _ellipsoid()
    CV, CF = decimate(V, F, 200)
    P = 0.5 * (CV[CF[:, 0]] + CV[CF[:, 1]])                  # edge midpoints: off the surface
    N = igl.per_vertex_normals(CV, CF)[CF[:, 0]] + igl.per_vertex_normals(CV, CF)[CF[:, 1]]
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    M = map_points(P, N, V, F, method)
    d2, _, closest = igl.point_mesh_squared_distance(M, V, F)
    assert np.sqrt(d2).max() < 1e-9                          # on the original
    moved = np.linalg.norm(M - P, axis=1)
    d_closest = np.linalg.norm(np.asarray(igl.point_mesh_squared_distance(P, V, F)[2]) - P, axis=1)
    if method == "closest":
        assert np.allclose(moved, d_closest, atol=1e-12)
    else:   # never nearer than the closest point, never farther than the reach
        assert (moved >= d_closest - 1e-12).all() and (moved <= RAY_REACH * d_closest + 1e-8).all()


def test_a_ray_that_misses_falls_back_to_the_closest_point():
    V, F = _ellipsoid(2)
    P = np.array([[3.0, 0.0, 0.0]])
    N = np.array([[0.0, 0.0, 1.0]])                          # parallel to the surface, far away: no crossing
    M = map_points(P, N, V, F, "normal")
    assert np.allclose(M, igl.point_mesh_squared_distance(P, V, F)[2])


@pytest.mark.parametrize("method", ["closest", "normal"])
def test_a_mapped_pair_nests_its_levels(method):
    V, F = _ellipsoid()
    pair = mapped_pair(V, F, 150, 2, method)
    n1 = len(pair.levels[0])
    assert torch.equal(pair.levels[1][:n1], pair.levels[0])
    assert n1 == len(pair.verts) + len(pair.faces) * 3 // 2 and len(pair.levels[1]) > n1


def test_map_quality_is_a_share():
    V, F = _ellipsoid()
    q = map_quality(V, F, 150, 2, "closest")
    assert 0 <= q.flipped <= 1 and 0 <= q.collapsed <= 1 and 0 < q.moved < 0.1


def test_clean_welds_a_triangle_soup():
    V, F = _ellipsoid(1)
    W, G = clean(V[F].reshape(-1, 3), np.arange(3 * len(F)).reshape(-1, 3))
    assert len(W) == len(V) and len(G) == len(F)


def test_training_on_real_meshes_only_and_its_settings(tmp_path):
    V, F = _ellipsoid()
    path = tmp_path / "ellipsoid.ply"
    trimesh.Trimesh(V, F, process=False).export(path)
    s = TrainSettings(steps=6, procedural=False, real=(str(path),))
    ckpt = tmp_path / "w.ckpt.npz"
    net = train(s, checkpoint=ckpt, every=3)
    assert sum(p.numel() for p in net.parameters()) > 0 and ckpt.exists()
    train(s, checkpoint=ckpt, resume=True)   # the settings (with their tuple of paths) match the checkpoint's
    with pytest.raises(InputError, match="expected procedural pairs, real meshes or both, got neither"):
        train(TrainSettings(steps=2, procedural=False))
    with pytest.raises(InputError, match="map: expected one of closest, normal, got 'nearest'"):
        train(TrainSettings(steps=2, map="nearest"))
    with pytest.raises(InputError, match="real mesh: expected an existing mesh file"):
        train(TrainSettings(steps=2, procedural=False, real=(str(tmp_path / "missing.ply"),)))
