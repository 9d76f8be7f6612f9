"""Hostile file content and values (issue #32): nesting that gets around the depth limit, numbers beyond
what numpy, torch and a double hold, decompression bombs, wrong types in macro files, a weights file that
is a plain array, a non-manifold training mesh, booleans where numbers belong, unknown camera keys, an
unreadable STL. Each exits 2 with one line ``ipm: error: ...`` naming the file or option and what is
allowed, writes nothing and changes no input (the contract of ``tests/test_cli_reliability.py``, whose
style this file follows). Big and deep inputs are built as text or as small files with huge headers,
never allocated for real.

Also what a user expects instead of an error: ``--discrete enumerate`` given ranges for some discrete
parameters searches those and holds the others at the start's values.
"""

from __future__ import annotations

import io
import json
import struct
import zipfile
import zlib
from pathlib import Path

import numpy as np
import pytest
from conftest import real_path, refusal, write_file
from conftest import run_cli as run

MUG = "vessels/ocrtoc_mug.ply"
HUGE = "99999999999999999999999"




def _png_header(width: int, height: int) -> bytes:
    """A PNG of ``width x height`` grey pixels that is 65 bytes long: a header and an empty image stream
    (Pillow refuses its size from the header, before decoding)."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(b"")) + chunk(b"IEND", b""))


def _bomb(path: Path) -> Path:
    """A 400-megapixel PNG (20000 x 20000) of 65 bytes."""
    return write_file(path, _png_header(20000, 20000))


def _photo(path: Path, size=(48, 64)) -> Path:
    from PIL import Image

    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.full((*size, 3), 90, np.uint8)).save(path)
    return path


def _camera(width: int = 32, height: int = 32) -> dict:
    from ipm.render.camera import orbit_camera

    return orbit_camera(30.0, 25.0, 3.2, fov_deg=40.0, width=width, height=height).to_json()


def _mask_set(folder: Path, view: bytes | None = None) -> Path:
    """One 32 x 32 view and its cameras.json; ``view``: the PNG's bytes instead of a disc."""
    from PIL import Image

    folder.mkdir(parents=True, exist_ok=True)
    if view is None:
        yy, xx = np.mgrid[:32, :32]
        Image.fromarray((((yy - 16) ** 2 + (xx - 16) ** 2 < 64) * 255).astype(np.uint8)).save(folder / "view_000.png")
    else:
        (folder / "view_000.png").write_bytes(view)
    write_file(folder / "cameras.json", [_camera()])
    return folder


def _chain(folder: Path, n: int, prefix: str = "chain") -> Path:
    """``n`` macro files, each using the next (``{prefix}0`` uses ``{prefix}1`` ... the last a sphere), and a
    tree file using the first; returns the tree file."""
    for k in range(n):
        body = {"node": f"{prefix}{k + 1}"} if k < n - 1 else {"node": "sphere", "params": {"radius": 0.5}}
        write_file(folder / "lib" / f"{prefix}{k:04d}.json",
               {"name": f"{prefix}{k}", "params": [{"name": "r", "default": 0.5, "lo": 0.1, "hi": 1.0}],
                "tree": body})
    return write_file(folder / "tree.json", {"tree": {"node": f"{prefix}0"}})


def _macro(folder: Path, **change) -> Path:
    """A good macro file with ``change`` applied (a value of None removes the key); returns its folder."""
    spec = {"name": "pillar", "doc": "a pillar", "params": [{"name": "h", "default": 1.0, "lo": 0.1, "hi": 3.0}],
            "tree": {"node": "translate", "params": {"y": {"mul": ["h", 0.5]}},
                     "children": [{"node": "cylinder", "params": {"radius": 0.1, "height": "h"}}]}}
    for k, v in change.items():
        if v is None:
            spec.pop(k)
        else:
            spec[k] = v
    write_file(folder / "lib" / "m.json", spec)
    return folder / "lib"


def _experiment(folder: Path, text: str) -> Path:
    return write_file(folder / "experiments" / "e.toml", 'name = "e"\nbudget = 2\nsize = 64\nheldout_size = 64\n'
                  'samples = 200\n' + text + '\n[[targets]]\nname = "s"\ngenerator = "dishes"\npreset = "mug"\n'
                  '[[methods]]\nname = "vh"\nmethod = "visual-hull"\nresolution = 16\n')


def _fin(path: Path) -> Path:
    """A closed icosphere with one more triangle on one of its edges: an edge of three faces."""
    import trimesh

    m = trimesh.creation.icosphere(1)
    V = np.vstack([m.vertices, [[0.0, 0.0, 3.0]]])
    a, b = m.faces[0][:2]
    path.parent.mkdir(parents=True, exist_ok=True)
    trimesh.Trimesh(V, np.vstack([m.faces, [[a, b, len(V) - 1]]]), process=False).export(path)
    return path


def _big_npz(path: Path) -> Path:
    """A weights file of 200 bytes whose one array declares 100000 x 100000 doubles (75 GB)."""
    head = io.BytesIO()
    np.lib.format.write_array_header_1_0(head, {"descr": "<f8", "fortran_order": False, "shape": (100000, 100000)})
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("net.init_net.0.weight.npy", head.getvalue() + bytes(1000))
    return path


def _nested_text(depth: int, open_: str, close: str, inner: str = "") -> str:
    return open_ * depth + inner + close * depth


def _circle(folder: Path) -> Path:
    """Two macro files using each other, and a tree file using one."""
    write_file(folder / "lib" / "a.json", {"name": "ca", "params": [], "tree": {"node": "cb"}})
    write_file(folder / "lib" / "b.json", {"name": "cb", "params": [], "tree": {"node": "ca"}})
    return write_file(folder / "t.json", {"tree": {"node": "ca"}})


def _deep_cameras(folder: Path) -> Path:
    """A mask set whose cameras.json nests 50,000 deep."""
    _mask_set(folder)
    write_file(folder / "cameras.json", _nested_text(50000, '{"cameras": [', "]}"))
    return folder


# case -> (arguments given the input folder i and output folder o, the words the one line must contain)
CASES = {
    # 1. nesting that gets around the depth limit
    "generate: 600 chained macros": (
        lambda i, o: ["generate", _chain(i, 600), "--library", i / "lib", "-o", o / "m.obj"],
        ("64 levels", "the limit", "chain0536.json")),
    "generate: macros using each other in a circle": (
        lambda i, o: ["generate", _circle(i), "--library", i / "lib", "-o", o / "m.obj"],
        ("a.json", "circle", "ca uses cb uses ca")),
    "render: cameras.json nested 50,000 deep": (
        lambda i, o: ["render", "dishes", "--cameras", write_file(i / "c.json", _nested_text(50000, "[", "]")),
                      "-o", o], ("c.json", "at most 4 deep", "50000")),
    "fit: a mask set's cameras.json nested 50,000 deep": (
        lambda i, o: ["fit", "dishes", "--masks", _deep_cameras(i / "m"), "-o", o], ("cameras.json", "at most 4 deep")),
    "bench: TOML arrays nested 5,000 deep": (
        lambda i, o: ["bench", _experiment(i, "x = " + _nested_text(5000, "[", "]")), "-o", o],
        ("e.toml", "at most 32 deep", "the limit")),
    "bench: TOML inline tables nested 5,000 deep": (
        lambda i, o: ["bench", _experiment(i, "x = " + _nested_text(5000, "{a = ", "}", "1")), "-o", o],
        ("e.toml", "at most 32 deep")),
    "bench: TOML dotted keys 5,000 deep": (
        lambda i, o: ["bench", _experiment(i, "[methods_x]\n" + ".".join(["a"] * 5000) + " = 1"), "-o", o],
        ("e.toml", "at most 32 deep")),
    # 2. overflow
    **{f"{cmd}: seed beyond the range": (lambda i, o, args=args: [*args(i, o), "--seed", HUGE],
                                         ("--seed", "0 to 2147483647", HUGE))
       for cmd, args in {
           "generate": lambda i, o: ["generate", "dishes", "--random", "-o", o / "m.obj"],
           "fit": lambda i, o: ["fit", "dishes", "--target-mesh", real_path(MUG), "-o", o],
           "convert": lambda i, o: ["convert", real_path(MUG), "--to", "bsp", "-o", o / "c.json"],
           "jacobian": lambda i, o: ["jacobian", "chair", "-o", o / "j.npz"],
           "mask": lambda i, o: ["mask", _photo(i / "p.png"), "--box", "1,1,20,20", "-o", o / "m.png"],
           "render": lambda i, o: ["render", "dishes", "--random", "-o", o],
           "train-subdivision": lambda i, o: ["train-subdivision", "-o", o / "w.npz"],
       }.items()},
    "mask: seed beyond OpenCV's C int": (
        lambda i, o: ["mask", _photo(i / "p.png"), "--box", "1,1,20,20", "--seed", "2147483648", "-o", o / "m.png"],
        ("--seed", "2147483647")),
    "generate: 1e400 in a params file": (
        lambda i, o: ["generate", "dishes", "--params",
                      write_file(i / "p.json", '{"generator": "dishes", "params": {"height": 1e400}}'), "-o", o / "m.obj"],
        ("p.json", "'height'", "1e400", "1.8e308")),
    "generate: --set height=1e400": (
        lambda i, o: ["generate", "dishes", "--set", "height=1e400", "-o", o / "m.obj"],
        ("'height'", "1e400", "1.8e308")),
    "generate: --set floors=1e400 (an integer parameter)": (
        lambda i, o: ["generate", "building", "--set", "floors=1e400", "-o", o / "m.obj"], ("'floors'", "1e400")),
    "generate: a 400-digit integer in a tree file": (
        lambda i, o: ["generate", write_file(i / "t.json", '{"tree": {"node": "sphere", "params": {"radius": 1'
                                         + "0" * 400 + "}}}"), "-o", o / "m.obj"],
        ("t.json", "'radius'", "401 characters")),
    "generate: a 5000-digit integer in a params file": (
        lambda i, o: ["generate", "dishes", "--params", write_file(i / "p.json", '{"params": {"height": 1'
                                                             + "0" * 5000 + "}}"), "-o", o / "m.obj"],
        ("p.json", "'height'", "1.8e308")),
    "bench: a seed beyond the range": (
        lambda i, o: ["bench", _experiment(i, "seeds = [" + HUGE + "]"), "-o", o], ("e.toml", "seeds")),
    # 3. 400-megapixel images
    "mask: a 400-megapixel photo": (
        lambda i, o: ["mask", _bomb(i / "big.png"), "--box", "1,1,20,20", "-o", o / "m.png"],
        ("big.png", "89,478,485 pixels", "the limit", "400,000,000")),
    "vectorize: a 400-megapixel drawing": (
        lambda i, o: ["vectorize", _bomb(i / "big.png"), "-o", o / "v.svg"], ("big.png", "89,478,485 pixels")),
    "fit: a 400-megapixel --shape image": (
        lambda i, o: ["fit", write_file(i / "t.json", {"tree": {"node": "circle"}}), "--shape", _bomb(i / "big.png"),
                      "-o", o], ("big.png", "89,478,485 pixels")),
    "fit: a 100-megapixel --shape image (Pillow only warns)": (
        lambda i, o: ["fit", write_file(i / "t.json", {"tree": {"node": "circle"}}), "--shape",
                      write_file(i / "big.png", _png_header(10000, 10000)), "-o", o], ("big.png", "100,000,000")),
    "fit: a 400-megapixel photo": (
        lambda i, o: ["fit", "dishes", "--image", _bomb(i / "big.png"), "--box", "1,1,20,20", "-o", o],
        ("big.png", "89,478,485 pixels")),
    "fit: a 400-megapixel view in a mask set": (
        lambda i, o: ["fit", "dishes", "--masks", _mask_set(i / "m", _png_header(20000, 20000)), "-o", o],
        ("view_000.png", "89,478,485 pixels")),
    "fit: a 400-megapixel depth map": (
        lambda i, o: ["fit", "dishes", "--masks", _mask_set(i / "m"), "--depth",
                      _bomb(i / "d" / "depth_000.png").parent, "-o", o], ("depth_000.png", "89,478,485 pixels")),
    # 4. wrong types in macro files
    **{f"generate: macro file with {label}": (
        lambda i, o, change=change: ["generate", "chair", "--library", _macro(i, **change), "-o", o / "m.obj"],
        ("m.json", word)) for label, change, word in [
            ('"defs": 5', {"defs": 5}, "'defs'"),
            ('"dim": "three"', {"dim": "three"}, "'dim'"),
            ('"dim": 4', {"dim": 4}, "'dim'"),
            ('"params": 5', {"params": 5}, "'params'"),
            ('a parameter\'s "default": "x"', {"params": [{"name": "h", "default": "x", "lo": 0, "hi": 1}]},
             "'default'"),
            ('a parameter without "hi"', {"params": [{"name": "h", "default": 1, "lo": 0}]}, "'hi'"),
            ('a parameter\'s "kind": "complex"', {"params": [{"name": "h", "default": 1, "lo": 0, "hi": 2,
                                                              "kind": "complex"}]}, "'kind'"),
            ('"name": 7', {"name": 7}, "'name'"),
            ('"exact": "yes"', {"exact": "yes"}, "'exact'"),
            ('"doc": []', {"doc": []}, "'doc'"),
            ('"tree": []', {"tree": []}, "'tree'"),
            ("an unknown key", {"colour": "red"}, "'colour'"),
            ('no "tree"', {"tree": None}, "'tree'"),
            ("a node's params as a list", {"tree": {"node": "sphere", "params": [1]}}, "'params'"),
            ('a slot "x"', {"tree": {"node": "translate", "children": [{"slot": "x"}]}}, "slot"),
            ("a slot of dim 5", {"tree": {"node": "translate", "children": [{"slot": 0, "dim": 5}]}}, "'dim'"),
        ]},
    # 5. a plain .npy as weights
    "subdivide: a .npy array as neural weights": (
        lambda i, o: ["subdivide", real_path(MUG), "--method", "neural", "--weights",
                      (np.save(i / "W.npy", np.zeros((3, 4))), i / "W.npy")[1], "-o", o / "x.obj"],
        ("W.npy", "single array", "train-subdivision")),
    "subdivide: a text file as neural weights": (
        lambda i, o: ["subdivide", real_path(MUG), "--method", "neural", "--weights", write_file(i / "w.npz", "hello"),
                      "-o", o / "x.obj"], ("w.npz", "plain arrays")),
    "subdivide: weights declaring 75 GB": (
        lambda i, o: ["subdivide", real_path(MUG), "--method", "neural", "--weights", _big_npz(i / "w.npz"),
                      "-o", o / "x.obj"], ("w.npz", "the limit")),
    # 6. a non-manifold training mesh
    "train-subdivision: a non-manifold --real mesh": (
        lambda i, o: ["train-subdivision", "--real", _fin(i / "fin.ply"), "--no-procedural", "--steps", "2",
                      "-o", o / "w.npz"], ("fin.ply", "non-manifold")),
    "train-subdivision: a garbage --real stl": (
        lambda i, o: ["train-subdivision", "--real", write_file(i / "g.stl", b"solid \x00\xff\xfe garbage\x01" * 20),
                      "--no-procedural", "--steps", "2", "-o", o / "w.npz"], ("g.stl", ".ply, .obj")),
    # 7. booleans, camera keys, an unreadable STL
    "generate: true for a float parameter in a params file": (
        lambda i, o: ["generate", "dishes", "--params", write_file(i / "p.json", {"params": {"height": True}}),
                      "-o", o / "m.obj"], ("'height'", "true")),
    "generate: true for a float parameter in a tree file": (
        lambda i, o: ["generate", write_file(i / "t.json", {"tree": {"node": "sphere", "params": {"radius": True}}}),
                      "-o", o / "m.obj"], ("t.json", "'radius'", "true")),
    "generate: false for an integer parameter in a flat tree file": (
        lambda i, o: ["generate", write_file(i / "t.json", {"structure": ["mirror", "sphere"], "params": [False, 0.0, 0.5]}),
                      "-o", o / "m.obj"], ("t.json", "'axis'", "false")),
    "generate: true for a float parameter in a mesh tree file": (
        lambda i, o: ["generate", write_file(i / "t.json", {"generator": "meshtree", "tree": {
            "node": "box", "params": {"size_x": True}}}), "-o", o / "m.obj"], ("'size_x'", "true")),
    "render: an unknown key in cameras.json": (
        lambda i, o: ["render", "dishes", "--cameras", write_file(i / "c.json", [{**_camera(), "colour": 1}]), "-o", o],
        ("c.json", "'colour'", "allowed: eye, target, up, fov_deg, width, height, cx, cy")),
    "render: an unknown key beside cameras": (
        lambda i, o: ["render", "dishes", "--cameras", write_file(i / "c.json", {"cameras": [_camera()], "fov": 3}),
                      "-o", o], ("c.json", "'fov'")),
    "render: garbage stl": (
        lambda i, o: ["render", write_file(i / "g.stl", b"solid \x00\xff\xfe garbage\x01" * 20), "-o", o],
        ("g.stl", ".ply, .obj, .stl, .glb, .gltf, .off")),
    "subdivide: garbage stl": (
        lambda i, o: ["subdivide", write_file(i / "g.stl", b"solid \x00\xff\xfe garbage\x01" * 20), "-o", o / "x.obj"],
        ("g.stl", ".ply, .obj, .stl")),
}


def _files(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in folder.rglob("*") if p.is_file()} \
        if folder.exists() else {}


def _macro_list_case(i: Path, o: Path) -> list:
    write_file(i / "lib" / "m.json", [1, 2])
    return ["generate", "chair", "--library", i / "lib", "-o", o / "m.obj"]


CASES["generate: macro file with a JSON list"] = (_macro_list_case, ("m.json", "expected a JSON object"))


@pytest.mark.parametrize("case", sorted(CASES))
def test_hostile_content_exits_2_with_one_line_and_leaves_nothing(case, tmp_path, capsys):
    make, words = CASES[case]
    i, o = tmp_path / "in", tmp_path / "out"
    i.mkdir()
    args = make(i, o)
    inputs = _files(i)
    line = refusal(case, *run(args, capsys))
    for word in words:
        assert word.lower() in line.lower(), f"{case}: {line!r} does not name {word!r}"
    assert "charset_normalizer" not in line
    assert not _files(o) and not o.exists(), f"{case}: left behind {sorted(_files(o))}"
    assert _files(i) == inputs, f"{case}: changed its inputs"


# -- what is accepted at the limits ------------------------------------------------------------------

def test_a_macro_chain_at_the_depth_limit_works_and_a_refused_library_registers_nothing(tmp_path):
    import torch

    from ipm.errors import InputError
    from ipm.sdf.complex import load_library
    from ipm.sdf.node import NODES
    from ipm.sdf.tree import load_tree
    from ipm.tree import MAX_DEPTH

    # 63 macros and the tree's own level: 64 levels with the macros expanded, the limit
    tree_file = _chain(tmp_path / "ok", MAX_DEPTH - 1, prefix="okchain")
    added = load_library([tmp_path / "ok" / "lib"])
    try:
        assert len(added) == MAX_DEPTH - 1 and NODES.get("okchain0").levels == MAX_DEPTH
        tree = load_tree(tree_file)
        d = tree.sdf(None, torch.zeros(1, 3, dtype=torch.float64))
        assert float(d) == pytest.approx(-0.5)
        lo, hi = tree.bounds()
        assert hi[0] == pytest.approx(0.5, abs=0.05)
        deeper = write_file(tmp_path / "deeper.json", {"tree": {"node": "translate", "children": [{"node": "okchain0"}]}})
        with pytest.raises(InputError, match=rf"deeper.json: expected a tree at most {MAX_DEPTH} levels deep .*"
                                             rf"got {MAX_DEPTH + 1} levels \(through the macro okchain0"):
            load_tree(deeper)
    finally:
        for name in added:
            NODES.remove(name)
    # one level more: refused, and none of the 64 files stays registered
    _chain(tmp_path / "bad", MAX_DEPTH, prefix="badchain")
    with pytest.raises(InputError, match=rf"badchain0000.json: expected a macro at most {MAX_DEPTH} levels deep"):
        load_library([tmp_path / "bad" / "lib"])
    assert not any(n.startswith("badchain") for n in NODES.names())


def test_macro_files_load_in_the_order_of_their_use(tmp_path):
    """A file may use a macro defined by a file after it (alphabetically): built after it, in one pass."""
    from ipm.sdf.complex import load_library
    from ipm.sdf.node import NODES

    write_file(tmp_path / "a.json", {"name": "ord_top", "params": [], "tree": {"node": "ord_mid"}})
    write_file(tmp_path / "b.json", {"name": "ord_mid", "params": [], "tree": {"node": "ord_leaf"}})
    write_file(tmp_path / "c.json", {"name": "ord_leaf", "params": [], "tree": {"node": "sphere"}})
    added = load_library([tmp_path])
    try:
        assert added == ["ord_leaf", "ord_mid", "ord_top"]
        assert [NODES.get(n).levels for n in added] == [2, 3, 4]
        assert load_library([tmp_path]) == []  # the same files again: already registered as they are
    finally:
        for name in added:
            NODES.remove(name)


def test_the_largest_seed_is_accepted(tmp_path, capsys):
    code, _, err = run(["generate", "dishes", "--random", "--seed", "2147483647", "-o", tmp_path / "m.obj"], capsys)
    assert code == 0, err


def test_numbers_in_json_beyond_a_double_are_refused_naming_the_key(tmp_path):
    from ipm.errors import InputError
    from ipm.files import read_json

    assert read_json(write_file(tmp_path / "ok.json", '{"a": 1.7e308, "b": -12345678901234567890, "c": [1e-400]}')) \
        == {"a": 1.7e308, "b": -12345678901234567890, "c": [0.0]}
    with pytest.raises(InputError, match=r"x.json: key 'a': expected a number of magnitude at most 1.8e308 .*"
                                         r"got -1e400$"):
        read_json(write_file(tmp_path / "x.json", '{"b": 1, "a": -1e400}'))
    with pytest.raises(InputError, match=r"y.json: expected a number .* got 1e999$"):
        read_json(write_file(tmp_path / "y.json", "[1, 1e999]"))


def test_booleans_are_numbers_only_for_switches():
    from ipm.errors import InputError
    from ipm.params import Param

    switch = Param("handle", 1, 0, 1, "bool")
    assert switch.check(True) == 1 and switch.check(False) == 0 and switch.check(0) == 0
    for kind in ("float", "int"):
        with pytest.raises(InputError, match=rf"parameter 'n' is {kind}: expected a number, got true"):
            Param("n", 1, 0, 5, kind).check(True)
    with pytest.raises(InputError, match="expected a value in"):
        Param("n", 1, 0, 5, "int").check(10 ** 400)


def test_shipped_experiments_nest_well_within_the_limit():
    import tomllib

    from conftest import ROOT

    from ipm.bench.config import MAX_NESTING, _data_depth, toml_nesting

    for path in sorted((ROOT / "experiments").glob("*.toml")):
        text = path.read_text()
        assert toml_nesting(text) <= 4 and _data_depth(tomllib.loads(text)) <= 6 < MAX_NESTING, path
    # brackets in strings and comments do not count
    assert toml_nesting('a = "[[[[" # {{{{\nb = \'[[\'\nc = """\n[[[\n"""\nd = [[1], {e = 2}]\n') == 2


# -- enumerate with ranges for some discrete parameters ------------------------------------------------

def test_enumerate_with_ranges_searches_those_and_holds_the_rest(tmp_path, capsys):
    """``--discrete enumerate --range floors=4:10 --range windows=2:6`` on the building (16 discrete
    parameters): the two ranged ones are searched (35 combinations), the other 14 stay at the start's
    values, and one info line says so; without ``--range`` the 64-combination limit still refuses it."""
    masks = tmp_path / "masks"
    assert run(["render", "building", "--views", "1", "--size", "40", "--no-previews", "-o", masks, "-q"],
               capsys)[0] == 0
    run_dir = tmp_path / "run"
    code, _, err = run(["fit", "building", "--masks", masks, "--discrete", "enumerate", "--range", "floors=4:10",
                        "--range", "windows=2:6", "--budget", "12", "-o", run_dir], capsys)
    assert code == 0, err
    said = [line for line in err.splitlines() if "enumerate searches" in line]
    assert len(said) == 1, err
    assert "given ranges (floors, windows); the other 14 stay at the start's values" in said[0]
    from ipm.generators import get_generator

    start = get_generator("building").values(None, {})
    params = json.loads((run_dir / "result.json").read_text())["params"]
    held = [p.name for p in get_generator("building").spec.discrete if p.name not in ("floors", "windows")]
    assert len(held) == 14 and all(params[n] == start[n] for n in held)
    assert 4 <= params["floors"] <= 10 and 2 <= params["windows"] <= 6
    # a range and a fix: the fixed one is not "held" in the line, the rest are
    code, _, err = run(["fit", "building", "--masks", masks, "--discrete", "enumerate", "--range", "floors=4:5",
                        "--fix", "wings=1", "--budget", "6", "-o", tmp_path / "run2"], capsys)
    assert code == 0, err
    said = [line for line in err.splitlines() if "enumerate searches" in line]
    assert len(said) == 1 and "the other 14 stay" in said[0] and "wings=" not in said[0], err
    # no --range: as before, every discrete parameter is enumerated, and that is too many
    code, _, err = run(["fit", "building", "--masks", masks, "--discrete", "enumerate", "-o", tmp_path / "r3"],
                       capsys)
    assert code == 2 and "at most 64 combinations" in err and not (tmp_path / "r3").exists()


def test_intrinsics_yaml_nested_too_deep_is_refused(tmp_path):
    """PyYAML recurses into flow lists: 50,000 of them are one line naming the file, not a RecursionError."""
    from ipm.errors import InputError
    from ipm.render.camera import load_intrinsics

    with pytest.raises(InputError, match=r"deep.yaml: expected a flat mapping of intrinsics, got YAML nested too deep"):
        load_intrinsics(write_file(tmp_path / "deep.yaml", _nested_text(50000, "[", "]")))
