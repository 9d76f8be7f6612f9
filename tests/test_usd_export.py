"""Meshes as USD stages (``ipm.io.usd``, ``.usda`` and ``.usdc``): vertices, faces and the generator's parameters
read back with pxr; written atomically; from the command line for any generator."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import run_cli as run

from ipm.errors import InputError
from ipm.generators import get_generator
from ipm.io.export import export_mesh
from ipm.io.usd import read_usd


@pytest.fixture(scope="module")
def cup():
    g = get_generator("dishes")
    values = g.values("mug")
    return g.to_mesh(values, lod="low"), g.metadata(values)


@pytest.mark.parametrize("suffix", [".usda", ".usdc"])
def test_vertices_faces_and_parameters_round_trip(suffix, cup, tmp_path):
    mesh, meta = cup
    path = export_mesh(mesh, tmp_path / f"cup{suffix}", meta)
    verts, faces, back = read_usd(path)
    np.testing.assert_allclose(verts, mesh.verts.numpy(), rtol=0, atol=1e-6)  # points are float32 in USD
    np.testing.assert_array_equal(faces, mesh.faces.numpy())
    assert back["generator"] == "dishes" and back["params"] == meta["params"] and back["ipm_version"]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([f"cup{suffix}", "cup.params.json"])  # no temporaries


def test_text_stage_is_y_up_and_names_the_generator(cup, tmp_path):
    from pxr import Usd, UsdGeom

    mesh, meta = cup
    path = export_mesh(mesh, tmp_path / "cup.usda", meta)
    text = path.read_text()
    assert text.startswith("#usda 1.0") and 'upAxis = "Y"' in text and 'string generator = "dishes"' in text
    stage = Usd.Stage.Open(str(path))
    prim = stage.GetDefaultPrim().GetChild("mesh")
    assert UsdGeom.Mesh(prim).GetSubdivisionSchemeAttr().Get() == "none"
    assert prim.GetCustomData()["params"]["height"] == pytest.approx(meta["params"]["height"])


def test_a_trees_metadata_round_trips_whole(tmp_path):
    g = get_generator("table")
    values = g.spec.defaults()
    meta = g.metadata(values)
    _, _, back = read_usd(export_mesh(g.to_mesh(values, resolution=32), tmp_path / "t.usdc", meta))
    assert back["tree"] == meta["tree"] and back["params"] == meta["params"]


@pytest.mark.parametrize("gen", ["dishes", "csg"])
def test_cli_writes_usd_for_any_generator(gen, tmp_path, capsys):
    out = tmp_path / "x.usda"
    code, stdout, err = run(["generate", gen, "-o", out, "--resolution", "32", "--json"], capsys)
    assert code == 0, err
    verts, faces, meta = read_usd(out)
    assert json.loads(stdout)["faces"] == len(faces) and len(verts) and meta["generator"] == gen


def test_a_file_without_a_mesh_is_refused(tmp_path):
    path = tmp_path / "empty.usda"
    path.write_text("#usda 1.0\n")
    with pytest.raises(InputError, match="expected a mesh"):
        read_usd(path)
