"""Every kind of extension is a Registry that ``ipm list`` shows (issue #33): loss terms and converters from a new
module in a package (conftest.throwaway_member), up axes, intrinsics formats, mesh formats and shape adapters
added to their registry; each is then used where its kind is used, and listed."""

from __future__ import annotations

import json

import pytest
import torch
from boxes import Boxes, boxes_target
from conftest import run_cli, throwaway_member

from ipm.cli.list_cmd import REGISTRIES, WHAT
from ipm.optim.fit import FitSettings
from ipm.optim.problem import Problem
from ipm.optim.terms import TERMS

TERM = '''
import torch

from ipm.optim.terms import TERMS


@TERMS.register()
class Constant:
    """A constant of 0.25, to see it in the sum."""

    name = "{name}"
    order = 99

    def applies(self, prob):
        return True

    def __call__(self, ev):
        return torch.tensor(0.25, dtype=ev.x.dtype)
'''

CONVERTER = '''
from ipm.convert import CONVERTERS


@CONVERTERS.register("{name}")
def identity(mesh, **options):
    """Hands the mesh back (a throwaway converter)."""
    return mesh
'''


def _listed(capsys, what: str) -> list[str]:
    code, out, err = run_cli(["list", what, "--json"], capsys)
    assert code == 0, err
    return [r["name"] for r in json.loads(out)]


def test_every_registry_is_listed(capsys):
    code, out, _ = run_cli(["list", "--json"], capsys)
    assert code == 0 and set(json.loads(out)) == set(WHAT)
    for what in REGISTRIES:
        assert _listed(capsys, what), what


def test_a_loss_term_from_a_new_module_joins_the_sum(tmp_path, monkeypatch, capsys):
    name = "throwaway_constant"
    target = boxes_target()
    settings = FitSettings(budget=5, seed=0)
    gen = Boxes()
    base = Problem(gen, target, settings)
    x, d = base.x0(), dict(base.d0)
    before = float(base.objective(x, d, False)[0])
    with throwaway_member(TERMS, name, TERM.format(name=name), tmp_path, monkeypatch, "throwaway_terms"):
        assert name in _listed(capsys, "terms")
        prob = Problem(gen, target, settings)
        assert [t.name for t in prob.terms][-1] == name
        assert float(prob.objective(x, d, False)[0]) == pytest.approx(before + 0.25, abs=1e-6)


def test_a_converter_from_a_new_module_is_a_target_of_convert(tmp_path, monkeypatch, capsys):
    from ipm.convert import CONVERTERS, get_converter

    name = "throwaway_identity"
    with throwaway_member(CONVERTERS, name, CONVERTER.format(name=name), tmp_path, monkeypatch,
                          "throwaway_converters"):
        assert name in _listed(capsys, "converters")
        assert get_converter(name)("m") == "m"


def test_an_up_axis_an_intrinsics_format_and_a_mesh_format_added_to_their_registries(tmp_path, capsys):
    from ipm.io.export import EXPORTERS, export_mesh
    from ipm.io.meshes import UP_AXES, to_y_up
    from ipm.render.camera import INTRINSICS_FORMATS, load_intrinsics
    from ipm.types import TriMesh

    def x_up(v):
        """X up: (x, y, z) -> (-y, x, z)."""
        return torch.stack([-v[:, 1], v[:, 0], v[:, 2]], 1)

    def txt(path, what):
        """Six numbers: fx fy cx cy width height."""
        fx, fy, cx, cy, w, h = (float(t) for t in path.read_text().split())
        return {"fx": fx, "fy": fy, "cx": cx, "cy": cy, "width": w, "height": h}

    written = []

    def xyz(mesh, path, meta):
        """Vertices as text."""
        written.append(path.name)
        path.write_text("\n".join(" ".join(map(str, v)) for v in mesh.verts.tolist()))

    UP_AXES.add("x", x_up)
    INTRINSICS_FORMATS.add(".txt", txt)
    EXPORTERS.add(".xyz", xyz)
    try:
        assert "x" in _listed(capsys, "axes") and ".txt" in _listed(capsys, "intrinsics")
        assert ".xyz" in _listed(capsys, "formats")
        v = torch.tensor([[1.0, 0.0, 0.0]])
        assert torch.equal(to_y_up(v, "x"), torch.tensor([[0.0, 1.0, 0.0]]))
        (tmp_path / "k.txt").write_text("100 100 32 24 64 48")
        assert load_intrinsics(tmp_path / "k.txt").fx == 100
        mesh = TriMesh(torch.eye(3), torch.tensor([[0, 1, 2]]))
        export_mesh(mesh, tmp_path / "m.xyz", sidecar=False)
        assert len(written) == 1 and len((tmp_path / "m.xyz").read_text().splitlines()) == 3  # written atomically
    finally:
        UP_AXES.remove("x")
        INTRINSICS_FORMATS.remove(".txt")
        EXPORTERS.remove(".xyz")
    assert "x" not in UP_AXES and ".txt" not in INTRINSICS_FORMATS and ".xyz" not in EXPORTERS


def test_a_shape_adapter_added_for_a_new_kind_of_generator():
    from ipm.optim.shapes import SHAPES, MeshShape, shape_for

    class Spline(MeshShape):
        """A mesh-like kind, for the test."""

    gen = Boxes()
    gen.kind = "spline"
    SHAPES.add("spline", Spline)
    try:
        assert isinstance(shape_for(gen, FitSettings(), torch.float32), Spline)
    finally:
        SHAPES.remove("spline")
