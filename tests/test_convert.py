"""``ipm convert`` end to end: every target writes a file that ``ipm generate`` loads back; ``ipm fit bsp``
runs on a mesh and on masks; bad input exits 2 with one line and writes nothing."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
import torch
import trimesh
from conftest import run_cli as run

from ipm.generators import get_generator


@pytest.fixture
def one_thread():
    """Conversions and fits are loops of small tensor ops (see tests/test_bsp.py)."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="module")
def meshes(tmp_path_factory):
    d = tmp_path_factory.mktemp("meshes")
    trimesh.creation.icosphere(3, radius=0.8).export(d / "sphere.ply")
    trimesh.creation.box((1.0, 0.6, 0.8)).export(d / "box.obj")
    (d / "points.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")          # vertices, no faces
    return d


def test_perturb_round_trip(tmp_path, meshes, capsys, one_thread):
    out = tmp_path / "sphere.json"
    code, stdout, err = run(["convert", meshes / "sphere.ply", "--to", "perturb", "-o", out, "--json"], capsys)
    assert code == 0, err
    res = json.loads(stdout)
    assert res["functions"] == 0 and res["mean_deviation_rel"] <= 1e-6 and res["reached"] is True
    data = json.loads(out.read_text())
    assert data["generator"] == "perturb" and data["source"]["mesh"].endswith("sphere.ply")
    g = get_generator(str(out))
    assert g.name == "perturb" and g.n == 0
    mesh_file = tmp_path / "sphere.obj"
    code, stdout, err = run(["generate", out, "--resolution", "48", "-o", mesh_file, "--json"], capsys)
    assert code == 0, err
    tm = trimesh.load(mesh_file, process=False)
    # the normalized sphere: radius 1, volume 4/3 pi (marching cubes at 48 samples loses a little)
    assert tm.is_watertight and tm.volume == pytest.approx(4 / 3 * np.pi, rel=0.02)


@pytest.mark.parametrize("to", ["bsp", "sdftree"])
def test_bsp_and_sdftree_round_trip(tmp_path, meshes, capsys, one_thread, to):
    out, poly = tmp_path / f"box_{to}.json", tmp_path / f"box_{to}.ply"
    code, stdout, err = run(["convert", meshes / "box.obj", "--to", to, "--planes", "8", "--convexes", "2",
                             "--steps", "120", "--mesh", poly, "-o", out, "--json"], capsys)
    assert code == 0, err
    res = json.loads(stdout)
    assert res["convexes"] == 1 and res["planes"] == 6 and res["iou_3d"] >= 0.99
    g = get_generator(str(out))
    assert g.name == ("bsp" if to == "bsp" else "sdftree")
    back = tmp_path / f"back_{to}.obj"
    code, _, err = run(["generate", out, "--resolution", "64", "-o", back], capsys)
    assert code == 0, err
    a, b = trimesh.load(poly, process=False), trimesh.load(back, process=False)
    assert a.is_watertight and b.is_watertight
    # normalized to the unit bounding sphere: the 1 x 0.6 x 0.8 box (diagonal sqrt(2)) scaled by 2 / sqrt(2)
    k = 2 / np.sqrt(2.0)
    assert a.volume == pytest.approx(0.48 * k**3, rel=0.01) and b.volume == pytest.approx(a.volume, rel=0.03)
    if to == "bsp":
        assert len(a.faces) == 12 and len(b.faces) == 12        # the exact polytope: a box is 12 triangles


@pytest.mark.slow
def test_fit_bsp_on_a_mesh_and_on_masks(tmp_path, meshes, capsys, one_thread):
    code, stdout, err = run(["fit", "bsp", "--target-mesh", meshes / "box.obj", "--budget", "6", "--discrete", "none",
                             "-o", tmp_path / "run_mesh", "--json"], capsys)
    assert code == 0, err
    assert json.loads(stdout)["evaluations"] == 6 and (tmp_path / "run_mesh" / "mesh.glb").is_file()
    masks = tmp_path / "masks"
    code, _, err = run(["render", meshes / "box.obj", "--views", "1", "--size", "32", "-o", masks], capsys)
    assert code == 0, err
    code, stdout, err = run(["fit", "bsp", "--masks", masks, "--budget", "4", "--discrete", "none",
                             "-o", tmp_path / "run_masks", "--json"], capsys)
    assert code == 0, err
    assert 0.0 < json.loads(stdout)["iou_mean"] <= 1.0


BAD = [
    (["points.obj", "--to", "perturb"], "expected triangles"),
    (["sphere.ply", "--to", "perturb", "--tolerance", "0"], "--tolerance: expected a positive number"),
    (["sphere.ply", "--to", "perturb", "--tolerance", "-0.5"], "--tolerance: expected a positive number"),
    (["sphere.ply", "--to", "perturb", "--max-functions", "0"], "--max-functions: expected at least 1"),
    (["sphere.ply", "--to", "nurbs"], "--to: expected one of bsp, perturb, sdftree"),
    (["sphere.ply", "--to", "bsp", "--max-functions", "5"], "--max-functions applies to --to perturb"),
    (["missing.ply", "--to", "bsp"], "mesh file not found"),
    (["sphere.ply", "--to", "perturb", "--resolution", "100000"], "resolution: expected at most 808 (a float32 grid"),
]


@pytest.mark.parametrize("args, message", BAD)
def test_bad_input_exits_2_with_one_line_and_writes_nothing(tmp_path, meshes, capsys, args, message):
    out = tmp_path / "out.json"
    code, stdout, err = run(["convert", meshes / args[0], *args[1:], "-o", out], capsys)
    assert code == 2 and stdout == ""
    assert err.count("\n") == 1 and err.startswith("ipm: error: ") and message in err, err
    assert list(tmp_path.iterdir()) == []


def test_a_huge_resolution_is_refused_before_any_work(tmp_path, meshes, capsys):
    import time

    t0 = time.perf_counter()
    code, _, err = run(["convert", meshes / "sphere.ply", "--to", "perturb", "--resolution", "100000", "--mesh",
                        tmp_path / "o.ply", "-o", tmp_path / "o.json"], capsys)
    assert code == 2 and "fit in 2 GiB" in err and time.perf_counter() - t0 < 5.0, err


def test_wrong_output_suffix(tmp_path, meshes, capsys):
    code, _, err = run(["convert", meshes / "box.obj", "--to", "bsp", "-o", tmp_path / "out.txt"], capsys)
    assert code == 2 and "expected a suffix among .json" in err and list(tmp_path.iterdir()) == []


def test_real_subprocess(tmp_path, meshes):
    out = tmp_path / "s.json"
    ok = subprocess.run([sys.executable, "-m", "ipm", "convert", str(meshes / "sphere.ply"), "--to", "perturb",
                         "-o", str(out)], capture_output=True, text=True, timeout=300)
    assert ok.returncode == 0, ok.stderr
    assert f"output: {out}" in ok.stdout and json.loads(out.read_text())["perturbations"] == 0
    bad = subprocess.run([sys.executable, "-m", "ipm", "convert", str(meshes / "sphere.ply"), "--to", "perturb",
                          "--tolerance", "0", "-o", str(tmp_path / "t.json")], capture_output=True, text=True,
                         timeout=300)
    assert bad.returncode == 2 and bad.stderr.startswith("ipm: error: --tolerance") and bad.stderr.count("\n") == 1
    assert not (tmp_path / "t.json").exists()


def test_kmeans_labels_are_nearest_centers_and_centers_are_means():
    """The plane clustering (scipy's kmeans2 from a farthest-point start) is a fixed point of Lloyd's step."""
    from ipm.convert.bsp import kmeans

    rng = np.random.default_rng(0)
    pts = np.concatenate([rng.normal(c, 0.05, size=(200, 4)) for c in np.eye(4) * 3])
    centers, lab = kmeans(pts, 4, np.random.default_rng(1), iters=30)
    d = ((pts[:, None] - centers[None]) ** 2).sum(-1)
    assert np.array_equal(lab, d.argmin(1))
    for j in range(4):
        assert np.allclose(centers[j], pts[lab == j].mean(0))
    assert sorted(np.bincount(lab)) == [200, 200, 200, 200]
