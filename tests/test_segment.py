"""ipm mask / ipm.segment: GrabCut from a box, on a synthetic scene and on the real ClearGrasp photo."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import REAL, require_file
from conftest import run_cli as run

from ipm.errors import InputError
from ipm.io.masks import read_mask, read_photo
from ipm.segment import box_mask, parse_box

PHOTO = REAL / "photos" / "cleargrasp_cups" / "000000130-opaque-rgb-img.jpg"
REFERENCE = Path(__file__).parent / "data" / "cleargrasp_teal_mug_polygon.json"




def iou(a, b) -> float:
    return float((a & b).sum() / (a | b).sum())


def reference_mask() -> np.ndarray:
    """The hand-traced polygon (outer minus the hole inside the handle) as a (720, 1280) mask."""
    from PIL import Image, ImageDraw

    d = json.loads(REFERENCE.read_text())
    im = Image.new("L", tuple(d["image_size"]), 0)
    draw = ImageDraw.Draw(im)
    draw.polygon([tuple(p) for p in d["outer"]], fill=1)
    for hole in d["holes"]:
        draw.polygon([tuple(p) for p in hole], fill=0)
    return np.asarray(im).astype(bool)


def test_a_disk_on_a_textured_background(rng):
    """A red disk on green noise: the mask is the disk (IoU >= 0.97), nothing outside the box."""
    H, W = 120, 160
    img = np.stack([rng.integers(0, 60, (H, W)), rng.integers(120, 200, (H, W)), rng.integers(0, 60, (H, W))], -1)
    yy, xx = np.mgrid[:H, :W]
    disk = (xx - 80) ** 2 + (yy - 60) ** 2 < 30 ** 2
    img[disk] = rng.integers(180, 255, (int(disk.sum()), 1)) * np.array([1, 0, 0]) + np.array([0, 20, 20])
    m = box_mask(img.astype(np.uint8), (40, 20, 121, 101))
    assert iou(m, disk) >= 0.97
    assert not m[:, :40].any() and not m[:, 121:].any()
    assert np.array_equal(m, box_mask(img.astype(np.uint8), (40, 20, 121, 101)))  # deterministic


@pytest.mark.parametrize("box, message", [((-1, 0, 50, 50), "expected 0 <= X0"), ((50, 10, 40, 60), "expected 0 <= X0"),
                                          ((10, 10, 14, 60), "at least 8 pixels"), ((0, 0, 160, 120), "whole image")])
def test_bad_boxes(box, message):
    with pytest.raises(InputError, match=message):
        box_mask(np.zeros((120, 160, 3), np.uint8), box)


def test_parse_box():
    assert parse_box("380, 255,600,495") == (380, 255, 600, 495)
    with pytest.raises(InputError, match="expected X0,Y0,X1,Y1"):
        parse_box("1,2,3")


def test_the_teal_mug_from_its_box_matches_a_hand_traced_mask(tmp_path, capsys):
    """Issue #13: ``ipm mask`` with the box 380,255,600,495 gives IoU >= 0.9 with a polygon traced by hand,
    independently (tests/data/cleargrasp_teal_mug_polygon.json)."""
    require_file(PHOTO)
    out = tmp_path / "mask.png"
    code, stdout, err = run(["mask", PHOTO, "--box", "380,255,600,495", "-o", out, "--overlay", tmp_path / "o.png",
                             "--json"], capsys)
    assert code == 0, err
    m = read_mask(out)
    ref = reference_mask()
    assert m.shape == ref.shape and iou(m, ref) >= 0.9
    assert json.loads(stdout)["pixels"] == int(m.sum())
    assert read_photo(tmp_path / "o.png").shape == (720, 1280, 3)
