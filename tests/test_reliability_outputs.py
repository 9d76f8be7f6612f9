"""Issue #32, sizes and outputs: bad sizes are refused before any work, and a command's outputs are written
all or nothing.

The table cases follow ``tests/test_cli_reliability.py``: inputs in ``tmp/in``, outputs into ``tmp/out``;
exit 2, exactly one line ``ipm: error: ...`` naming the thing, ``tmp/out`` absent afterwards and ``tmp/in``
unchanged (file names and bytes). Size cases also guard the work they must not start (a guarded function
that is called fails the test with exit 1 instead of allocating gigabytes).

A full disk is simulated by the ``full`` fixture: a folder in which files can be made, but every
temporary file that :mod:`ipm.files` makes under it is ``/dev/full``, so writing fails with ENOSPC at
write or flush time, as on a real full disk.
"""

from __future__ import annotations

import errno
import json
import os
import struct
import tempfile
import zlib
from pathlib import Path

import numpy as np
import pytest
from conftest import run_cli as run
from conftest import write_file


def _photo(folder: Path) -> Path:
    """A small photo (64 x 48): a red square (16..40, 12..36) on grey."""
    from PIL import Image

    path = folder / "photo.png"
    im = np.full((48, 64, 3), 90, np.uint8)
    im[12:36, 16:40] = (220, 30, 30)
    Image.fromarray(im).save(path)
    return path


def _drawing(folder: Path, n: int = 32) -> Path:
    from PIL import Image, ImageDraw

    im = Image.new("L", (n, n), 255)
    ImageDraw.Draw(im).line([(4, 4), (n - 4, n - 6)], fill=0, width=3)
    path = folder / "d.png"
    im.save(path)
    return path


def _png_header(path: Path, width: int, height: int) -> Path:
    """A PNG that declares ``width x height`` pixels but holds almost none (its header is all a size check
    may read; decoding it would fail or allocate gigabytes)."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return write_file(path, b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0" * 16))
                  + chunk(b"IEND", b""))


def _cameras(width: int, height: int, n: int = 1) -> list[dict]:
    from ipm.render.camera import cameras_to_json, orbit_camera

    return json.loads(cameras_to_json([orbit_camera(30.0 * i, 25.0, 3.2, fov_deg=40.0, width=width,
                                                    height=height) for i in range(n)]))


def _points(path: Path, value: float) -> Path:
    np.save(path, np.full((4, 3), value))
    return path


def _box_obj(folder: Path) -> Path:
    import trimesh

    path = folder / "box.obj"
    trimesh.creation.box((1.0, 1.0, 1.0)).export(path)
    return path


def _earlier_render(folder: Path) -> Path:
    """A folder holding what looks like an earlier render (any files do: render refuses a non-empty folder)."""
    folder.mkdir()
    write_file(folder / "view_000.png", b"old")
    write_file(folder / "cameras.json", "[]")
    return folder


# work that a refusal must come before: "module:function" or "module:Class.method"; a guarded function whose
# body runs fails the test (its code is swapped, so every binding of it is guarded, also ones made later)
RENDER_WORK = ["ipm.render.raster:rasterize"]
JACOBIAN_WORK = ["ipm.subdiv.linear:LinearScheme.operator", "ipm.jacobian:sdf_jacobian", "ipm.jacobian:mesh_jacobian"]
VECTORIZE_WORK = ["ipm.io.drawings:read_drawing"]

# case -> (arguments given the input folder i and output folder o, a word the message must contain, guarded work)
CASES = {
    # 1. sizes: totals, checked before any work, each limit named with its value
    "render: 256 views of 8192^2": (lambda i, o: ["render", "dishes", "--views", "256", "--size", "8192", "-o", o],
                                    "268,435,456", RENDER_WORK),
    "render: 5 views of 8192^2": (lambda i, o: ["render", "dishes", "--views", "5", "--size", "8192", "-o", o],
                                  "at most 4 views", RENDER_WORK),
    "render: cameras file totalling too many pixels": (
        lambda i, o: ["render", "dishes", "--cameras", write_file(i / "c.json", _cameras(8192, 8192, 5)), "-o", o],
        "268,435,456", RENDER_WORK),
    "jacobian: loop subdivision 6 levels": (
        lambda i, o: ["jacobian", "dishes", "--subdivide", "loop", "--levels", "6", "-o", o / "j.npz"],
        "268,435,456", JACOBIAN_WORK),
    "jacobian: midpoint subdivision 5 levels": (
        lambda i, o: ["jacobian", "dishes", "--subdivide", "midpoint", "--levels", "5", "-o", o / "j.npz"],
        "--levels", JACOBIAN_WORK),
    "jacobian: SDF points beyond the entries limit": (
        lambda i, o: ["jacobian", "chair", "--n-points", "100000000", "-o", o / "j.npz"], "268,435,456",
        JACOBIAN_WORK),
    "vectorize: a 6000^2 drawing": (lambda i, o: ["vectorize", _png_header(i / "big.png", 6000, 6000),
                                                  "-o", o / "d.svg"], "4,194,304", VECTORIZE_WORK),
    "vectorize: a header declaring 10^5 x 10^5": (
        lambda i, o: ["vectorize", _png_header(i / "bomb.png", 100000, 100000), "-o", o / "d.svg"], "bomb.png",
        VECTORIZE_WORK),
    # 3. two outputs that are one file; quiet wrong results
    "mask: overlay is the output": (lambda i, o: ["mask", _photo(i), "--box", "8,8,40,40", "--overlay", o / "m.png",
                                                  "-o", o / "m.png"], "--overlay", []),
    "mask: overlay is the output by another spelling": (
        lambda i, o: ["mask", _photo(i), "--box", "8,8,40,40", "--overlay", o / "x" / ".." / "m.png",
                      "-o", o / "m.png"], "expected different files", []),
    "convert: result is the mesh's parameter file": (
        lambda i, o: ["convert", _box_obj(i), "--to", "bsp", "--mesh", o / "c.obj", "-o", o / "c.params.json"],
        "parameter file", ["ipm.convert:get_converter"]),
    "vectorize: JSON file is the preview's": (
        lambda i, o: ["vectorize", _drawing(i), "-o", o / "d.svg", "--json-file", o / "d.json", "--preview",
                      o / "d.json"], "suffix", VECTORIZE_WORK),
    "jacobian: float32 points of 1e20": (
        lambda i, o: ["jacobian", "chair", "--points", _points(i / "p.npy", 1e20), "--dtype", "float32",
                      "-o", o / "j.npz"], "p.npy", ["ipm.jacobian:sdf_jacobian"]),
    "jacobian: float64 points of 1e200": (
        lambda i, o: ["jacobian", "chair", "--points", _points(i / "p.npy", 1e200), "-o", o / "j.npz"], "float64",
        ["ipm.jacobian:sdf_jacobian"]),
    # 4. overflow in the box
    "mask: infinite box": (lambda i, o: ["mask", _photo(i), "--box", "inf,10,50,50", "-o", o / "m.png"], "--box", []),
    "mask: box beyond float range": (lambda i, o: ["mask", _photo(i), "--box", "1e400,10,50,50", "-o", o / "m.png"],
                                     "--box", []),
    "mask: NaN box": (lambda i, o: ["mask", _photo(i), "--box", "nan,10,50,50", "-o", o / "m.png"], "--box", []),
    "mask: fractional box": (lambda i, o: ["mask", _photo(i), "--box", "8.5,8,40,40", "-o", o / "m.png"],
                             "whole", []),
    "fit: infinite box": (lambda i, o: ["fit", "dishes", "--image", _photo(i), "--box", "-inf,8,40,40", "-o", o],
                          "--box", []),
    # 5. minor
    "generate: negative resolution": (lambda i, o: ["generate", "dishes", "--resolution", "-3", "-o", o / "g.obj"],
                                      "8..2048", ["ipm.generators.dishes:DishesGenerator.to_mesh"]),
    "generate: resolution 0 for an SDF tree": (lambda i, o: ["generate", "chair", "--resolution", "0",
                                                             "-o", o / "g.obj"], "8..2048", []),
    "jacobian: --points for a mesh generator": (
        lambda i, o: ["jacobian", "dishes", "--points", _points(i / "p.npy", 0.1), "-o", o / "j.npz"], "--points",
        []),
    "jacobian: --n-points for a mesh generator": (
        lambda i, o: ["jacobian", "dishes", "--n-points", "50", "-o", o / "j.npz"], "--n-points", []),
    # 2. render into a folder holding an earlier render
    "render: non-empty folder without --overwrite": (
        lambda i, o: ["render", "dishes", "--views", "1", "--size", "32", "-o", _earlier_render(i / "r")],
        "--overwrite", RENDER_WORK),
    "render: --overwrite the --masks folder itself": (
        lambda i, o: ["render", "dishes", "--masks", _earlier_render(i / "r"), "--overwrite", "-o", i / "r"],
        "--masks", RENDER_WORK),
}


def _files(folder: Path) -> dict[str, bytes | None]:
    """Every path under ``folder`` with its bytes (None for folders)."""
    if not folder.exists():
        return {}
    return {str(p.relative_to(folder)): (None if p.is_dir() else p.read_bytes()) for p in folder.rglob("*")}


def _forbidden_code(n_free: int):
    """The code of a function that fails when called, with ``n_free`` free variables (a function's code can
    only be swapped for one with as many as its closure has)."""
    names = [f"_cell{k}" for k in range(n_free)]
    src = ("def outer():\n" + "".join(f"    {v} = None\n" for v in names)
           + "    def forbidden(*args, **kwargs):\n" + (f"        {', '.join(names)}\n" if names else "")
           + "        raise AssertionError('guarded work was started: the refusal must come before it')\n"
           + "    return forbidden\n")
    scope: dict = {}
    exec(src, scope)
    return scope["outer"]().__code__


def _guard(monkeypatch, work) -> None:
    import importlib

    for spec in work:
        module, name = spec.split(":")
        fn = importlib.import_module(module)
        for part in name.split("."):
            fn = getattr(fn, part)
        monkeypatch.setattr(fn, "__code__", _forbidden_code(len(fn.__code__.co_freevars)))


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_sizes_and_outputs_exit_2_with_one_line_and_leave_nothing(case, tmp_path, capsys, monkeypatch):
    make, word, work = CASES[case]
    i, o = tmp_path / "in", tmp_path / "out"
    i.mkdir()
    args = make(i, o)
    inputs = _files(i)
    _guard(monkeypatch, work)
    code, stdout, err = run(args, capsys)
    lines = err.strip().splitlines()
    assert code == 2, f"{case}: exit {code}, stderr: {err}"
    assert len(lines) == 1 and lines[0].startswith("ipm: error: "), f"{case}: stderr: {err!r}"
    assert word.lower() in lines[0].lower(), f"{case}: {lines[0]!r} does not name {word!r}"
    assert stdout == ""
    assert not o.exists(), f"{case}: left behind {sorted(_files(o))}"
    assert _files(i) == inputs, f"{case}: changed {sorted(set(_files(i)) ^ set(inputs))}"


def test_the_limits_are_in_the_help_texts(capsys):
    from ipm.cli import jacobian as cli_jacobian
    from ipm.cli import render as cli_render
    from ipm.cli import vectorize as cli_vectorize
    from ipm.jacobian import MAX_ENTRIES

    assert cli_jacobian.MAX_ENTRIES == MAX_ENTRIES
    for command, numbers in (("render", [cli_render.MAX_PIXELS, cli_render.MAX_SIDE]),
                             ("jacobian", [MAX_ENTRIES]), ("vectorize", [cli_vectorize.MAX_PIXELS]),
                             ("generate", [cli_render.MAX_RESOLUTION])):
        code, out, _ = run([command, "--help"], capsys)
        flat = " ".join(out.split())
        assert code == 0
        for n in numbers:
            assert f"{n:,}" in flat or str(n) in flat, f"ipm {command} --help does not say {n}"
    code, out, _ = run(["render", "--help"], capsys)
    assert "--overwrite" in out


# -- a full disk -------------------------------------------------------------------------------------------
@pytest.fixture
def full(tmp_path, monkeypatch) -> Path:
    """A folder on a "full disk": the temporary files ipm.files makes under it are symlinks to /dev/full."""
    if not os.path.exists("/dev/full"):
        pytest.skip("no /dev/full here")
    folder = (tmp_path / "full")
    folder.mkdir()
    real = tempfile.mkstemp

    def mkstemp(suffix=None, prefix=None, dir=None, text=False):
        fd, name = real(suffix=suffix, prefix=prefix, dir=dir, text=text)
        where = Path(dir or tempfile.gettempdir()).resolve()
        if where == folder.resolve() or folder.resolve() in where.parents:
            os.close(fd)
            os.unlink(name)
            os.symlink("/dev/full", name)
            fd = os.open(os.devnull, os.O_RDONLY)
        return fd, name

    monkeypatch.setattr(tempfile, "mkstemp", mkstemp)
    return folder


def _existing_mesh(folder: Path) -> Path:
    folder.mkdir()
    write_file(folder / "existing.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    write_file(folder / "existing.params.json", '{"generator": "earlier"}\n')
    return folder / "existing.obj"


# case -> (arguments given the input folder i, output folder o, a folder k of earlier outputs and the full
# folder F; the path the message must name)
FULL_CASES = {
    "generate: preview on a full disk keeps the existing mesh": (
        lambda i, o, k, F: ["generate", "dishes", "--preview", F / "p.png", "-o", _existing_mesh(k)], "p.png"),
    "generate: mesh under new folders on a full disk": (
        lambda i, o, k, F: ["generate", "dishes", "-o", F / "new" / "sub" / "g.obj"], "g.obj"),
    "convert: result on a full disk leaves no mesh": (
        lambda i, o, k, F: ["convert", _box_obj(i), "--to", "bsp", "--planes", "4", "--convexes", "1", "--steps", "2",
                            "--resolution", "16", "--mesh", o / "c.obj", "-o", F / "c.json"], "c.json"),
    "convert: mesh on a full disk keeps the existing result": (
        lambda i, o, k, F: ["convert", _box_obj(i), "--to", "bsp", "--planes", "4", "--convexes", "1", "--steps", "2",
                            "--resolution", "16", "--mesh", F / "new" / "c.obj",
                            "-o", write_file(_existing_mesh(k).with_name("c.json"), "{}")], "c.obj"),
    "render: a full disk": (lambda i, o, k, F: ["render", "dishes", "--views", "2", "--size", "32", "-o", F / "r"],
                            "view_000.png"),
    "render: a full disk under new folders": (
        lambda i, o, k, F: ["render", "dishes", "--views", "1", "--size", "32", "-o", F / "a" / "b"], "view_000.png"),
    "jacobian: a full disk": (lambda i, o, k, F: ["jacobian", "chair", "--n-points", "20", "-o", F / "n" / "j.npz"],
                              "j.npz"),
    "mask: overlay on a full disk leaves no mask": (
        lambda i, o, k, F: ["mask", _photo(i), "--box", "8,8,40,40", "-o", o / "m.png", "--overlay", F / "ov.png"],
        "ov.png"),
    "vectorize: preview on a full disk leaves no SVG": (
        lambda i, o, k, F: ["vectorize", _drawing(i), "--steps", "3", "-o", o / "d.svg", "--preview", F / "p.png"],
        "p.png"),
}


@pytest.mark.parametrize("case", sorted(FULL_CASES))
def test_a_full_disk_leaves_nothing_and_changes_nothing(case, tmp_path, capsys, full):
    make, name = FULL_CASES[case]
    i, o, k = tmp_path / "in", tmp_path / "out", tmp_path / "keep"
    i.mkdir()
    args = make(i, o, k, full)
    inputs, kept = _files(i), _files(k)
    code, stdout, err = run([*args, "-q"], capsys)
    lines = err.strip().splitlines()
    assert code == 2, f"{case}: exit {code}, stderr: {err}"
    assert len(lines) == 1 and lines[0].startswith("ipm: error: cannot write "), f"{case}: stderr: {err!r}"
    assert "no space left on the device" in lines[0] and name in lines[0], lines[0]
    assert str(full) in lines[0] and ".tmp" not in lines[0], f"{case}: names a temporary path: {lines[0]}"
    assert stdout == ""
    assert not o.exists(), f"{case}: left behind {sorted(_files(o))}"
    assert _files(full) == {}, f"{case}: left in the full folder {sorted(_files(full))}"
    assert _files(k) == kept, f"{case}: changed the earlier outputs {sorted(_files(k))}"
    assert _files(i) == inputs


def test_a_full_disk_names_the_file_also_through_the_os_error_line(tmp_path):
    """An OS error that reaches the CLI names its file(s); one that names none says so."""
    from ipm.cli.common import os_error_line

    assert os_error_line(OSError(errno.ENOSPC, "No space left on device", str(tmp_path / "x"))) == \
        f"{tmp_path / 'x'}: no space left on the device"
    e = OSError(errno.EXDEV, "Invalid cross-device link", "a", None, "b")
    assert os_error_line(e) == "a -> b: Invalid cross-device link"
    assert "named no file" in os_error_line(OSError(errno.ENOSPC, "No space left on device"))


# -- render into a folder with an earlier render -------------------------------------------------------------
def test_render_overwrite_replaces_the_earlier_render_as_a_whole(tmp_path, capsys):
    """Three views with cues and parts, then one view without: no file of the first render survives (a later
    ``ipm fit --parts`` must not find its part labels), other files stay."""
    out = tmp_path / "r"
    code, _, err = run(["render", "dishes", "--preset", "mug", "--views", "3", "--size", "32", "-o", out], capsys)
    assert code == 0, err
    first = _files(out)
    assert {"view_002.png", "part_002.png", "parts.json", "depth_002.npy", "normal_002.png",
            "preview_002.png"} <= set(first)
    write_file(out / "notes.txt", "mine")
    code, _, err = run(["render", "dishes", "--preset", "mug", "--views", "1", "--size", "32", "-o", out], capsys)
    assert code == 2 and "--overwrite" in err
    assert _files(out) == {**first, "notes.txt": b"mine"}
    code, _, err = run(["render", "dishes", "--preset", "bowl", "--views", "1", "--size", "40", "--no-cues",
                        "--no-previews", "-o", out, "--overwrite"], capsys)
    assert code == 0, err
    assert sorted(_files(out)) == ["cameras.json", "notes.txt", "view_000.png"]
    assert json.loads((out / "cameras.json").read_text())[0]["width"] == 40
    code, _, err = run(["fit", "dishes", "--masks", out, "--parts", out, "--budget", "2", "-o", tmp_path / "run"],
                       capsys)
    assert code == 2 and "parts" in err.lower(), err
    # an empty folder needs no --overwrite
    (tmp_path / "empty").mkdir()
    code, _, err = run(["render", "dishes", "--views", "1", "--size", "32", "--no-previews", "-o", tmp_path / "empty"],
                       capsys)
    assert code == 0, err


def test_render_overwrite_refused_half_way_puts_the_folder_back(tmp_path, capsys, monkeypatch):
    out = tmp_path / "r"
    code, _, err = run(["render", "dishes", "--views", "2", "--size", "32", "--no-previews", "-o", out], capsys)
    assert code == 0, err
    before = _files(out)
    real, calls = os.replace, []

    def flaky(a, b, *k, **kw):
        calls.append((a, b))
        if Path(b).parent == out and len([c for c in calls if Path(c[1]).parent == out]) == 2:
            raise OSError(errno.EIO, "Input/output error", str(b))
        return real(a, b, *k, **kw)

    monkeypatch.setattr(os, "replace", flaky)
    code, _, err = run(["render", "dishes", "--views", "1", "--size", "48", "--no-previews", "-o", out,
                        "--overwrite"], capsys)
    monkeypatch.undo()
    assert code == 2 and err.startswith(f"ipm: error: cannot write {out}"), err
    assert _files(out) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r"]


# -- ipm.files -------------------------------------------------------------------------------------------------
def test_all_or_nothing_restores_every_output_when_a_rename_is_refused(tmp_path, monkeypatch):
    from ipm import files
    from ipm.errors import InputError

    a, b, c = tmp_path / "a.txt", tmp_path / "b.txt", tmp_path / "new" / "c.txt"
    a.write_text("old a")
    real = os.replace

    def refuse_c(src, dst, *k, **kw):
        if Path(dst) == c:
            raise OSError(errno.ENOSPC, "No space left on device", str(dst))
        return real(src, dst, *k, **kw)

    monkeypatch.setattr(os, "replace", refuse_c)
    with pytest.raises(InputError, match=rf"^cannot write {c}: no space left on the device$"):
        with files.all_or_nothing(a, b, c):
            files.write_text(a, "new a")
            files.write_text(b, "new b")
            assert a.read_text() == "old a" and not b.exists()  # nothing in place before the block ends
            files.write_text(c, "new c")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt"]
    assert a.read_text() == "old a"
    monkeypatch.undo()
    with files.all_or_nothing(a, b, c):
        files.write_text(a, "new a")
        files.write_text(b, "new b")
        files.write_text(c, "new c")
    assert (a.read_text(), b.read_text(), c.read_text()) == ("new a", "new b", "new c")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt", "b.txt", "new"]


def test_all_or_nothing_takes_everything_back_on_any_error(tmp_path):
    from ipm import files

    a = tmp_path / "a.txt"
    a.write_text("old")
    with pytest.raises(RuntimeError):
        with files.all_or_nothing(a, tmp_path / "x" / "y" / "b.txt"):
            files.write_text(a, "new")
            files.write_text(tmp_path / "x" / "y" / "b.txt", "new")
            raise RuntimeError("a bug after the writes")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt"] and a.read_text() == "old"


def test_same_outputs_are_refused(tmp_path):
    from ipm import files
    from ipm.errors import InputError

    (tmp_path / "d").mkdir()
    os.symlink(tmp_path / "d", tmp_path / "link")
    files.check_distinct({"-o": tmp_path / "a.png", "--overlay": tmp_path / "b.png", "--x": None})
    with pytest.raises(InputError, match="-o and --overlay: expected different files"):
        files.check_distinct({"-o": tmp_path / "d" / "a.png", "--overlay": tmp_path / "link" / "a.png"})
    (tmp_path / "a.png").write_bytes(b"x")
    os.link(tmp_path / "a.png", tmp_path / "hard.png")
    with pytest.raises(InputError):
        files.check_distinct({"-o": tmp_path / "a.png", "--overlay": tmp_path / "hard.png"})
    with pytest.raises(InputError, match="twice"):
        with files.all_or_nothing(tmp_path / "q.png", tmp_path / "d" / ".." / "q.png"):
            pass


def test_a_failed_write_takes_back_the_folders_it_made(tmp_path):
    from ipm import files

    target = tmp_path / "a" / "b" / "c.txt"
    with pytest.raises(RuntimeError):
        with files.atomic_path(target):
            raise RuntimeError("failed")
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(RuntimeError):
        with files.staged_directory(tmp_path / "x" / "y") as tmp:
            (tmp / "f.txt").write_text("half")
            raise RuntimeError("failed")
    assert list(tmp_path.iterdir()) == []


def test_a_write_error_without_a_file_name_names_the_output(tmp_path):
    """A writer's flush on a full disk raises OSError with no file name: the line names the output."""
    from ipm import files
    from ipm.errors import InputError

    with pytest.raises(InputError, match=rf"^cannot write {tmp_path / 'o.txt'}: no space left on the device$"):
        with files.atomic_path(tmp_path / "o.txt"):
            raise OSError(errno.ENOSPC, "No space left on device")
    with pytest.raises(InputError, match=rf"^cannot write {tmp_path / 'r' / 'v.png'}: no space left"):
        with files.staged_directory(tmp_path / "r") as tmp:
            with files.atomic_path(tmp / "v.png"):
                raise OSError(errno.ENOSPC, "No space left on device")
    assert list(tmp_path.iterdir()) == []


def test_a_non_finite_jacobian_is_refused(tmp_path, capsys, monkeypatch):
    """Whatever makes a Jacobian non-finite (float32 overflow), it is refused, not written."""
    import torch

    import ipm.jacobian as J

    real = J.sdf_jacobian

    def overflowing(*a, **k):
        out = real(*a, **k)
        out[0, 0] = float("inf")
        out[1, 1] = float("nan")
        return out

    monkeypatch.setattr(J, "sdf_jacobian", overflowing)
    code, stdout, err = run(["jacobian", "chair", "--n-points", "8", "--dtype", "float32", "-o",
                             tmp_path / "o" / "j.npz"], capsys)
    assert code == 2 and stdout == ""
    assert err.strip() == ("ipm: error: chair at 8 points: expected a finite Jacobian, got 2 NaN or infinite entries "
                           "in J with dtype float32; use float64, or points nearer the shape")
    assert not (tmp_path / "o").exists()
    assert torch.isfinite(real(lambda th, p: p.norm(dim=-1), torch.zeros(0), torch.ones(2, 3))).all()


def test_float32_points_within_range_still_work(tmp_path, capsys):
    pts = _points(tmp_path / "p.npy", 1e3)
    code, _, err = run(["jacobian", "chair", "--points", pts, "--dtype", "float32", "-o", tmp_path / "j.npz"], capsys)
    assert code == 0, err
    with np.load(tmp_path / "j.npz") as z:
        assert np.isfinite(z["J"]).all()
