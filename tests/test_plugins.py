"""Generator plug-ins (issue #31): a user's file or installed package adds a generator with no edit to ipm.

The tutorial's gear (docs/examples/gear.py) is the worked example: its mesh is checked for invariants, its
Jacobian against float64 central differences, and every command the tutorial shows runs. Broken plug-ins
are refused with one line naming the file and the problem.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from conftest import refusal, write_file

from ipm.errors import InputError
from ipm.generators.base import GENERATORS

ROOT = Path(__file__).resolve().parents[1]
GEAR = ROOT / "docs" / "examples" / "gear.py"
TUTORIAL = ROOT / "docs" / "plugins.md"

GOOD_SDF = '''
import torch
from ipm.generators.custom import Param, SdfGenerator


class Pill(SdfGenerator):
    name = "pill_{tag}"
    params = (Param("radius", 0.3, 0.05, 1.0), Param("length", 0.6, 0.0, 2.0), Param("caps", 1, 0, 1, "bool"))

    def distance(self, p, points):
        y = points[..., 1] - torch.clamp(points[..., 1], -p["length"] / 2, p["length"] / 2)
        r = torch.sqrt(points[..., 0] ** 2 + y ** 2 + points[..., 2] ** 2 + 1e-12)
        return r - p["radius"]

    def bounds(self, p):
        r, h = float(p["radius"]), float(p["length"]) / 2 + float(p["radius"])
        return (-r, -h, -r), (r, h, r)
'''

MESH_TEMPLATE = '''
import torch
from ipm.generators.custom import MeshGenerator, Param


class Tri(MeshGenerator):
    name = "{name}"
    params = (Param("size", 1.0, 0.1, 2.0),)

    def build(self, p):
        {body}
'''

TETRA = ("v = torch.tensor([[0., 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=p['size'].dtype) * p['size']\n"
         "        return v, [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]")


@pytest.fixture
def plugins(monkeypatch):
    """Load plug-in files in this process; on exit the generators they added are forgotten."""
    from ipm.generators import plugins as P

    GENERATORS.discover()
    before, loaded = GENERATORS.current(), dict(P._LOADED)
    monkeypatch.setenv(P.ENV, "")
    yield P
    for name in set(GENERATORS.current()) - set(before):
        GENERATORS.remove(name)
        P.SOURCES.pop(name, None)
    for path in set(P._LOADED) - set(loaded):
        sys.modules.pop(P._LOADED.pop(path).__name__, None)


def _mesh_plugin(tmp_path: Path, name: str, body: str) -> Path:
    return write_file(tmp_path / f"{name}.py", MESH_TEMPLATE.format(name=name, body=body))


def test_gear_mesh_is_closed_and_moves_with_its_parameters(plugins):
    """The tutorial's gear: watertight, outward, 16 vertices per tooth; its volume grows with the thickness."""
    (name,) = plugins.load_file(GEAR)
    g = GENERATORS[name]()
    m = g.to_mesh(g.values(overrides={"teeth": 9}))
    tm = m.to_trimesh()
    assert (m.n_verts, m.n_faces) == (16 * 9, 32 * 9)
    assert tm.is_watertight and tm.is_winding_consistent and tm.volume > 0
    thick = g.to_mesh(g.values(overrides={"teeth": 9, "thickness": 0.4})).to_trimesh()
    assert thick.volume == pytest.approx(2 * tm.volume, rel=1e-9)  # a prism: volume proportional to thickness
    assert plugins.SOURCES[name] == str(GEAR)


def test_gear_jacobian_matches_float64_central_differences(plugins):
    """``ipm.jacobian`` of a plug-in generator against central differences in float64."""
    from ipm.jacobian import output_jacobian

    plugins.load_file(GEAR)
    g = GENERATORS["gear"]()
    values = g.values(overrides={"teeth": 7, "taper": 0.5})
    theta, discrete = g.split(values)
    J = torch.as_tensor(output_jacobian(g, values).J)
    eps = 1e-6
    for i in range(theta.numel()):
        up, down = theta.clone(), theta.clone()
        up[i] += eps
        down[i] -= eps
        fd = (g.mesh(up, discrete).verts - g.mesh(down, discrete).verts).reshape(-1) / (2 * eps)
        assert torch.allclose(J[:, i].double(), fd, atol=1e-7), g.spec.continuous[i].name


def test_sdf_plugin_gets_meshes_jacobians_and_fields(plugins, tmp_path):
    """An :class:`SdfGenerator` plug-in: distances checked, meshed by marching cubes, Jacobian in theta and position."""
    from ipm.jacobian import output_jacobian

    (name,) = plugins.load_file(write_file(tmp_path / "pill.py", GOOD_SDF.format(tag="a")))
    g = GENERATORS[name]()
    values = g.values()
    tm = g.to_mesh(values, resolution=48).to_trimesh()
    assert tm.is_watertight
    expected = 4 / 3 * torch.pi * 0.3 ** 3 + torch.pi * 0.3 ** 2 * 0.6  # a capsule
    assert tm.volume == pytest.approx(float(expected), rel=0.03)
    pts = torch.tensor([[0.5, 0.1, 0.0], [0.0, 0.9, 0.2]], dtype=torch.float64)
    J = torch.as_tensor(output_jacobian(g, values, points=pts).J)
    assert tuple(J.shape) == (2, g.spec.n_continuous + 3)
    # d distance / d radius = -1; d / d position = the unit direction from the axis segment
    assert torch.allclose(J[:, 0], torch.full((2,), -1.0, dtype=J.dtype), atol=1e-9)


def test_installed_package_entry_point(tmp_path):
    """A package with an ``ipm.generators`` entry point (a path on sys.path with its metadata) is found by every
    command with no --plugin: listed with its source, generated."""
    pkg = tmp_path / "site"
    shutil.copy(GEAR, write_file(pkg / "geartools" / "__init__.py", "").parent / "gear.py")
    write_file(pkg / "geartools-0.1.dist-info" / "METADATA", "Metadata-Version: 2.1\nName: geartools\nVersion: 0.1\n")
    write_file(pkg / "geartools-0.1.dist-info" / "entry_points.txt", "[ipm.generators]\nspur = geartools.gear:Gear\n")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(pkg), str(ROOT)]), "IPM_PLUGINS": ""}
    run = subprocess.run([sys.executable, "-m", "ipm", "list", "generators", "--json"], capture_output=True,
                         text=True, env=env, cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    rows = {r["name"]: r for r in json.loads(run.stdout)}
    assert rows["spur"]["source"] == "spur = geartools.gear:Gear (package geartools)"
    run = subprocess.run([sys.executable, "-m", "ipm", "generate", "spur", "--set", "teeth=6", "-o", "s.obj"],
                         capture_output=True, text=True, env=env, cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    assert (tmp_path / "s.obj").is_file()


BAD = {
    "import error": ("import not_a_module_anywhere\n", r"ModuleNotFoundError: No module named 'not_a_module_anywhere' "
                     r"\(.*import_error\.py:1\)"),
    "syntax error": ("def broken(:\n", r"SyntaxError: .*syntax_error\.py:1"),
    "no generator": ("X = 1\n", r"defines no generator"),
    "2D vertices": (MESH_TEMPLATE.format(name="flat", body="return torch.zeros(3, 2) * p['size'], [[0, 1, 2]]"),
                    r"vertices: expected shape \(V, 3\), got \(3, 2\)"),
    "float faces": (MESH_TEMPLATE.format(name="ffaces", body="return torch.eye(3) * p['size'], [[0., 1., 2.]]"),
                    r"faces: expected \(F, 3\) integers with F > 0, got \(1, 3\) float"),
    "faces out of range": (MESH_TEMPLATE.format(name="range", body="return torch.eye(3) * p['size'], [[0, 1, 5]]"),
                           r"faces index vertices 0\.\.5, but there are 3"),
    "not a tuple": (MESH_TEMPLATE.format(name="tup", body="return [torch.eye(3)]"),
                    r"build\(\) must return \(verts, faces\) or a TriMesh, got list"),
    "not differentiable": (MESH_TEMPLATE.format(name="nodiff", body="return torch.eye(3) * float(p['size']), "
                                                "[[0, 1, 2]]"), r"not differentiable in its continuous parameters"),
    "a built-in's name": (MESH_TEMPLATE.format(name="dishes", body=TETRA),
                          r"generator 'dishes' is taken by ipm\.generators\.dishes"),
    "distances of the wrong shape": (GOOD_SDF.format(tag="b").replace("return r - p[\"radius\"]",
                                                                      "return (r - p[\"radius\"])[..., None]"),
                                     r"distance\(\) must return a float tensor of shape \(64,\).*got \(64, 1\)"),
    "an empty box": (GOOD_SDF.format(tag="c").replace("return (-r, -h, -r), (r, h, r)", "return (0, 0, 0), (0, 0, 0)"),
                     r"bounds\(\) must return finite \(lo, hi\)"),
    "bad params": (MESH_TEMPLATE.format(name="params", body=TETRA).replace(
        'params = (Param("size", 1.0, 0.1, 2.0),)', 'params = ("size",)'), r"params must be a list of ipm Param"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_broken_plugins_are_refused_with_one_line(plugins, tmp_path, case):
    """Every way a plug-in can be broken is an :class:`InputError` naming the file and the problem."""
    text, pattern = BAD[case]
    path = write_file(tmp_path / (re.sub(r"\W+", "_", case) + ".py"), text)
    with pytest.raises(InputError) as err:
        plugins.load_file(path)
    msg = str(err.value)
    assert "\n" not in msg and str(path) in msg, msg
    assert re.search(pattern, msg), msg


def test_cli_refuses_broken_plugins_and_bad_options(tmp_path):
    """Through the command line: exit 2, one ``ipm: error:`` line, no traceback, no output written."""
    bad = write_file(tmp_path / "bad.py", MESH_TEMPLATE.format(name="nodiff", body="return torch.eye(3) * "
                                                                "float(p['size']), [[0, 1, 2]]"))
    env = {**os.environ, "IPM_PLUGINS": ""}
    cases = {"non-differentiable": (["--plugin", str(bad), "generate", "nodiff", "-o", "x.obj"],
                                    "not differentiable"),
             "missing file": (["generate", "gear", "-o", "x.obj", "--plugin", "nope.py"], "--plugin nope.py: no such"),
             "not python": (["--plugin", str(GEAR.with_suffix(".toml")), "list", "generators"], "expected a Python file"),
             "unknown without the plug-in": (["generate", "gear", "-o", "x.obj"], "ipm --plugin FILE.py")}
    for case, (args, needle) in cases.items():
        run = subprocess.run([sys.executable, "-m", "ipm", *args], capture_output=True, text=True, env=env,
                             cwd=tmp_path)
        line = refusal(case, run.returncode, run.stdout, run.stderr)
        assert needle in line, (case, line)
    assert not (tmp_path / "x.obj").exists()


def _tutorial_commands() -> list[str]:
    """The ``ipm ...`` lines of the tutorial's shell blocks, in order."""
    blocks = re.findall(r"```sh\n(.*?)```", TUTORIAL.read_text(), flags=re.S)
    return [line.strip() for b in blocks for line in b.splitlines() if line.strip().startswith("ipm ")]


@pytest.mark.slow
def test_tutorial_commands_run(tmp_path):
    """Every command of docs/plugins.md, as written, from a copy of the repository's docs/examples (the bench
    on one target at a small budget: the full table is results/gear, `make table-gear`)."""
    shutil.copytree(ROOT / "docs" / "examples", tmp_path / "docs" / "examples")
    exp = tmp_path / "docs" / "examples" / "gear.toml"
    text = exp.read_text().replace("budget = 500", "budget = 40").replace("samples = 10000", "samples = 1000")
    exp.write_text(re.sub(r'\[\[targets\]\]\nname = "gear_2".*?(?=\[\[methods\]\])', "", text, flags=re.S))
    commands = _tutorial_commands()
    assert len(commands) >= 5 and any(" fit " in c for c in commands) and any(" bench " in c for c in commands)
    env = {**os.environ, "IPM_PLUGINS": "", "IPM_THREADS": "1"}
    for command in commands:
        args = command.split()[1:]
        run = subprocess.run([sys.executable, "-m", "ipm", *args], capture_output=True, text=True, env=env,
                             cwd=tmp_path)
        assert run.returncode == 0, (command, run.stderr[-2000:])
