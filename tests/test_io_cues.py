"""Depth maps, normal maps and part labels as files (ipm.io.cues), and ``ipm render`` writing them."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from conftest import run_cli as run

from ipm.errors import InputError
from ipm.io import cues
from ipm.io.masks import load_mask_set


def _depth(rng, h=12, w=17):
    d = rng.uniform(0.3, 4.0, size=(h, w))
    d[rng.random((h, w)) < 0.3] = np.nan
    return d


def test_depth_npy_round_trip_keeps_float32_values_and_holes(rng, tmp_path):
    d = _depth(rng)
    back = cues.read_depth(cues.write_depth(tmp_path / "d.npy", d))
    assert np.array_equal(np.isnan(back), np.isnan(d))
    ok = ~np.isnan(d)
    assert np.array_equal(back[ok], d[ok].astype(np.float32).astype(np.float64))


def test_depth_png_is_millimetres(rng, tmp_path):
    from PIL import Image

    d = _depth(rng)
    path = cues.write_depth(tmp_path / "d.png", d)
    raw = np.asarray(Image.open(path))
    assert raw.dtype == np.uint16 and raw[np.isnan(d)].max() == 0
    back = cues.read_depth(path)
    ok = ~np.isnan(d)
    assert np.array_equal(np.isnan(back), ~ok)
    assert np.abs(back[ok] - d[ok]).max() <= 0.0005 + 1e-12      # half a millimetre
    assert np.allclose(cues.read_depth(path, png_scale=1.0)[ok], np.round(d[ok] * 1000))


def test_depth_png_refuses_what_16_bits_cannot_hold(tmp_path):
    with pytest.raises(InputError, match="expected depths in"):
        cues.write_depth(tmp_path / "d.png", np.full((2, 2), 70.0))
    assert not (tmp_path / "d.png").exists()


@pytest.mark.parametrize("make, message", [
    (lambda p: np.save(p / "d.npy", np.full((3, 3), np.nan)), "expected some valid depth"),
    (lambda p: np.save(p / "d.npy", np.zeros((3, 3, 2))), "expected a \\(H, W\\) array"),
    (lambda p: (p / "d.npy").write_bytes(b"\x00garbage"), "expected a .npy array"),
])
def test_bad_depth_files(tmp_path, make, message):
    make(tmp_path)
    with pytest.raises(InputError, match=message):
        cues.read_depth(tmp_path / "d.npy")


def test_parts_round_trip_and_names(rng, tmp_path):
    lab = rng.integers(-1, 5, size=(9, 11))
    assert np.array_equal(cues.read_parts(cues.write_parts(tmp_path / "p.png", lab)), lab)
    cues.write_part_names(tmp_path, ["walls", "windows"])
    assert cues.read_part_names(tmp_path) == {0: "walls", 1: "windows"}
    (tmp_path / cues.PARTS_FILE).write_text(json.dumps({"labels": {"1": "a", "2": "a"}}))
    with pytest.raises(InputError, match="distinct names"):
        cues.read_part_names(tmp_path)
    (tmp_path / cues.PARTS_FILE).write_text(json.dumps({"labels": {"0": "a"}}))
    with pytest.raises(InputError, match="expected labels 1..255"):
        cues.read_part_names(tmp_path)


def test_render_writes_cues_that_match_the_rasterizer(tmp_path, capsys):
    """``ipm render building``: depth where the mask is, NaN elsewhere; part labels are the faces' groups."""
    from ipm.generators import get_generator
    from ipm.io.meshes import normalize_mesh
    from ipm.render.raster import rasterize_mesh

    out = tmp_path / "r"
    code, stdout, err = run(["render", "building", "--views", "2", "--size", "48", "--no-previews", "-o", out,
                             "--json"], capsys)
    assert code == 0, err
    res = json.loads(stdout)
    assert len(res["depth"]) == 2 and len(res["parts"]) == 2
    ms = load_mask_set(out)
    g = get_generator("building")
    mesh = normalize_mesh(g.to_mesh(g.values()))
    names = cues.read_part_names(out)
    assert [names[k] for k in sorted(names)] == list(mesh.group_names)
    for i, cam in enumerate(ms.cameras):
        fr = rasterize_mesh(mesh, cam)
        depth = cues.read_depth(out / cues.depth_name(i))
        mask = ms.masks[i].numpy()
        assert np.array_equal(~np.isnan(depth), mask)
        assert np.allclose(depth[mask], fr.depth.numpy()[mask], rtol=1e-6)
        parts = cues.read_parts(out / cues.part_name(i))
        want = torch.where(fr.mask, mesh.groups[fr.face.clamp_min(0)], -1).numpy()
        assert np.array_equal(parts, want)
        assert {1, 0} <= set(np.unique(parts[mask]).tolist())   # windows and walls both seen
        assert (out / cues.normal_name(i)).is_file()


def test_render_without_parts_or_cues(tmp_path, capsys):
    code, stdout, _ = run(["render", "csg", "--views", "1", "--size", "32", "--resolution", "32", "--no-previews",
                           "-o", tmp_path / "a", "--json"], capsys)
    assert code == 0 and "parts" not in json.loads(stdout)
    assert (tmp_path / "a" / "depth_000.npy").is_file() and not (tmp_path / "a" / cues.PARTS_FILE).exists()
    code, stdout, _ = run(["render", "csg", "--views", "1", "--size", "32", "--resolution", "32", "--no-previews",
                           "--no-cues", "-o", tmp_path / "b", "--json"], capsys)
    assert code == 0 and "depth" not in json.loads(stdout)
    assert sorted(p.name for p in (tmp_path / "b").iterdir()) == ["cameras.json", "view_000.png"]
