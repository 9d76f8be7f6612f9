"""Bench method ``structure`` (ipm/bench/methods/structure.py): the structure search from the task's masks,
scored as a mesh; its settings checked like every method's, one view refused.

The recovery threshold was set from a measurement at the test's settings (an L of two boxes from 4 views at
64 px, budget 1000: held-out IoU 0.978), with a margin for platform noise."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ipm.bench.config import load_experiment
from ipm.bench.methods import METHODS, Task, check_settings
from ipm.errors import InputError, MethodFailed
from ipm.types import TriMesh

SIZE = 64


def _masks(mesh: TriMesh, cams) -> np.ndarray:
    from ipm.render.raster import rasterize_mesh

    return np.stack([rasterize_mesh(mesh, c).mask.cpu().numpy().astype(bool) for c in cams])


@pytest.fixture(scope="module")
def ell() -> TriMesh:
    import trimesh

    a = trimesh.creation.box(extents=(1.6, 0.4, 0.8))
    b = trimesh.creation.box(extents=(0.4, 1.4, 0.8))
    b.apply_translation((-0.6, 0.5, 0.0))
    m = trimesh.util.concatenate([a, b])
    return TriMesh(torch.as_tensor(np.asarray(m.vertices)), torch.as_tensor(np.asarray(m.faces)))


def test_structure_method_recovers_two_parts_from_four_views(ell):
    from ipm.metrics import mask_iou
    from ipm.render.camera import heldout_views, input_views

    cams = input_views(4, SIZE)
    pred = METHODS["structure"](Task(_masks(ell, cams), cams), {}, 1000, 0)
    held = heldout_views(SIZE)
    iou = float(np.mean([mask_iou(a, b) for a, b in zip(_masks(pred.mesh, held), _masks(ell, held))]))
    assert iou > 0.93, iou
    assert pred.evaluations == 1000 and pred.info["nodes"] >= 3 and "box" in pred.info["structure"]
    assert pred.mesh.verts.dtype == torch.float64 and pred.mesh.faces.shape[1] == 3


def test_structure_method_refuses_one_view(ell):
    from ipm.render.camera import input_views

    cams = input_views(1, SIZE)
    with pytest.raises(MethodFailed, match="at least 2 views"):
        METHODS["structure"](Task(_masks(ell, cams), cams), {}, 100, 0)


@pytest.mark.parametrize("settings, message", [
    ({"budget": 5}, r"unknown setting\(s\) 'budget'"),
    ({"seed": 1}, r"unknown setting\(s\) 'seed'"),
    ({"edits": ["add", "teleport"]}, "teleport"),
    ({"beam": 0}, "beam"),
    ({"resolution": 4}, r"setting resolution: expected an integer in \[16, 512\], got 4"),
    ({"resolution": True}, "setting resolution"),
])
def test_structure_method_settings_are_checked(settings, message):
    with pytest.raises(InputError, match=message):
        check_settings("structure", settings)


def test_structure_method_in_an_experiment_file(tmp_path):
    exp = tmp_path / "e.toml"
    exp.write_text('name = "e"\n[[targets]]\nname = "a"\ngenerator = "chair"\n'
                   '[[methods]]\nname = "search"\nmethod = "structure"\nviews = [2, 4]\nbudget = 16000\n'
                   'edits = ["add", "replace", "delete"]\n')
    e = load_experiment(exp)
    m = e.method("search")
    assert m.budget_or(e.budget) == 16000 and m.settings == {"edits": ["add", "replace", "delete"]}
    exp.write_text(exp.read_text().replace('"delete"]', '"delete"]\nsteps = 0'))
    with pytest.raises(InputError, match="method search: structure: .*steps"):
        load_experiment(exp)
