"""``ipm render`` and mask sets: outputs, comparison overlays, and bad input (exit 2, one line on stderr,
nothing left behind)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import ROOT, real_path
from conftest import run_cli as run
from PIL import Image

from ipm.files import staged_directory
from ipm.io.masks import load_mask_set, save_mask_set
from ipm.render.camera import input_views, load_cameras

MUG = "vessels/probcomp_mug.obj"




def assert_usage_error(code, err, *needles):
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("ipm: error: "), err
    assert "Traceback" not in err
    for n in needles:
        assert n in lines[0], lines[0]


def test_render_mesh_file(tmp_path, capsys):
    out = tmp_path / "mug"
    code, stdout, err = run(["render", real_path(MUG), "--views", "2", "--size", "64", "-o", out, "--json"],
                            capsys)
    assert code == 0, err
    res = json.loads(stdout)
    assert res["views"] == 2 and len(res["masks"]) == 2 and len(res["previews"]) == 2
    assert sorted(p.name for p in out.iterdir()) == ["cameras.json", "depth_000.npy", "depth_001.npy",
                                                    "normal_000.png", "normal_001.png", "preview_000.png",
                                                    "preview_001.png", "view_000.png", "view_001.png"]
    ms = load_mask_set(out)
    assert ms.masks.shape == (2, 64, 64) and 200 < int(ms.masks[0].sum()) < 64 * 64
    for a, b in zip(ms.cameras, input_views(2, 64)):
        assert np.allclose(a.eye.numpy(), b.eye.numpy())
    with Image.open(out / "view_000.png") as im:
        assert im.mode == "L" and set(np.unique(np.asarray(im))) <= {0, 255}


def test_render_generator_and_compare_with_masks(tmp_path, capsys):
    a = tmp_path / "a"
    code, _, err = run(["render", "csg", "--resolution", "40", "--views", "1", "--size", "48", "-o", a], capsys)
    assert code == 0, err
    b = tmp_path / "b"
    code, stdout, err = run(["render", "csg", "--resolution", "40", "--masks", a, "--no-previews", "-o", b,
                             "--json"], capsys)
    assert code == 0, err
    res = json.loads(stdout)
    assert res["iou"] == [1.0] and (b / "overlay_000.png").is_file() and not (b / "preview_000.png").exists()


def test_render_with_cameras_file_and_up_z(tmp_path, capsys):
    cams = tmp_path / "cameras.json"
    cams.write_text(json.dumps([{"eye": [0, 0.5, 3.0], "target": [0, 0, 0], "up": [0, 1, 0], "fov_deg": 40,
                                 "width": 40, "height": 30}]))
    out = tmp_path / "o"
    code, _, err = run(["render", real_path("vessels/ocrtoc_mug.ply"), "--up", "z", "--cameras", cams, "-o", out],
                       capsys)
    assert code == 0, err
    assert load_cameras(out / "cameras.json")[0].width == 40
    assert load_mask_set(out).masks.shape == (1, 30, 40)


def _mask_set(tmp_path, n=2, size=16) -> Path:
    folder = tmp_path / "set"
    masks = np.zeros((n, size, size), bool)
    masks[:, 4:12, 5:11] = True
    save_mask_set(folder, masks, input_views(n, size))
    return folder


def test_mask_set_round_trip(tmp_path):
    folder = _mask_set(tmp_path)
    ms = load_mask_set(folder)
    assert len(ms) == 2 and ms.masks.dtype.is_floating_point is False
    assert int(ms.masks[1].sum()) == 8 * 6 and [p.name for p in ms.paths] == ["view_000.png", "view_001.png"]


def _break(folder: Path, how: str) -> str:
    """Damage a mask set; returns a piece of the expected message."""
    if how == "not_an_image":
        (folder / "view_001.png").write_text("this is not a PNG")
        return "expected a PNG image"
    if how == "wrong_size":
        Image.fromarray(np.zeros((10, 16), np.uint8)).save(folder / "view_001.png")
        return "expected 16x16 pixels"
    if how == "missing_field":
        data = json.loads((folder / "cameras.json").read_text())
        del data[1]["fov_deg"]
        (folder / "cameras.json").write_text(json.dumps(data))
        return "missing fov_deg"
    if how == "count":
        data = json.loads((folder / "cameras.json").read_text())
        (folder / "cameras.json").write_text(json.dumps(data[:1]))
        return "2 masks and 1 entries"
    if how == "gap":
        (folder / "view_001.png").rename(folder / "view_002.png")
        return "gap at view_001.png"
    if how == "no_cameras":
        (folder / "cameras.json").unlink()
        return "expected cameras.json"
    raise AssertionError(how)


BROKEN = ["not_an_image", "wrong_size", "missing_field", "count", "gap", "no_cameras"]


@pytest.mark.parametrize("how", BROKEN)
def test_load_mask_set_rejects(tmp_path, how):
    folder = _mask_set(tmp_path)
    needle = _break(folder, how)
    with pytest.raises(ValueError, match="expected") as e:
        load_mask_set(folder)
    assert needle in str(e.value)


@pytest.mark.parametrize("how", BROKEN)
def test_render_with_broken_mask_set_exits_2(tmp_path, capsys, how):
    folder = _mask_set(tmp_path)
    needle = _break(folder, how)
    out = tmp_path / "out"
    code, _, err = run(["render", real_path(MUG), "--masks", folder, "-o", out], capsys)
    assert_usage_error(code, err, needle)
    assert not out.exists()


def test_bad_inputs_exit_2_and_leave_nothing(tmp_path, capsys):
    out = tmp_path / "out"
    flat = tmp_path / "flat.obj"
    flat.write_text("v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n")
    inside = tmp_path / "inside.json"
    inside.write_text(json.dumps([{"eye": [0.05, 0.1, 0.0], "target": [0, 0, 1], "up": [0, 1, 0], "fov_deg": 60,
                                   "width": 16, "height": 16}]))
    cases = [
        (["render", flat, "-o", out], "zero-area"),
        (["render", real_path(MUG), "--cameras", inside, "-o", out], "inside the object"),
        (["render", tmp_path / "missing.ply", "-o", out], "not found"),
        (["render", real_path(MUG), "--views", "2", "--cameras", inside, "-o", out], "give one of"),
        (["render", real_path(MUG), "--views", "0", "-o", out], "--views"),
        (["render", real_path(MUG), "--up", "x", "-o", out], "--up"),
        (["render", real_path(MUG), "--set", "a=1", "-o", out], "apply to generators"),
        (["render", "no_such_generator", "-o", out], "unknown generator"),
    ]
    for args, needle in cases:
        code, _, err = run(args, capsys)
        assert_usage_error(code, err, needle)
        assert not out.exists(), args
    assert sorted(p.name for p in tmp_path.iterdir()) == ["flat.obj", "inside.json"]


def test_staged_directory_leaves_nothing_on_error(tmp_path):
    out = tmp_path / "o"
    with pytest.raises(RuntimeError):
        with staged_directory(out) as tmp:
            (tmp / "a.png").write_bytes(b"x")
            raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []
    out.mkdir()
    (out / "keep.txt").write_text("k")
    with staged_directory(out) as tmp:
        (tmp / "a.png").write_bytes(b"x")
    assert sorted(p.name for p in out.iterdir()) == ["a.png", "keep.txt"]
    assert [p.name for p in tmp_path.iterdir()] == ["o"]


@pytest.mark.slow
def test_subprocess(tmp_path):
    out = tmp_path / "masks"
    mug = real_path(MUG)
    ok = subprocess.run([sys.executable, "-m", "ipm", "render", str(mug), "--views", "1", "--size", "32",
                         "-o", str(out)], capture_output=True, text=True, cwd=ROOT)
    assert ok.returncode == 0, ok.stderr
    assert (out / "view_000.png").is_file() and f"dir: {out}" in ok.stdout
    bad = subprocess.run([sys.executable, "-m", "ipm", "render", str(mug), "--size", "32", "--masks",
                          str(out), "-o", str(tmp_path / "x")], capture_output=True, text=True, cwd=ROOT)
    assert bad.returncode == 2
    assert bad.stderr.strip().splitlines() == [bad.stderr.strip()] and bad.stderr.startswith("ipm: error: ")
    assert not (tmp_path / "x").exists()


def test_render_normalizes_to_the_unit_sphere_and_warns_when_a_view_clips(tmp_path, capsys, caplog):
    """``--normalize`` (the default) keeps the object inside every protocol view (protocol v2); a mesh in
    file units that the views clip is rendered, with a warning naming the clipped views."""
    import logging

    import trimesh

    from ipm.metrics import touches_border

    code, _, err = run(["render", real_path(MUG), "--up", "z", "--views", "4", "--size", "64", "--no-previews",
                        "-o", tmp_path / "ok"], capsys)
    assert code == 0, err
    assert not any(touches_border(m) for m in load_mask_set(tmp_path / "ok").masks.numpy() > 0.5)
    big = tmp_path / "big.ply"
    trimesh.creation.box((3.0, 3.0, 3.0)).export(big)
    with caplog.at_level(logging.WARNING, logger="ipm"):
        code, _, err = run(["render", big, "--no-normalize", "--views", "2", "--size", "32", "--no-previews",
                            "-o", tmp_path / "big"], capsys)
    assert code == 0, err
    assert "touches the image border in views 0, 1" in caplog.text
