"""CLI: list, generate and jacobian on SDF trees; bad input gives exit code 2 and one line."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
import trimesh
from conftest import run_cli as run


def test_list_nodes_json(capsys):
    code, out, _ = run(["list", "nodes", "--json"], capsys)
    rows = json.loads(out)
    assert code == 0 and len(rows) >= 40
    assert {"name": "sphere", "exact": True}.items() <= rows[[r["name"] for r in rows].index("sphere")].items()


def test_list_presets_and_generators(capsys):
    code, out, _ = run(["list", "presets", "--json"], capsys)
    assert code == 0 and any(r["preset"] == "csg" for r in json.loads(out))
    code, out, _ = run(["list", "generators", "--json"], capsys)
    assert code == 0 and any(r["name"] == "sdftree" for r in json.loads(out))


@pytest.mark.parametrize("gen", ["csg", "chair", "mug", "vase", "wind_rose", "shelf", "table"])
def test_generate_presets_watertight(tmp_path, capsys, gen):
    out = tmp_path / f"{gen}.ply"
    code, stdout, err = run(["generate", gen, "--resolution", "64", "-o", str(out), "--json"], capsys)
    assert code == 0, err
    res = json.loads(stdout)
    mesh = trimesh.load(out, process=False)
    assert mesh.is_watertight and mesh.volume > 0
    assert res["faces"] == len(mesh.faces)
    assert json.loads((tmp_path / f"{gen}.params.json").read_text())["generator"] == gen


def test_generate_with_set_and_params_file(tmp_path, capsys):
    pfile = tmp_path / "p.json"
    pfile.write_text(json.dumps({"generator": "sdftree", "params": {"n2_sphere.radius": 0.6}}))
    a, b = tmp_path / "a.obj", tmp_path / "b.obj"
    assert run(["generate", "csg", "--params", str(pfile), "--resolution", "48", "-o", str(a)], capsys)[0] == 0
    assert run(["generate", "csg", "--set", "n2_sphere.radius=0.6", "--resolution", "48", "-o", str(b)],
               capsys)[0] == 0
    assert np.allclose(trimesh.load(a).vertices, trimesh.load(b).vertices)


def test_generate_tree_file(tmp_path, capsys):
    tree = tmp_path / "t.json"
    tree.write_text(json.dumps({"structure": ["subtraction", "box", "sphere"], "params": [1, 1, 1, 0.6]}))
    code, _, err = run(["generate", str(tree), "--resolution", "48", "-o", str(tmp_path / "t.stl")], capsys)
    assert code == 0, err
    assert trimesh.load(tmp_path / "t.stl").is_watertight


def test_jacobian_check(tmp_path, capsys):
    out = tmp_path / "J.npz"
    code, stdout, err = run(["jacobian", "chair", "--n-points", "500", "--check", "-o", str(out), "--json"],
                            capsys)
    assert code == 0, err
    res = json.loads(stdout)
    assert res["shape"] == [500, 9] and res["max_rel_error"] <= 1e-6
    data = np.load(out)
    assert data["J"].shape == (500, 9) and list(data["names"][-3:]) == ["p.x", "p.y", "p.z"]


def test_jacobian_given_points(tmp_path, capsys):
    pts = tmp_path / "p.npy"
    np.save(pts, np.random.default_rng(0).uniform(-1, 1, (50, 3)))
    code, stdout, _ = run(["jacobian", "csg", "--points", str(pts), "--mode", "fwd", "-o",
                           str(tmp_path / "J.npz"), "--json"], capsys)
    assert code == 0 and json.loads(stdout)["shape"] == [50, 19]


def _tree(tmp_path, data) -> str:
    p = tmp_path / "tree.json"
    p.write_text(data if isinstance(data, str) else json.dumps(data))
    return str(p)


BAD = [
    (lambda t: ["generate", _tree(t, {"node": "blob"}), "-o", str(t / "o.obj")], "unknown node type 'blob'"),
    (lambda t: ["generate", _tree(t, {"node": "union", "children": [{"node": "sphere"}]}), "-o", str(t / "o.obj")],
     "expected 2 children, got 1"),
    (lambda t: ["generate", _tree(t, {"node": "circle"}), "-o", str(t / "o.obj")], "the root must be a 3D node"),
    (lambda t: ["generate", _tree(t, {"node": "extrude", "children": [{"node": "box"}]}), "-o", str(t / "o.obj")],
     "expected 2D children"),
    (lambda t: ["generate", "csg", "--set", "n9_sphere.radius=1", "-o", str(t / "o.obj")], "unknown parameter"),
    (lambda t: ["generate", _tree(t, {"structure": ["sphere"], "params": []}), "-o", str(t / "o.obj")],
     "params ended early"),
    (lambda t: ["generate", "csg", "--set", "n2_sphere.radius=nan", "-o", str(t / "o.obj")], "finite number"),
    (lambda t: ["generate", "csg", "--set", "n2_sphere.radius=99", "-o", str(t / "o.obj")], "expected a value in"),
    (lambda t: ["generate", _tree(t, "{oops"), "-o", str(t / "o.obj")], "not valid JSON"),
    (lambda t: ["generate", str(t / "missing.json"), "-o", str(t / "o.obj")], "not found"),
    (lambda t: ["generate", "csg", "--resolution", "4000", "-o", str(t / "o.obj")], "fit in memory"),
    (lambda t: ["generate", "csg", "-o", str(t / "o.xyz")], "expected a suffix among"),
    (lambda t: ["generate", "nosuchgen", "-o", str(t / "o.obj")], "unknown generator 'nosuchgen'"),
    (lambda t: ["generate", "csg", "--bogus", "-o", str(t / "o.obj")], "No such option: --bogus"),
    (lambda t: ["jacobian", "csg", "--mode", "sideways", "-o", str(t / "J.npz")], "--mode: expected one of"),
    (lambda t: ["jacobian", "csg", "--points", str(t / "none.npy"), "-o", str(t / "J.npz")], "points file not found"),
    (lambda t: ["list", "colours"], "expected one of generators, nodes, presets"),
]


@pytest.mark.parametrize("make_args, message", BAD, ids=[m for _, m in BAD])
def test_bad_input_exit_2_one_line_no_output(tmp_path, capsys, make_args, message):
    args = make_args(tmp_path)
    before = set(tmp_path.iterdir())
    code, out, err = run(args, capsys)
    assert code == 2
    assert err.count("\n") == 1 and err.startswith("ipm: error: ") and message in err, err
    assert "Traceback" not in err
    assert set(tmp_path.iterdir()) == before  # nothing written, not even a temporary file


def test_real_subprocess(tmp_path):
    out = tmp_path / "csg.glb"
    ok = subprocess.run([sys.executable, "-m", "ipm", "generate", "csg", "--resolution", "48", "-o", str(out)],
                        capture_output=True, text=True, timeout=120)
    assert ok.returncode == 0, ok.stderr
    assert out.is_file() and str(out) in ok.stdout
    bad = subprocess.run([sys.executable, "-m", "ipm", "generate", "csg", "--set", "x=1", "-o",
                          str(tmp_path / "x.obj")], capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and bad.stderr.startswith("ipm: error: unknown parameter 'x'")
    assert bad.stderr.count("\n") == 1
