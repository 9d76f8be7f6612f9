"""The parsimony rule (:func:`ipm.optim.parsimony.simpler_winner`): a part the input views show stays only where
it brings the loss below ``part_ratio`` of the best fit without it.

The rule's choice is tested on an evaluator whose objective returns set losses per discrete combination (the
losses are the polished ones it sees in a fit: the validation mustard bottle from one view, a handle's 0.030
against 0.046 without; the tune mug's, 0.009 against 0.101)."""

from __future__ import annotations

import json

import pytest
import torch

from ipm.errors import InputError
from ipm.generators import get_generator
from ipm.optim.evaluator import Evaluator
from ipm.optim.fit import FitSettings, MaskTarget, MeshTarget, Problem, part_ratio
from ipm.optim.parsimony import simpler_winner
from ipm.render.camera import orbit_camera
from ipm.render.raster import rasterize_mesh
from tests.conftest import run_cli

COMBOS = ("has_handle", "has_spout", "has_knob")


def _target() -> MaskTarget:
    gen = get_generator("dishes")
    cam = orbit_camera(30.0, 20.0, 3.2, fov_deg=40.0, width=32)
    mesh = gen.to_mesh(gen.values("mug"))
    return MaskTarget(rasterize_mesh(mesh, cam).mask.float()[None], [cam.to(torch.float32)])


@pytest.fixture(scope="module")
def prob() -> Problem:
    return Problem(get_generator("dishes"), _target(), FitSettings(preset="glass"))


def _evaluated(prob: Problem, losses: dict[tuple, float]) -> Evaluator:
    """An evaluator that has seen each combination of ``losses`` once, with that loss."""
    def objective(x, disc, grad):
        return torch.tensor(losses[tuple(disc[k] for k in COMBOS)], dtype=torch.float64), None, {}

    ev = Evaluator(objective, len(losses))
    for combo in losses:
        ev(prob.x0(), dict(zip(COMBOS, combo)), grad=False)
    return ev


@pytest.mark.parametrize("losses, ratio, want, dropped", [
    # a handle that buys too little goes; one that buys a clear fit stays
    ({(1, 0, 0): 0.030, (0, 0, 0): 0.046}, 0.5, (0, 0, 0), ("has_handle",)),
    ({(1, 0, 0): 0.009, (0, 0, 0): 0.101}, 0.5, (1, 0, 0), ()),
    # the spout and the knob go together where they buy too little; the handle, which buys enough, stays
    ({(1, 1, 1): 0.050, (1, 0, 0): 0.062, (0, 0, 0): 0.200}, 0.5, (1, 0, 0), ("has_spout", "has_knob")),
    # of two simpler candidates within the share, the lower loss
    ({(1, 1, 0): 0.040, (1, 0, 0): 0.060, (0, 1, 0): 0.050}, 0.5, (0, 1, 0), ("has_handle",)),
    # a candidate that trades one part for another is no simpler
    ({(1, 0, 0): 0.030, (0, 1, 0): 0.031}, 0.5, (1, 0, 0), ()),
    # ratio 1: the lower loss wins
    ({(1, 0, 0): 0.030, (0, 0, 0): 0.031}, 1.0, (1, 0, 0), ()),
    # exactly at the share the parts stay
    ({(1, 0, 0): 0.025, (0, 0, 0): 0.050}, 0.5, (1, 0, 0), ()),
])
def test_the_rule_takes_the_simpler_combination_where_the_parts_buy_too_little(prob, losses, ratio, want, dropped):
    ev = _evaluated(prob, losses)
    best, fewer = simpler_winner(prob, ev, ratio)
    assert tuple(best.discrete[k] for k in COMBOS) == want
    assert best.loss == losses[want]
    assert fewer == dropped


def _two_views() -> MaskTarget:
    one = _target()
    cam = orbit_camera(120.0, 20.0, 3.2, fov_deg=40.0, width=32)
    gen = get_generator("dishes")
    mask = rasterize_mesh(gen.to_mesh(gen.values("mug")), cam).mask.float()[None]
    return MaskTarget(torch.cat([one.masks, mask]), [*one.cameras, cam.to(torch.float32)])


def _mesh_target() -> MeshTarget:
    gen = get_generator("dishes")
    return MeshTarget(gen.to_mesh(gen.values("mug")), samples=200)


def _with_parts() -> MaskTarget:
    one = _target()
    labels = torch.where(one.masks > 0.5, 0, -1).long()   # every object pixel labelled "body"
    return MaskTarget(one.masks, one.cameras, parts=labels, part_names=("body",))


@pytest.mark.parametrize("target", [_two_views, _mesh_target, _with_parts], ids=["two views", "a mesh", "parts"])
def test_the_rule_is_for_one_view(target):
    """Two views tell a part from a stand-in for the outline, a mesh shows every part as it is, and part labels
    say where a part is: the rule does not apply, and the lower loss stays the winner."""
    prob = Problem(get_generator("dishes"), target(), FitSettings(preset="glass"))
    ev = _evaluated(prob, {(1, 0, 0): 0.030, (0, 0, 0): 0.046})
    best, fewer = simpler_winner(prob, ev, 0.5)
    assert (best.discrete["has_handle"], fewer, ev.count) == (1, (), 2)


def test_the_share_comes_from_the_settings_else_the_generator():
    dishes, building = get_generator("dishes"), get_generator("building")
    assert part_ratio(dishes, FitSettings()) == dishes.part_ratio == 0.5
    assert part_ratio(building, FitSettings()) == 1.0   # the building declares none: no rule
    assert part_ratio(dishes, FitSettings(part_ratio=0.8)) == 0.8


def test_the_share_is_checked():
    with pytest.raises(InputError, match=r"^part_ratio: expected a share of the loss in \(0, 1\], got 0.0$"):
        FitSettings(part_ratio=0.0).check()


def test_the_fit_without_the_parts_may_be_the_winners_own_body(prob):
    """The best fit without a handle is the better of the handle-less combination's own best point and the
    winner's shape with the handle taken off (one evaluation): here the latter, whose body the search fitted
    better; it takes the winner's place with the winner's body."""
    x_w = prob.x0(yaw=30.0)
    x_other = prob.x0(yaw=30.0).clone()
    x_other[: prob.n] = 1.0 - x_other[: prob.n]

    def objective(x, disc, grad):
        if disc["has_handle"] == 1:
            loss = 0.030
        else:   # the winner's body without its handle fits well; the handle-less leader's own body does not
            loss = 0.046 if torch.equal(x[: prob.n], x_w[: prob.n]) else 0.200
        return torch.tensor(loss, dtype=torch.float64), None, {}

    ev = Evaluator(objective, 3)
    ev(x_w, {"has_handle": 1, "has_spout": 0, "has_knob": 0}, grad=False)
    ev(x_other, {"has_handle": 0, "has_spout": 0, "has_knob": 0}, grad=False)
    best, fewer = simpler_winner(prob, ev, 0.5)
    assert ev.count == 3 and ev.phase == "parsimony"
    assert (best.discrete["has_handle"], best.loss, fewer) == (0, 0.046, ("has_handle",))
    assert torch.equal(best.x[: prob.n], x_w[: prob.n])
    # with no evaluation left, the handle-less leader's own point is all there is: the handle stays
    ev = Evaluator(objective, 2)
    ev(x_w, {"has_handle": 1, "has_spout": 0, "has_knob": 0}, grad=False)
    ev(x_other, {"has_handle": 0, "has_spout": 0, "has_knob": 0}, grad=False)
    assert simpler_winner(prob, ev, 0.5)[1] == ()


def test_the_cli_fit_names_what_the_rule_dropped(tmp_path, capsys):
    """``ipm fit --part-ratio``: the mug's handle, in view, stays where the lower loss wins (1); where a part
    must bring the loss below 1 % of the fit without it, it goes, and result.json says so under ``dropped``."""
    masks = tmp_path / "m"
    code, _, err = run_cli(["render", "dishes", "--preset", "mug", "--views", "1", "--size", "48", "--no-previews",
                            "-o", masks], capsys)
    assert code == 0, err
    got = {}
    for ratio in ("1", "0.01"):
        run = tmp_path / f"run_{ratio}"
        code, _, err = run_cli(["fit", "dishes", "--masks", masks, "--preset", "glass", "--budget", "120",
                                "--part-ratio", ratio, "-o", run], capsys)
        assert code == 0, err
        result = json.loads((run / "result.json").read_text())
        got[ratio] = (result["discrete"]["has_handle"], result["dropped"])
    assert got == {"1": (1, []), "0.01": (0, ["has_handle"])}
