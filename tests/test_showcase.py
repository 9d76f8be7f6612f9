"""The demo's scoring of real targets (ipm/showcase.py: ``_real_target``, used by the learned-start, fused-views,
teapot and parsimony steps): the masks it writes are the target's, and its score is protocol v2's held-out IoU (from
one view: the target itself scores 1, a scaled copy too, since K = 1 predictions are scaled about the eye first;
another shape less; from more views nothing is rescaled)."""

from __future__ import annotations

from pathlib import Path

import torch
from conftest import require_file

from ipm import data as D
from ipm.showcase import _real_target
from ipm.types import TriMesh


def test_real_target_scores_as_protocol_v2(tmp_path):
    require_file(D.path(D.TEAPOT))
    target, score = _real_target(D.TEAPOT, tmp_path / "masks")
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


def test_real_target_takes_the_up_axis_the_bench_does(tmp_path):
    """The parsimony step's sugar bowl is Y up: ``_real_target(up="y")`` loads it as table1.toml's bench does,
    vertex for vertex."""
    from ipm.bench.harness import load_target

    require_file(D.path(D.SUGAR_BOWL))
    target, _ = _real_target(D.SUGAR_BOWL, tmp_path / "masks", up="y")
    bench = load_target(Path(__file__).resolve().parents[1] / "experiments" / "table1.toml", "sugar_bowl").mesh
    torch.testing.assert_close(target.verts.double(), bench.verts.double())


def test_real_target_from_several_views_is_scored_as_it_is(tmp_path):
    """From more than one view protocol v2 rescales nothing: a copy 1.2 times farther from the first camera scores
    well below the target itself (it scored over 0.99 from one view, above)."""
    from ipm.render.camera import input_views

    require_file(D.path(D.TEAPOT))
    target, score = _real_target(D.TEAPOT, tmp_path / "masks", views=4)
    assert sorted(p.name for p in (tmp_path / "masks").glob("view_*.png")) == [f"view_00{i}.png" for i in range(4)]
    assert score(target) > 0.999
    eye = input_views(4, 256)[0].eye.double()
    assert score(TriMesh(eye + (target.verts.double() - eye) * 1.2, target.faces)) < 0.9
