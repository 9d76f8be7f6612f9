"""The description length of a fit: FitSettings.part_cost per part that discrete values add (Param.adds)."""

from __future__ import annotations

import pytest
import torch

from ipm.errors import InputError
from ipm.generators import get_generator
from ipm.optim.problem import Problem
from ipm.optim.settings import FitSettings
from ipm.optim.targets import MaskTarget
from ipm.params import Param
from ipm.render.camera import orbit_camera


def test_only_discrete_parameters_add_parts():
    with pytest.raises(InputError, match="adds 'handle' expects a bool or int count"):
        Param("reach", 0.5, 0.0, 1.0, "float", adds="handle")
    p = Param("wings", 0, 0, 3, "int", adds="wing")
    assert p.to_json()["adds"] == "wing"


def test_switches_that_add_parts_say_so():
    spec = get_generator("dishes").spec
    assert [(p.name, p.adds) for p in spec.discrete if p.adds] == [("has_handle", "handle"), ("has_spout", "spout"),
                                                                         ("has_knob", "knob")]
    spec = get_generator("building").spec
    assert [(p.name, p.adds) for p in spec.discrete if p.adds] == [("wings", "wing"), ("roof_boxes", "roof box")]


def _problem(cost: float) -> Problem:
    cam = orbit_camera(30.0, 25.0, 3.2, fov_deg=40.0, width=32, height=32)
    mask = torch.zeros(1, 32, 32)
    mask[0, 8:26, 10:22] = 1.0
    return Problem(get_generator("dishes"), MaskTarget(mask, [cam]), FitSettings(preset="mug", part_cost=cost))


def test_part_cost_is_charged_per_part_and_leaves_the_gradient_alone():
    free, charged = _problem(0.0), _problem(0.01)
    x = free.x0(scale=0.8)
    for handle, extra in ((1, 0.01), (0, 0.0)):
        d = {"has_handle": handle}
        l0, g0, _ = free.objective(x, d, need_grad=True)
        l1, g1, _ = charged.objective(x, d, need_grad=True)
        assert float(l1 - l0) == pytest.approx(extra, abs=1e-6)
        assert torch.equal(g0, g1)
    assert charged.part_cost({}) == pytest.approx(0.01)  # the mug preset has its handle


def test_part_cost_is_checked_and_old_runs_replay_without_it():
    from ipm.fitting import _settings_from_json

    with pytest.raises(InputError, match="part_cost"):
        FitSettings(part_cost=-1.0).check()
    assert _settings_from_json({"budget": 10}).part_cost == 0.0
