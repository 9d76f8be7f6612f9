"""Issue #32, "no input breaks it", property-based: every kind of file the CLI reads, damaged at random
(truncated, random bytes, bytes flipped, values of the wrong type, nesting thousands deep, well-formed files
of the wrong shape), is fed to the command that reads it. The command must exit 2 with exactly one line
``ipm: error: ...`` and leave its output absent and its inputs unchanged, or, when the damage happened to
leave a valid file, exit 0. It must never exit 1 (an internal error) or write half an output.

Hypothesis runs a few dozen examples per kind, derandomized (the same examples on every run, so CI is
stable) with no deadline. Each example copies a set of valid inputs (built once per module) into a fresh
folder and damages one file. Commands run in-process with stdout and stderr captured.

A kind whose reader is known to break may be marked ``xfail(strict=False)`` with the file named (``XFAIL``;
empty today).
"""

from __future__ import annotations

import contextlib
import io
import json
import re
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

EXAMPLES = 30
# no shrinking: a failing kind reports its first failing example at once (shrinking one took minutes)
PROPERTY = settings(max_examples=EXAMPLES, deadline=None, derandomize=True, database=None,
                    phases=[Phase.explicit, Phase.generate], report_multiple_bugs=False,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture,
                                           HealthCheck.data_too_large])


def _cli(args) -> tuple[int, str, str]:
    """``ipm ARGS`` in this process: (exit code, stdout, stderr). Macro nodes a run registers (``--library``)
    are forgotten afterwards, as a new process would: each example stands alone."""
    from ipm.cli import main
    from ipm.sdf.node import NODES

    known = set(NODES.names())
    out, err = io.StringIO(), io.StringIO()
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                main([str(a) for a in args])
            except SystemExit as e:
                code = e.code
            else:
                code = 0
    finally:
        for name in set(NODES.names()) - known:
            NODES.remove(name)
    return code, out.getvalue(), err.getvalue()


# -- the valid inputs every example starts from ---------------------------------------------------------------
EXPERIMENT = """name = "e"
budget = 2
size = 64
heldout_size = 64
samples = 200
views = [1]

[[targets]]
name = "s"
generator = "dishes"
preset = "mug"

[[methods]]
name = "vh"
method = "visual-hull"
resolution = 16
"""

MACRO = {"name": "bump", "doc": "A ball.", "params": [{"name": "r", "default": 0.3, "lo": 0.05, "hi": 1.0}],
         "tree": {"node": "sphere", "params": {"radius": "r"}}}
TREE = {"tree": {"node": "union", "children": [
    {"node": "translate", "params": {"x": 0.2}, "children": [{"node": "sphere", "params": {"radius": 0.4}}]},
    {"node": "box", "params": {"size_x": 0.5, "size_y": 0.3, "size_z": 0.4}}]}}
TREE_WITH_MACRO = {"tree": {"node": "union", "children": [{"node": "bump", "params": {"r": 0.4}},
                                                         {"node": "box", "params": {"size_x": 0.5}}]}}


def _build(folder: Path) -> Path:
    """Valid inputs of every kind in ``folder``."""
    import trimesh
    from PIL import Image

    folder.mkdir(parents=True, exist_ok=True)
    box = trimesh.creation.box((1.0, 0.8, 0.6))
    for suffix in (".obj", ".ply", ".stl"):
        box.export(folder / f"mesh{suffix}")
    photo = np.full((48, 64, 3), 90, np.uint8)
    photo[12:36, 16:40] = (220, 30, 30)
    Image.fromarray(photo).save(folder / "photo.png")
    Image.fromarray(photo).save(folder / "photo.jpg", quality=90)
    mask = np.zeros((48, 64), np.uint8)
    mask[12:36, 16:40] = 255
    Image.fromarray(mask).save(folder / "mask.png")
    depth = np.full((48, 64), 800, np.uint16)
    depth[12:36, 16:40] = 700
    Image.fromarray(depth).save(folder / "depth.png")
    np.save(folder / "depth.npy", depth.astype(np.float32) / 1000)
    (folder / "K.yaml").write_text("# camera\nfx: 60.0\nfy: 60.0\ncx: 32.0\ncy: 24.0\nxres: 64\nyres: 48\n")
    (folder / "K.json").write_text(json.dumps({"fx": 60.0, "fy": 60.0, "cx": 32.0, "cy": 24.0, "width": 64,
                                               "height": 48}))
    (folder / "tree.json").write_text(json.dumps(TREE))
    (folder / "lib").mkdir()
    (folder / "lib" / "bump.json").write_text(json.dumps(MACRO))
    (folder / "macro_tree.json").write_text(json.dumps(TREE_WITH_MACRO))
    (folder / "experiments").mkdir()
    (folder / "experiments" / "e.toml").write_text(EXPERIMENT)
    np.save(folder / "points.npy", np.random.default_rng(0).uniform(-1, 1, (16, 3)))
    for args in (["generate", "dishes", "--preset", "mug", "-o", folder / "g.obj"],
                 ["render", "dishes", "--preset", "mug", "--views", "1", "--size", "32", "--no-previews",
                  "-o", folder / "ms"],
                 ["fit", "dishes", "--masks", folder / "ms", "--budget", "4", "--discrete", "none",
                  "-o", folder / "run"]):
        code, _, err = _cli(args)
        assert code == 0, err
    (folder / "p.json").write_text((folder / "g.params.json").read_text())
    return folder


@pytest.fixture(scope="module")
def base(tmp_path_factory) -> Path:
    return _build(tmp_path_factory.mktemp("valid") / "in")


# -- damage ---------------------------------------------------------------------------------------------------
WEIRD_JSON = [None, True, False, -1, 0, 1, 3.5, -1e308, 1e308, 10**30, float("nan"), float("inf"), "", "x",
              "1e999", [], {}, [1, 2, 3], [[[]]], {"a": {"b": None}}, ["x", None]]
WEIRD_TOKENS = ["nan", "inf", "-inf", "1e999", "-1", "0", "99999999999999999999", "x", "", "1.5e-320", "-0"]
WEIRD_TOML = ['"x"', "[]", "{}", "-1", "0", "inf", "nan", "-inf", "true", '""', "99999999999999999999", "1e999",
              "[[1], [2]]", '{ a = 1 }', "1979-05-27"]
WEIRD_YAML = ["x", "[]", "{}", "-1", "0", ".inf", ".nan", "-.inf", "null", "~", "1e999", "[1, [2]]", "true",
              "!!python/object/apply:os.getcwd []", "&a [*a]", "'60'", "0x3c", "60.0.0", "{fx: 1}"]


def _truncate(data: bytes):
    return st.integers(0, max(0, len(data) - 1)).map(lambda k: data[:k])


def _flip(data: bytes):
    def apply(edits):
        b = bytearray(data)
        for pos, value in edits:
            b[pos % len(b)] = value
        return bytes(b)
    return st.lists(st.tuples(st.integers(0, 1 << 20), st.integers(0, 255)), min_size=1, max_size=12).map(apply)


def _splice(data: bytes):
    """Random bytes put in at a random place."""
    return st.tuples(st.integers(0, len(data)), st.binary(min_size=1, max_size=64)).map(
        lambda t: data[:t[0]] + t[1] + data[t[0]:])


def _bytes_damage(data: bytes):
    return st.one_of(_truncate(data), st.binary(max_size=300), _flip(data), _splice(data))


def _json_paths(doc, prefix=()):
    yield prefix
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from _json_paths(v, (*prefix, k))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            yield from _json_paths(v, (*prefix, i))


def _json_set(doc, path, value):
    if not path:
        return value
    doc = json.loads(json.dumps(doc))
    node = doc
    for k in path[:-1]:
        node = node[k]
    node[path[-1]] = value
    return doc


def _json_drop(doc, path):
    if not path:
        return None
    doc = json.loads(json.dumps(doc))
    node = doc
    for k in path[:-1]:
        node = node[k]
    del node[path[-1]]
    return doc


def _deep(n: int, inner: str = "1") -> str:
    return "[" * n + inner + "]" * n


def _json_damage(data: bytes):
    doc = json.loads(data)
    paths = list(_json_paths(doc))
    wrong_type = st.tuples(st.sampled_from(paths), st.sampled_from(WEIRD_JSON)).map(
        lambda t: json.dumps(_json_set(doc, *t)).encode())
    dropped = st.sampled_from(paths).map(lambda p: json.dumps(_json_drop(doc, p)).encode())
    deep_value = st.tuples(st.sampled_from(paths[1:] or paths), st.integers(300, 50000)).map(
        lambda t: json.dumps(_json_set(doc, t[0], "@DEEP@")).replace('"@DEEP@"', _deep(t[1])).encode())
    deep_whole = st.integers(300, 200000).map(lambda n: _deep(n).encode())
    return st.one_of(_bytes_damage(data), wrong_type, wrong_type, dropped, deep_value, deep_whole)


def _jsonl_damage(data: bytes):
    lines = data.decode().splitlines()
    docs = [json.loads(x) for x in lines]

    def one_line(t):
        i, value = t
        out = list(lines)
        out[i % len(out)] = value
        return ("\n".join(out) + "\n").encode()

    def wrong_type(t):
        i, (path_pick, value) = t
        d = docs[i % len(docs)]
        paths = list(_json_paths(d))
        return one_line((i, json.dumps(_json_set(d, paths[path_pick % len(paths)], value))))

    return st.one_of(
        _bytes_damage(data),
        st.tuples(st.integers(0, 1 << 10), st.tuples(st.integers(0, 1 << 10), st.sampled_from(WEIRD_JSON))).map(
            wrong_type),
        st.tuples(st.integers(0, 1 << 10), st.sampled_from(["", "{", "[]", "null", "1", '"x"', _deep(5000)])).map(
            one_line),
        st.permutations(lines).map(lambda ls: ("\n".join(ls) + "\n").encode()))


def _line_value_damage(data: bytes, pattern: str, weird: list[str]):
    """Replace the value of a ``key = value`` / ``key: value`` line, or drop or double a line."""
    lines = data.decode().splitlines()
    rx = re.compile(pattern)
    valued = [i for i, x in enumerate(lines) if rx.match(x)] or [0]

    def replace(t):
        i, value = t
        out = list(lines)
        m = rx.match(out[i])
        if m:
            out[i] = m.group(1) + value
        return ("\n".join(out) + "\n").encode()

    def drop(i):
        return ("\n".join(lines[:i] + lines[i + 1:]) + "\n").encode()

    def double(i):
        return ("\n".join(lines[:i + 1] + lines[i:]) + "\n").encode()

    return st.one_of(_bytes_damage(data), st.tuples(st.sampled_from(valued), st.sampled_from(weird)).map(replace),
                     st.tuples(st.sampled_from(valued), st.sampled_from(weird)).map(replace),
                     st.sampled_from(valued).map(drop), st.sampled_from(valued).map(double))


def _toml_damage(data: bytes):
    return _line_value_damage(data, r"^(\s*[A-Za-z_]+\s*=\s*).*$", WEIRD_TOML)


def _yaml_damage(data: bytes):
    deep = [_deep(n) for n in (100, 1000, 3000)]
    return _line_value_damage(data, r"^(\s*[A-Za-z_]+\s*:\s*).*$", WEIRD_YAML + deep)


def _obj_damage(data: bytes):
    text = data.decode()
    numbers = [m.span() for m in re.finditer(r"-?\d+(?:\.\d+)?(?:e-?\d+)?", text)]

    def token(t):
        i, value = t
        a, b = numbers[i % len(numbers)]
        return (text[:a] + value + text[b:]).encode()

    extra = st.sampled_from(["f 1 2 99999\n", "f 0 1 2\n", "f -9 1 2\n", "v 1 2\n", "f 1 1 1\n", "f 1 2\n",
                             "v nan 0 0\n", "v 1e999 0 0\n", "f 1/2/3 x y\n", "mtllib /etc/passwd\n"]).map(
        lambda line: (text + line).encode())
    return st.one_of(_bytes_damage(data), st.tuples(st.integers(0, 1 << 16), st.sampled_from(WEIRD_TOKENS)).map(token),
                     extra)


def _stl_damage(data: bytes):
    """A binary STL: bytes damaged, or one vertex coordinate set to NaN, inf or 1e38 (84-byte header and
    count, then 50 bytes a triangle: normal, three vertices, attribute)."""
    import struct

    n = (len(data) - 84) // 50

    def coordinate(t):
        tri, k, value = t
        at = 84 + 50 * (tri % n) + 12 + 4 * (k % 9)
        return data[:at] + struct.pack("<f", value) + data[at + 4:]

    return st.one_of(_bytes_damage(data), st.tuples(st.integers(0, 1 << 10), st.integers(0, 8), st.sampled_from(
        [float("nan"), float("inf"), -float("inf"), 1e38])).map(coordinate))


def _npy(arr) -> bytes:
    buf = io.BytesIO()
    np.save(buf, arr, allow_pickle=True)
    return buf.getvalue()


def _npy_damage(data: bytes):
    arrays = [np.zeros(4), np.zeros((4, 2)), np.zeros((0, 3)), np.zeros((2, 2, 2)), np.full((4, 3), np.nan),
              np.full((4, 3), np.inf), np.full((48, 64), np.nan), np.full((48, 64), -1.0), np.zeros((48, 64)),
              np.array(["a", "b"]), np.array([1 + 2j, 3j]), np.ones((4, 3), bool), np.full((4, 3), 1e300),
              np.array([{"a": 1}], dtype=object), np.zeros((1, 1)), np.zeros((2, 3), np.uint64) + 2**63,
              np.zeros((4, 3), [("x", "f8")])]
    return st.one_of(_bytes_damage(data), st.sampled_from(arrays).map(_npy))


def _png(arr) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(arr).save(buf, format="PNG")
    return buf.getvalue()


def _image_damage(data: bytes):
    images = [np.zeros((1, 1), np.uint8), np.zeros((48, 64), np.uint8), np.full((48, 64), 255, np.uint8),
              np.zeros((48, 64, 4), np.uint8), np.zeros((47, 63, 3), np.uint8), np.zeros((48, 64), np.uint16),
              np.full((48, 64), 65535, np.uint16), np.zeros((64, 48, 3), np.uint8), np.zeros((8, 4096), np.uint8),
              np.zeros((48, 64, 3), np.uint8)]
    return st.one_of(_bytes_damage(data), st.sampled_from(images).map(_png))


# -- the kinds ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Kind:
    file: str                 # the damaged file, relative to the input folder
    damage: object            # bytes -> strategy of damaged bytes
    args: object              # (input folder, output folder) -> arguments


PHOTO_FIT = ["--budget", "2", "--size", "32"]
KINDS = {
    "mesh .obj": Kind("mesh.obj", _obj_damage,
                      lambda i, o: ["render", i / "mesh.obj", "--views", "1", "--size", "16", "--no-previews",
                                    "--no-cues", "-o", o]),
    "mesh .ply": Kind("mesh.ply", _bytes_damage,
                      lambda i, o: ["render", i / "mesh.ply", "--views", "1", "--size", "16", "--no-previews",
                                    "--no-cues", "-o", o]),
    "mesh .stl": Kind("mesh.stl", _stl_damage,
                      lambda i, o: ["render", i / "mesh.stl", "--views", "1", "--size", "16", "--no-previews",
                                    "--no-cues", "-o", o]),
    "mask set: a mask": Kind("ms/view_000.png", _image_damage,
                             lambda i, o: ["render", "dishes", "--masks", i / "ms", "--no-previews", "--no-cues",
                                           "-o", o]),
    "mask set: cameras.json": Kind("ms/cameras.json", _json_damage,
                                   lambda i, o: ["render", "dishes", "--masks", i / "ms", "--no-previews",
                                                 "--no-cues", "-o", o]),
    "mask set: parts.json": Kind("ms/parts.json", _json_damage,
                                 lambda i, o: ["fit", "dishes", "--masks", i / "ms", "--parts", i / "ms", "--budget",
                                               "2", "--discrete", "none", "-o", o]),
    "parameter JSON": Kind("p.json", _json_damage,
                           lambda i, o: ["generate", "dishes", "--params", i / "p.json", "-o", o / "m.obj"]),
    "SDF tree JSON": Kind("tree.json", _json_damage,
                          lambda i, o: ["generate", i / "tree.json", "--resolution", "16", "-o", o / "m.obj"]),
    "macro library": Kind("lib/bump.json", _json_damage,
                          lambda i, o: ["generate", i / "macro_tree.json", "--library", i / "lib", "--resolution",
                                        "16", "-o", o / "m.obj"]),
    "experiment TOML": Kind("experiments/e.toml", _toml_damage,
                            lambda i, o: ["bench", i / "experiments" / "e.toml", "--dry-run", "-o", o]),
    "intrinsics YAML": Kind("K.yaml", _yaml_damage,
                            lambda i, o: ["fit", "dishes", "--image", i / "photo.png", "--mask", i / "mask.png",
                                          "--depth", i / "depth.png", "--intrinsics", i / "K.yaml", *PHOTO_FIT,
                                          "-o", o]),
    "intrinsics JSON": Kind("K.json", _json_damage,
                            lambda i, o: ["fit", "dishes", "--image", i / "photo.png", "--mask", i / "mask.png",
                                          "--intrinsics", i / "K.json", *PHOTO_FIT, "-o", o]),
    "depth PNG": Kind("depth.png", _image_damage,
                      lambda i, o: ["fit", "dishes", "--image", i / "photo.png", "--mask", i / "mask.png",
                                    "--depth", i / "depth.png", "--intrinsics", i / "K.yaml", *PHOTO_FIT, "-o", o]),
    "depth .npy": Kind("depth.npy", _npy_damage,
                       lambda i, o: ["fit", "dishes", "--image", i / "photo.png", "--mask", i / "mask.png",
                                     "--depth", i / "depth.npy", "--intrinsics", i / "K.yaml", *PHOTO_FIT, "-o", o]),
    "depth .npy of a mask set": Kind("ms/depth_000.npy", _npy_damage,
                                     lambda i, o: ["fit", "dishes", "--masks", i / "ms", "--depth", i / "ms",
                                                   "--budget", "2", "--discrete", "none", "-o", o]),
    "photo PNG": Kind("photo.png", _image_damage,
                      lambda i, o: ["mask", i / "photo.png", "--box", "8,8,48,40", "-o", o / "m.png"]),
    "photo JPEG": Kind("photo.jpg", _bytes_damage,
                       lambda i, o: ["mask", i / "photo.jpg", "--box", "8,8,48,40", "-o", o / "m.png"]),
    "photo mask": Kind("mask.png", _image_damage,
                       lambda i, o: ["fit", "dishes", "--image", i / "photo.png", "--mask", i / "mask.png",
                                     *PHOTO_FIT, "-o", o]),
    "points .npy": Kind("points.npy", _npy_damage,
                        lambda i, o: ["jacobian", "chair", "--points", i / "points.npy", "-o", o / "j.npz"]),
    "run folder: settings.json": Kind("run/settings.json", _json_damage,
                                      lambda i, o: ["fit", "--resume", i / "run"]),
    "run folder: trajectory.jsonl": Kind("run/trajectory.jsonl", _jsonl_damage,
                                         lambda i, o: ["fit", "--resume", i / "run"]),
}

# kind -> the file outside issue #32's "sizes and outputs" part whose reader still fails some damaged inputs
# (re-enable once the fixes to that file are merged). On a trial merge with main at 2ed439b (i32-a and i32-b
# merged) cameras.json, intrinsics YAML and both run-folder kinds pass; the three mesh kinds still fail there.
XFAIL: dict[str, str] = {}  # every kind passes since the readers were fixed (issue #32)


def _files(folder: Path) -> dict[str, bytes | None]:
    return {str(p.relative_to(folder)): (None if p.is_dir() else p.read_bytes())
            for p in sorted(folder.rglob("*"))} if folder.exists() else {}


def _check(kind: str, base: Path, damaged: bytes) -> None:
    k = KINDS[kind]
    with tempfile.TemporaryDirectory(prefix="ipm-prop-") as tmp:
        i, o = Path(tmp) / "in", Path(tmp) / "out"
        shutil.copytree(base, i, symlinks=True)
        (i / k.file).write_bytes(damaged)
        before = _files(i)
        code, stdout, err = _cli(k.args(i, o))
        lines = err.strip().splitlines()
        assert code in (0, 2), f"{kind}: exit {code} for {damaged[:120]!r}...: {err[-600:]}"
        if code == 0:   # the damage left a valid file
            return
        errors = [x for x in lines if x.startswith("ipm: error: ")]
        assert len(errors) == 1 and errors[0] == lines[-1], f"{kind}: stderr {err[-600:]!r}"
        assert len(lines) == 1, f"{kind}: more than one line on stderr: {err[-600:]!r}"
        assert stdout == "", f"{kind}: stdout {stdout!r}"
        assert not o.exists(), f"{kind}: left behind {sorted(_files(o))}"
        assert _files(i) == before, f"{kind}: changed its inputs: {sorted(set(_files(i)) ^ set(before))}"


def _case(kind: str):
    marks = [pytest.mark.xfail(reason=XFAIL[kind], strict=False)] if kind in XFAIL else []
    return pytest.param(kind, marks=marks, id=kind)


@pytest.mark.parametrize("kind", [_case(k) for k in KINDS])
@PROPERTY
@given(data=st.data())
def test_a_damaged_file_gives_exit_2_and_one_line(kind, base, data):
    original = (base / KINDS[kind].file).read_bytes()
    damaged = data.draw(KINDS[kind].damage(original), label="damaged file")
    _check(kind, base, damaged)


def test_the_valid_inputs_pass(base):
    """The starting inputs are valid: every kind's command exits 0 on them (the damage is what fails)."""
    for kind, k in KINDS.items():
        with tempfile.TemporaryDirectory(prefix="ipm-prop-") as tmp:
            i, o = Path(tmp) / "in", Path(tmp) / "out"
            shutil.copytree(base, i, symlinks=True)
            code, _, err = _cli(k.args(i, o))
            assert code == 0, f"{kind}: {err}"
