"""Search strategies and mask losses are registry members: one new module in a package registers one, and
``FitSettings`` and ``run_fit`` accept it by name (here from a throwaway package on ``sys.path``)."""

from __future__ import annotations

import sys

import pytest
import torch
from boxes import Boxes, boxes_target
from conftest import throwaway_member

from ipm.errors import InputError
from ipm.losses import LOSSES
from ipm.optim.fit import FitSettings, run_fit
from ipm.optim.strategies import STRATEGIES

STRATEGY = '''
from ipm.optim.strategies import STRATEGIES

CALLS = []


@STRATEGIES.register("{name}")
def first_start_only(ev, space, refine, rng, settings=None):
    CALLS.append(ev.remaining)
    x, d = space.starts[0]
    refine(x, d, ev.remaining)
'''

LOSS = '''
from ipm.losses import LOSSES

CALLS = []


@LOSSES.register("{name}")
def l1_loss(pred, target):
    CALLS.append(1)
    return (pred - target).abs().mean()
'''




@pytest.fixture(scope="module")
def target():
    return boxes_target()


def test_a_strategy_from_a_new_module(tmp_path, monkeypatch, target):
    name, pkg = "throwaway_first_start", "throwaway_strategies"
    with pytest.raises(InputError, match="discrete search: expected one of"):
        FitSettings(discrete=name).check()
    with throwaway_member(STRATEGIES, name, STRATEGY.format(name=name), tmp_path, monkeypatch, pkg):
        assert name in STRATEGIES.names()
        with pytest.raises(InputError, match=f"expected one of .*{name}"):
            FitSettings(discrete="nope").check()
        res, _, best = run_fit(Boxes(), target, FitSettings(budget=40, discrete=name, seed=0, lr=0.03))
        calls = sys.modules[f"{pkg}.member"].CALLS
        assert len(calls) == 1 and 0 < calls[0] < 40 and res.evaluations == 40


def test_a_mask_loss_from_a_new_module(tmp_path, monkeypatch, target):
    name, pkg = "throwaway_l1", "throwaway_losses"
    with pytest.raises(InputError, match=r"loss: expected a mask loss \(iou, mse"):
        FitSettings(loss=name).check()
    with throwaway_member(LOSSES, name, LOSS.format(name=name), tmp_path, monkeypatch, pkg):
        assert name in LOSSES
        res, _, _ = run_fit(Boxes(), target, FitSettings(budget=30, discrete="none", loss=name, seed=0))
        assert len(sys.modules[f"{pkg}.member"].CALLS) == 30 and res.loss < 1.0
    assert name not in LOSSES


def test_the_builtin_members():
    assert {"memetic", "nlopt", "enumerate", "none"} <= set(STRATEGIES.names())
    assert {"iou", "mse"} <= set(LOSSES.names())
    p, t = torch.rand(2, 8, 8, dtype=torch.float64), torch.rand(2, 8, 8, dtype=torch.float64)
    from ipm.losses import mse_loss, soft_iou_loss

    assert LOSSES["iou"] is soft_iou_loss and LOSSES["mse"] is mse_loss
    assert float(LOSSES["mse"](p, p)) == 0.0 and 0.0 <= float(LOSSES["iou"](p, t)) <= 1.0


STRATEGY_WITH_SETTINGS = '''
from dataclasses import dataclass

from ipm.optim.strategies import STRATEGIES

SEEN = []


@dataclass(frozen=True)
class Settings:
    share: float = 0.5


@STRATEGIES.register("{name}")
def part_of_the_budget(ev, space, refine, rng, settings=None):
    s = settings.strategy() if settings is not None else Settings()
    SEEN.append(s)
    x, d = space.starts[0]
    refine(x, d, int(ev.remaining * s.share))


part_of_the_budget.settings = Settings
'''


def test_a_strategy_with_settings_is_one_new_module(tmp_path, monkeypatch, target):
    """Issue #33: a strategy registers its settings class with itself; FitSettings.search carries them by the
    strategy's name, checked by that class (unknown keys refused), and run files keep them."""
    name, pkg = "throwaway_share", "throwaway_strategies_settings"
    with throwaway_member(STRATEGIES, name, STRATEGY_WITH_SETTINGS.format(name=name), tmp_path, monkeypatch, pkg):
        assert name in STRATEGIES  # found: its module imported
        mod = sys.modules[f"{pkg}.member"]
        s = FitSettings(budget=40, discrete=name, seed=0, lr=0.03, search={name: {"share": 0.25}})
        s.check()
        assert s.strategy() == mod.Settings(0.25) and s.to_json()["search"] == {name: {"share": 0.25}}
        with pytest.raises(InputError, match=rf"{name} settings: unknown setting\(s\) bogus"):
            FitSettings(discrete=name, search={name: {"bogus": 1}})
        run_fit(Boxes(), target, s)
        assert mod.SEEN == [mod.Settings(0.25)]
