"""Exports keep vertex order (process=False), carry metadata, and are atomic."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
import trimesh

from ipm.files import atomic_path
from ipm.io.export import export_mesh, sidecar_path
from ipm.types import TriMesh


def small_mesh() -> TriMesh:
    tm = trimesh.creation.icosphere(subdivisions=2)
    # shuffle the vertices so that a reordering exporter would be caught
    perm = np.random.default_rng(0).permutation(len(tm.vertices))
    inv = np.argsort(perm)
    return TriMesh(torch.as_tensor(tm.vertices[perm]), torch.as_tensor(inv[tm.faces]))


@pytest.mark.parametrize("suffix", [".obj", ".ply", ".stl", ".glb"])
def test_roundtrip_keeps_vertices(tmp_path, suffix):
    mesh = small_mesh()
    path = export_mesh(mesh, tmp_path / f"m{suffix}", {"generator": "test", "params": {"a": 1.0}})
    loaded = trimesh.load(path, process=False, force="mesh")
    if suffix == ".stl":  # STL stores triangle soups: compare the triangles' corners instead
        tri = mesh.verts.numpy()[mesh.faces.numpy()]
        assert np.allclose(np.asarray(loaded.triangles), tri, atol=1e-6)
    else:
        assert np.allclose(loaded.vertices, mesh.verts.numpy(), atol=1e-6)
        assert np.array_equal(loaded.faces, mesh.faces.numpy())
    meta = json.loads(sidecar_path(path).read_text())
    assert meta["generator"] == "test" and meta["params"] == {"a": 1.0} and "ipm_version" in meta


def test_glb_carries_metadata(tmp_path):
    path = export_mesh(small_mesh(), tmp_path / "m.glb", {"generator": "g", "params": {"x": 2}})
    scene = trimesh.load(path)
    assert scene.metadata["generator"] == "g" and scene.metadata["params"] == {"x": 2}


def test_bad_suffix_and_empty_mesh(tmp_path):
    with pytest.raises(ValueError, match="expected a suffix among"):
        export_mesh(small_mesh(), tmp_path / "m.xyz")
    empty = TriMesh(torch.zeros(0, 3), torch.zeros(0, 3, dtype=torch.int64))
    with pytest.raises(ValueError, match="empty"):
        export_mesh(empty, tmp_path / "m.obj")
    assert list(tmp_path.iterdir()) == []


def test_atomic_path_leaves_nothing_on_failure(tmp_path):
    target = tmp_path / "out.txt"
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_text("half")
            raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []


def test_own_glb_and_obj_writers_read_back_by_trimesh(tmp_path):
    """:mod:`ipm.io.plain` (the writers a fit's run folder uses, without trimesh): one triangle and numpy values
    in the metadata; chunks 4-byte aligned, the length in the header right, trimesh reads both back."""
    import struct

    mesh = TriMesh(torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.5]]), torch.tensor([[0, 1, 2]]))
    path = export_mesh(mesh, tmp_path / "t.glb", {"generator": "g", "params": {"a": np.float64(0.25)},
                                                  "pose": {"t": np.array([1.0, 2.0])}}, sidecar=False)
    data = path.read_bytes()
    magic, version, length = struct.unpack("<4sII", data[:12])
    assert (magic, version, length) == (b"glTF", 2, len(data)) and len(data) % 4 == 0
    scene = trimesh.load(path)
    assert scene.metadata["params"] == {"a": 0.25} and scene.metadata["pose"] == {"t": [1.0, 2.0]}
    loaded = trimesh.load(path, process=False, force="mesh")
    assert np.allclose(loaded.vertices, mesh.verts.numpy()) and np.array_equal(loaded.faces, [[0, 1, 2]])
    obj = trimesh.load(export_mesh(mesh, tmp_path / "t.obj", sidecar=False), process=False, force="mesh")
    assert np.allclose(obj.vertices, mesh.verts.numpy()) and np.array_equal(obj.faces, [[0, 1, 2]])
