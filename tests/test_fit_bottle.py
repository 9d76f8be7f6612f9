"""Issue #17: a bottle without a handle, fitted from one view, never gets a handle (10 seeds: five from the
bottle preset, five from the mug preset, which starts with the handle on)."""

from __future__ import annotations

import pytest

from ipm.generators import get_generator
from ipm.optim.fit import FitSettings, run_fit
from ipm.render.camera import input_views
from tests.test_fit_generators import mask_target, normalized_mesh

# (seed, preset): from the mug preset a handle left on would have to be switched off by the search
RUNS = [(seed, "bottle") for seed in range(5)] + [(seed, "mug") for seed in range(5, 10)]


@pytest.mark.slow
def test_a_bottle_seen_once_never_gets_a_handle():
    # not the preset itself: a taller bottle, wider in the body, with a shorter neck
    radii = [0.4, 0.42, 0.42, 0.41, 0.39, 0.33, 0.18, 0.12, 0.12]
    target = normalized_mesh("dishes", "bottle", {"height": 2.2, **{f"radius_{i}": r for i, r in enumerate(radii)}})
    cams = input_views(1, 96)
    handles = []
    for seed, preset in RUNS:
        _, _, best = run_fit(get_generator("dishes"), mask_target(target, cams),
                             FitSettings(budget=500, seed=seed, preset=preset))
        handles.append(best["discrete"]["has_handle"])
    assert handles == [0] * len(RUNS), list(zip(RUNS, handles))
