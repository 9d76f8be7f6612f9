"""The polish's share of the budget: ``FitSettings.polish`` if given, else the generator's ``polish_share``, else
``POLISH_SHARE``; the search stops where that share begins."""

from __future__ import annotations

from boxes import Boxes, boxes_target

from ipm.generators import get_generator
from ipm.optim.fit import FitSettings, polish_share, run_fit
from ipm.optim.settings import POLISH_SHARE


def test_the_share_is_the_settings_then_the_generators_then_the_default():
    building, dishes = get_generator("building"), get_generator("dishes")
    assert polish_share(building, FitSettings()) == building.polish_share == 0.25
    assert polish_share(dishes, FitSettings()) == POLISH_SHARE == 0.15   # dishes declares none
    assert polish_share(building, FitSettings(polish=0.1)) == 0.1
    assert polish_share(building, FitSettings(polish=0.0)) == 0.0       # an explicit 0 is not "not given"


class HalfPolished(Boxes):
    polish_share = 0.5


def _searched(gen, settings: FitSettings) -> int:
    phases: list[str] = []
    run_fit(gen, boxes_target(), settings, sink=lambda rec: phases.append(rec["phase"]))
    assert len(phases) == settings.budget
    return sum(1 for p in phases if not p.startswith(("polish", "ties", "parsimony")))


def test_the_search_stops_where_the_generators_share_begins():
    settings = dict(budget=60, seed=0, discrete="none", lr=0.03)
    assert _searched(HalfPolished(), FitSettings(**settings)) == 30
    assert _searched(Boxes(), FitSettings(**settings)) == 60 - int(60 * POLISH_SHARE)
    assert _searched(HalfPolished(), FitSettings(polish=0.25, **settings)) == 45
