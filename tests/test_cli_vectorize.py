"""``ipm vectorize`` from the command line: outputs, and bad input (exit 2, one line, nothing written)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from conftest import ROOT
from conftest import run_cli as run
from PIL import Image
from test_curves import circle, drawing


@pytest.fixture(scope="module")
def circle_png(tmp_path_factory) -> str:
    path = tmp_path_factory.mktemp("in") / "circle.png"
    Image.fromarray((255 * (1 - drawing(circle(), size=128 * 2)[::2, ::2])).astype(np.uint8)).save(path)
    return str(path)


def test_writes_svg_json_and_preview(circle_png, tmp_path, capsys):
    out = tmp_path / "o" / "c.svg"
    code, stdout, err = run(["vectorize", circle_png, "-o", out, "--preview", tmp_path / "p.png", "--steps", "60",
                             "--json"], capsys)
    assert code == 0, err
    summary = json.loads(stdout)
    assert summary["curves"] >= 1 and summary["json"] == str(out.with_suffix(".json"))
    data = json.loads(out.with_suffix(".json").read_text())
    assert data["format"] == "ipm-vectorized" and data["size"] == [128, 128]
    assert out.read_text().startswith("<svg") and Image.open(tmp_path / "p.png").size[0] >= 128


def _image(folder, name, arr):
    path = folder / name
    Image.fromarray(arr).save(path)
    return path


CASES = {
    "missing file": (lambda i: i / "nope.png", [], "not found"),
    "not an image": (lambda i: (i / "x.png").write_text("hello") and i / "x.png", [], "image"),
    "all white": (lambda i: _image(i, "w.png", np.full((32, 32), 255, np.uint8)), [], "nothing"),
    "all black": (lambda i: _image(i, "b.png", np.zeros((32, 32), np.uint8)), [], "nothing"),
    "cell too large": (lambda i: _image(i, "s.png", np.pad(np.zeros((4, 4), np.uint8), 6, constant_values=255)),
                       ["--cell", "40"], "cell"),
    "cell too small": (lambda i: _image(i, "s.png", np.pad(np.zeros((4, 4), np.uint8), 6, constant_values=255)),
                       ["--cell", "1"], "cell"),
    "bad suffix": (lambda i: _image(i, "s.png", np.pad(np.zeros((4, 4), np.uint8), 6, constant_values=255)),
                   ["-o", "OUT/x.pdf"], "suffix"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_input_exits_2_with_one_line_and_writes_nothing(case, tmp_path, capsys):
    make, extra, word = CASES[case]
    i, o = tmp_path / "in", tmp_path / "out"
    i.mkdir()
    image = make(i)
    args = ["vectorize", image, *[a.replace("OUT", str(o)) for a in extra]]
    if "-o" not in extra:
        args += ["-o", o / "x.svg"]
    code, stdout, err = run(args, capsys)
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and lines[0].startswith("ipm: error: "), err
    assert word in lines[0].lower() and stdout == ""
    assert not o.exists() or not any(o.iterdir())


def test_a_real_subprocess(circle_png, tmp_path):
    out = tmp_path / "c.svg"
    proc = subprocess.run([sys.executable, "-m", "ipm.cli", "vectorize", circle_png, "-o", str(out), "--steps", "30"],
                          capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "curves:" in proc.stdout and out.is_file() and out.with_suffix(".json").is_file()
    empty = tmp_path / "empty.png"
    empty.write_bytes(b"")
    proc = subprocess.run([sys.executable, "-m", "ipm.cli", "vectorize", str(empty), "-o", str(tmp_path / "e.svg")],
                          capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and not (tmp_path / "e.svg").exists()
