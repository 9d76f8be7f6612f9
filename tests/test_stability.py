"""Fits whose answer does not hinge on noise (issue #28): the same case under a perturbation that stands in for
another machine (benchmarks/perturbation.py: the eager kernel instead of the native one, two threads, every
start or the target moved by 1e-6 relative) lands within TOLERANCE of the unperturbed run on its scores and on
the same discrete values. ``make bench-perturbation`` runs every case under every variant, torch's kernels
without SIMD among them, and writes results/perturbation.md."""

from __future__ import annotations

import pytest

from benchmarks.perturbation import DATA, TOLERANCE, run_one, spread
from tests.conftest import require_file

pytestmark = pytest.mark.slow

# the eager kernel costs 3-5x the native one: it is tried on the cheaper cases
CASES = {
    "demo_mug": ("eager", "threads2", "start", "target"),
    "t1_cup": ("eager", "threads2", "start", "target"),
    "t1_bottle": ("threads2", "start", "target"),
    "t1_building": ("threads2", "start", "target"),
}


@pytest.mark.parametrize("case", list(CASES))
def test_a_fit_lands_in_the_same_place_under_perturbations(case):
    require_file(DATA / "vessels" / "ocrtoc_mug.ply")
    rows = [run_one(case, v) for v in ("base", *CASES[case])]
    s = spread(rows)[case]
    assert s["same_discrete"], [(r["variant"], r["discrete"]) for r in rows]
    assert s["max_deviation"] <= TOLERANCE, [(r["variant"], r["scores"]) for r in rows]
