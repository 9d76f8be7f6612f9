"""Issue #14, subdivision in fitting (FitSettings.subdivide): the problem renders the generator's mesh
subdivided, keeps every face's part, passes gradients through, and refuses what it cannot do."""

from __future__ import annotations

import pytest
import torch

from ipm.errors import InputError
from ipm.generators import get_generator
from ipm.optim.fit import FitSettings
from ipm.optim.problem import Problem
from ipm.render.camera import input_views
from tests.test_fit_generators import mask_target, normalized_mesh


def _problem(**kw) -> Problem:
    cams = input_views(1, 64)
    target = mask_target(normalized_mesh("dishes", "mug"), cams)
    return Problem(get_generator("dishes"), target, FitSettings(budget=10, preset="mug", lod="low", **kw))


@pytest.mark.parametrize("scheme", ["loop", "midpoint", "neural"])
def test_the_rendered_mesh_is_the_subdivided_one(scheme):
    plain, sub = _problem(), _problem(subdivide=scheme, subdivide_levels=1)
    x = plain.x0()
    m0, m1 = plain.mesh_world(x, dict(plain.d0)), sub.mesh_world(x, dict(sub.d0))
    assert m1.n_faces == 4 * m0.n_faces and m1.group_names == m0.group_names
    # every child face keeps its parent's part: the parent's corners among its vertices share its group
    F0, F1 = m0.faces.numpy(), m1.faces.numpy()
    n = m0.n_verts
    # libigl numbers a face's four children together: their old vertices are exactly the parent's corners
    children = F1.reshape(-1, 12)
    for parent, kids in zip(F0, children):
        assert set(kids[kids < n].tolist()) == set(parent.tolist())
    parent_of_corner = {}
    for f, g in zip(F0, m0.groups.numpy()):
        for v in f:
            parent_of_corner.setdefault(int(v), set()).add(int(g))
    for f, g in zip(F1, m1.groups.numpy()):
        old = [int(v) for v in f if v < n]
        assert all(int(g) in parent_of_corner[v] for v in old)
    if scheme == "midpoint":   # midpoint keeps the surface: the old vertices do not move
        assert torch.allclose(m1.verts[:n], m0.verts)


def test_gradients_reach_the_parameters_through_the_subdivision():
    prob = _problem(subdivide="loop")
    loss, grad, _ = prob.objective(prob.x0(), dict(prob.d0), True)
    assert torch.isfinite(loss) and torch.isfinite(grad).all() and grad[: prob.n].abs().sum() > 0


@pytest.mark.parametrize("kw, message", [
    ({"subdivide": "butterfly"}, "subdivision: expected one of loop, midpoint, neural, got 'butterfly'"),
    ({"subdivide": "loop", "subdivide_levels": 0}, "subdivision levels: expected a number of levels in [1, 3]"),
    ({"subdivide": "loop", "subdivide_levels": 4}, "subdivision levels: expected a number of levels in [1, 3]"),
])
def test_bad_subdivision_settings_are_refused(kw, message):
    with pytest.raises(InputError, match=message.replace("[", r"\[").replace("]", r"\]").replace("(", r"\(")
                       .replace(")", r"\)")):
        FitSettings(**kw).check()


def test_an_sdf_generator_cannot_be_subdivided():
    cams = input_views(1, 32)
    target = mask_target(normalized_mesh("dishes", "mug"), cams)
    with pytest.raises(InputError, match="subdivision: applies to mesh generators; chair is an SDF generator"):
        Problem(get_generator("chair"), target, FitSettings(budget=10, subdivide="loop"))
