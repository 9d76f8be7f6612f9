"""The split report's chance analysis (:func:`benchmarks.split_report.split_chance`): the share of all re-splits
of each class's targets in which the per-class check would hold, counted by hand on small classes."""

from __future__ import annotations

import pytest

from benchmarks.split_report import split_chance


def _rows(scores: dict[str, tuple[float, float]]) -> list[dict]:
    """Bench rows of method ``ipm``, seed 0, with held-out IoU ``scores[target]`` at K = 1 and 2."""
    return [{"target": t, "method": "ipm", "views": k, "seed": 0, "heldout_iou": v, "status": "ok"}
            for t, pair in scores.items() for k, v in zip((1, 2), pair)]


def test_each_class_is_counted_over_every_split_of_its_sizes():
    classes = {"a1": "a", "a2": "a", "a3": "a", "b1": "b", "b2": "b"}
    tune = _rows({"a1": (0.90, 0.90), "b1": (0.80, 0.80)})
    val = _rows({"a2": (0.92, 0.945), "a3": (0.96, 0.94), "b2": (0.84, 0.70)})
    rows = {r["class"]: r for r in split_chance(tune, val, classes)}
    # class a, one target against two, by the tune target: {a1} +0.04 / +0.0425 (out, not below), {a2} +0.01 /
    # -0.025 (within), {a3} -0.05 / -0.0175 (out, below by more)
    assert rows["a"]["splits"] == 3
    assert rows["a"]["both ways"] == pytest.approx(1 / 3, abs=1e-3)
    assert rows["a"]["not below"] == pytest.approx(2 / 3, abs=1e-3)
    # class b, one against one: +0.04 / -0.10 either way round: never within both ways, below by more either way
    assert rows["b"] == {"class": "b", "n tune": 1, "n validation": 1, "splits": 2, "both ways": 0.0,
                         "not below": 0.0}
    assert rows["all at once"]["splits"] == 6
    assert rows["all at once"]["both ways"] == 0.0


def test_classes_without_targets_on_one_side_are_left_out():
    classes = {"a1": "a", "a2": "a", "v1": "vase"}
    tune = _rows({"a1": (0.90, 0.90), "v1": (0.98, 0.98)})
    val = _rows({"a2": (0.91, 0.91)})
    rows = split_chance(tune, val, classes)
    assert [r["class"] for r in rows] == ["a", "all at once"]
    assert rows[0]["both ways"] == 1.0 and rows[-1]["both ways"] == 1.0
