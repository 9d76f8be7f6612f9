"""Pictures: shaded previews (group colors), overlays with IoU, contact sheets, loss plots (lazy
matplotlib), and loading meshes with the protocol's up axis and normalization."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import torch
from conftest import real_path
from PIL import Image

from ipm.errors import InputError
from ipm.io.meshes import load_mesh, normalize_mesh, to_y_up
from ipm.render.camera import orbit_camera
from ipm.render.preview import render_preview, render_sdf_preview, write_preview
from ipm.types import TriMesh
from ipm.viz import contact_sheet, mask_iou, overlay, plot_losses


def two_boxes() -> TriMesh:
    import trimesh

    a = TriMesh.from_trimesh(trimesh.creation.box((1, 1, 1)))
    b = TriMesh(a.verts + torch.tensor([1.2, 0.0, 0.0], dtype=torch.float64), a.faces)
    return TriMesh.concat([a, b], ["left", "right"])


def test_preview_is_shaded_with_group_colors(tmp_path):
    mesh = two_boxes()
    cam = orbit_camera(20.0, 25.0, 4.0, target=(0.6, 0.0, 0.0), width=96, height=64)
    img = render_preview(mesh, cam)
    assert img.shape == (64, 96, 3) and img.dtype == np.uint8
    assert (img[0, 0] == 255).all()  # white background
    left, right = img[36, 30].astype(int), img[36, 62].astype(int)
    assert (left != 255).any() and (right != 255).any()
    # different groups, different hues (not just brighter or darker)
    assert np.argmax(left) != np.argmax(right)
    path = write_preview(mesh, tmp_path / "p.png", cam)
    with Image.open(path) as im:
        assert im.size == (96, 64) and im.mode == "RGB"
    # without groups: one color, and Lambert shading makes the top face darker than the front face
    plain = render_preview(TriMesh(mesh.verts, mesh.faces), cam).astype(int)
    assert np.argmax(plain[36, 30]) == np.argmax(plain[36, 62])
    assert plain[22, 30].sum() < plain[36, 30].sum()


def test_sdf_preview():
    cam = orbit_camera(0.0, 0.0, 3.0, width=32, height=32)
    img = render_sdf_preview(lambda p: p.norm(dim=-1) - 0.6, cam, [-1] * 3, [1] * 3)
    assert img.shape == (32, 32, 3)
    assert (img[0, 0] == 255).all() and (img[16, 16] < 255).any()
    assert 255 * 3 > img[16, 9].sum() and img[16, 16].sum() > img[16, 9].sum()  # headlight: center is brightest


def test_overlay_colors_and_iou():
    t = np.zeros((20, 30), bool)
    f = np.zeros((20, 30), bool)
    t[2:10, 2:12] = True
    f[5:15, 8:20] = True
    img = overlay(t, f, "view 0")
    assert img.size == (30, 20 + 18)
    arr = np.asarray(img)[18:]
    assert tuple(arr[3, 3]) == (220, 40, 40)  # target only: red
    assert tuple(arr[12, 15]) == (40, 180, 60)  # fit only: green
    assert tuple(arr[6, 9]) == (240, 210, 40)  # both: yellow
    inter, union = (t & f).sum(), (t | f).sum()
    assert mask_iou(t, f) == pytest.approx(inter / union)
    assert mask_iou(torch.from_numpy(t), torch.from_numpy(t)) == 1.0
    assert np.asarray(img)[:18].min() < 128  # the title text was drawn


def test_contact_sheet():
    ims = [np.zeros((10, 12), bool), np.full((10, 12, 3), 128, np.uint8), Image.new("RGB", (8, 8))]
    sheet = contact_sheet(ims, cols=2, labels=["a", "b", "c"], pad=2)
    assert sheet.size == (2 * 12 + 3 * 2, 2 * (10 + 14) + 3 * 2)
    with pytest.raises(ValueError, match="one label per image"):
        contact_sheet(ims, labels=["a"])


def test_loss_plot(tmp_path):
    """Both curves drawn in their colours (and a legend), on a log scale; one value and non-positive values too."""
    from ipm.viz.plots import COLORS, nice_ticks

    path = plot_losses({"train": [1.0, 0.5, 0.2], "val": [1.2, 0.7, 0.4]}, tmp_path / "loss.png")
    with Image.open(path) as im:
        assert im.format == "PNG" and im.size[0] > 100
        pixels = np.asarray(im.convert("RGB")).reshape(-1, 3)
    for color in COLORS[:2]:
        assert (pixels == color).all(1).sum() > 50, color
    for curve in ([0.3], [0.0, -1.0, 2.0], [float("nan"), 1.0, 0.5]):
        with Image.open(plot_losses(curve, tmp_path / "one.png")) as im:
            assert (np.asarray(im.convert("RGB")).reshape(-1, 3) == COLORS[0]).all(1).any()
    with pytest.raises(InputError, match="non-empty curve"):
        plot_losses({"a": []}, tmp_path / "none.png")
    assert nice_ticks(0, 1) == pytest.approx([0, 0.2, 0.4, 0.6, 0.8, 1.0])
    assert nice_ticks(0, 2, integer=True) == [0, 1, 2]
    assert nice_ticks(0.013, 0.87)[0] >= 0.013


def test_viz_and_render_do_not_import_matplotlib():
    code = "import sys, ipm.viz, ipm.render, ipm.cli; print('matplotlib' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_load_mesh_z_up_and_normalize():
    raw = load_mesh(real_path("vessels/ocrtoc_mug.ply"), up="y", normalize=False)
    ext = raw.verts.amax(0) - raw.verts.amin(0)
    assert float(ext[2]) == pytest.approx(0.081, abs=2e-3)  # the scan stands along Z
    mesh = load_mesh(real_path("vessels/ocrtoc_mug.ply"), up="z")
    lo, hi = mesh.verts.amin(0), mesh.verts.amax(0)
    assert torch.allclose((lo + hi) / 2, torch.zeros(3, dtype=torch.float64), atol=1e-12)
    # the unit bounding sphere (protocol v2): the farthest vertex at distance 1
    assert float(torch.linalg.vector_norm(mesh.verts, dim=1).max()) == pytest.approx(1.0, abs=1e-12)
    # Z-up height became the Y extent (proportions kept)
    assert float((hi - lo)[1] / (hi - lo).max()) == pytest.approx(float(ext[2]) / float(ext.max()), rel=1e-9)
    v = torch.tensor([[1.0, 2.0, 3.0]])
    assert to_y_up(v, "z").tolist() == [[1.0, 3.0, -2.0]]


def test_mesh_errors(tmp_path):
    with pytest.raises(ValueError, match="expected an existing file"):
        load_mesh(tmp_path / "nope.obj")
    bad = tmp_path / "bad.stl"
    bad.write_bytes(b"\x00" * 10)
    with pytest.raises(ValueError, match="bad.stl"):
        load_mesh(bad)
    flat = tmp_path / "flat.obj"
    flat.write_text("v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n")
    with pytest.raises(ValueError, match="zero-area"):
        load_mesh(flat)
    with pytest.raises(ValueError, match="up axis"):
        load_mesh(flat, up="x")
    with pytest.raises(ValueError, match="nonzero extent"):
        normalize_mesh(TriMesh(torch.zeros(3, 3, dtype=torch.float64), torch.tensor([[0, 1, 2]])))
