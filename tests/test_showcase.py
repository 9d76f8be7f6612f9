"""The demo's one-view scoring (ipm/showcase.py: ``_one_view_target``, used by the learned-start, teapot and parsimony
steps): the mask it writes is the target's, and its score is protocol v2's K = 1 held-out IoU (the target itself
scores 1, a scaled copy too, since K = 1 predictions are scaled about the eye first; another shape less)."""

from __future__ import annotations

from pathlib import Path

import torch
from conftest import require_file

from ipm import data as D
from ipm.showcase import _one_view_target
from ipm.types import TriMesh


def test_one_view_target_scores_as_protocol_v2(tmp_path):
    require_file(D.path(D.TEAPOT))
    target, score = _one_view_target(D.TEAPOT, tmp_path / "masks")
    assert (tmp_path / "masks" / "view_000.png").is_file() and (tmp_path / "masks" / "cameras.json").is_file()
    assert score(target) > 0.999
    from ipm.render.camera import input_views

    eye = input_views(1, 256)[0].eye.double()
    farther = TriMesh(eye + (target.verts.double() - eye) * 1.2, target.faces)  # the same view, 1.2x the distance
    assert score(farther) > 0.99  # scaled about the eye to the Chamfer-best size before it is scored
    assert score(TriMesh(target.verts.double() * 1.2, target.faces)) < 0.95  # not a mere scale about the origin
    import trimesh

    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.6)
    sphere = TriMesh(torch.as_tensor(ball.vertices), torch.as_tensor(ball.faces))
    assert score(sphere) < 0.8


def test_one_view_target_takes_the_up_axis_the_bench_does(tmp_path):
    """The parsimony step's sugar bowl is Y up: ``_one_view_target(up="y")`` loads it as table1.toml's bench does,
    vertex for vertex."""
    from ipm.bench.harness import load_target

    require_file(D.path(D.SUGAR_BOWL))
    target, _ = _one_view_target(D.SUGAR_BOWL, tmp_path / "masks", up="y")
    bench = load_target(Path(__file__).resolve().parents[1] / "experiments" / "table1.toml", "sugar_bowl").mesh
    torch.testing.assert_close(target.verts.double(), bench.verts.double())
