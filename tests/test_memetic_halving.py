"""Successive halving (ipm.optim.discrete.halving): the memetic search's first population and enumerate."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ipm.optim.discrete import halving, halving_rungs
from ipm.optim.evaluator import BudgetExhausted


class FakeRefine:
    """Candidate i's loss after s steps in total is floor[i] + 1 / (1 + s): each keeps its rank, and the
    steps each was given are recorded."""

    def __init__(self, floors, budget=None):
        self.floors, self.budget = floors, budget
        self.steps = [0] * len(floors)
        self.calls: list[tuple[int, int]] = []

    def __call__(self, x, d, k):
        i = d["i"]
        if self.budget is not None and sum(self.steps) + k > self.budget:
            raise BudgetExhausted
        self.steps[i] += k
        self.calls.append((i, k))
        return x + k, self.floors[i] + 1.0 / (1 + self.steps[i])


def _first(n):
    return [(torch.zeros(2), {"i": i}) for i in range(n)]


def test_halving_gives_the_best_the_most_steps_on_the_same_budget():
    floors = [0.5, 0.1, 0.9, 0.3, 0.7, 0.2, 0.8, 0.4]
    f = FakeRefine(floors)
    assert halving_rungs(8) == 4
    pop = halving(_first(8), f, 12)
    # rungs of 8, 4, 2 and 1 candidates, each costing 8 x 12 steps
    assert [k for _, k in f.calls] == [12] * 8 + [24] * 4 + [48] * 2 + [96]
    # the survivors of each rung are the better half: 1, 5, 3, 7 (floors 0.1, 0.2, 0.3, 0.4), then 1, 5, then 1
    assert [i for i, k in f.calls if k == 24] == [1, 5, 3, 7]
    assert [i for i, k in f.calls if k == 48] == [1, 5]
    assert f.steps[1] == 12 + 24 + 48 + 96 and f.steps[0] == 12
    # every candidate comes back with its latest refinement and loss, in the order given
    assert [d["i"] for _, d, _ in pop] == list(range(8))
    for i, (x, _, loss) in enumerate(pop):
        assert loss == pytest.approx(floors[i] + 1.0 / (1 + f.steps[i]))
        assert float(x[0]) == f.steps[i]


@pytest.mark.parametrize("n", [1, 2, 3, 6])
def test_halving_any_number_of_candidates_stays_within_its_rungs(n):
    f = FakeRefine([0.1 * i for i in range(n)])
    halving(_first(n), f, 10)
    assert 0 < sum(f.steps) <= n * 10 * halving_rungs(n)
    assert f.steps[0] == max(f.steps)  # the best candidate got the most


def test_halving_passes_an_exhausted_budget_on():
    f = FakeRefine([0.1 * i for i in range(8)], budget=100)
    with pytest.raises(BudgetExhausted):
        halving(_first(8), f, 50)


def test_best_pose_keeps_a_candidates_own_pose_when_it_fits_best():
    """A preset comes posed by rank_presets (area and centroid matched): best_pose tries that pose too,
    not only the kept starts' (building_2 from block_stair: 0.33 after 12 steps from a start's pose)."""
    from ipm.optim.discrete import Space, best_pose

    gen = np.array([0, 1])  # generator coordinates; 2, 3 are the pose
    starts = [(torch.tensor([0.5, 0.5, 0.1, 0.1], dtype=torch.float64), {}),
              (torch.tensor([0.5, 0.5, 0.9, 0.9], dtype=torch.float64), {})]
    space = Space(4, gen, [], starts)
    seen = []

    def ev(x, d, grad=False):  # the loss is the pose's distance from (0.6, 0.6)
        seen.append(x.clone())
        return float(((x[2:] - 0.6) ** 2).sum()), None

    own = torch.tensor([0.2, 0.3, 0.6, 0.6], dtype=torch.float64)
    got = best_pose(ev, space, own, {})
    assert torch.equal(got, own) and len(seen) == 3
    far = torch.tensor([0.2, 0.3, 0.0, 0.0], dtype=torch.float64)
    got = best_pose(ev, space, far, {})
    assert torch.equal(got, torch.tensor([0.2, 0.3, 0.9, 0.9], dtype=torch.float64))
    # a candidate already in a start's pose is evaluated once in it
    seen.clear()
    best_pose(ev, space, torch.tensor([0.2, 0.3, 0.1, 0.1], dtype=torch.float64), {})
    assert len(seen) == 2


def test_the_first_population_takes_each_discrete_combination_before_a_second_preset_of_one():
    """Ranked presets are reordered so that a combination no kept start and no better preset has comes in
    first (its best preset), then the rest in their ranked order; each list keeps its points."""
    from ipm.optim.strategies.memetic import combinations_first

    def entry(i, handle, spout=0):
        return torch.full((2,), float(i)), {"has_handle": handle, "has_spout": spout}

    starts = [entry(0, 1), entry(1, 1)]
    presets = [entry(10, 1), entry(11, 0), entry(12, 1), entry(13, 0), entry(14, 1, 1), entry(15, 1, 1)]
    got = [int(x[0]) for x, _ in combinations_first(presets, starts)]
    assert got == [11, 14, 10, 12, 13, 15]
    assert combinations_first([], starts) == [] and len(combinations_first(presets, [])) == len(presets)
    assert [int(x[0]) for x, _ in combinations_first(presets, [])] == [10, 11, 14, 12, 13, 15]
