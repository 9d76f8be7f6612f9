"""``benchmarks.ambiguity``'s table and arguments: the reference fit named after its view count, the verdict from the
losses, ``--against METHOD:VIEWS`` checked."""

from __future__ import annotations

import argparse

import pytest

from benchmarks.ambiguity import _against, _table


def _row(target: str, own: float, own_refined: float, ref: float, refined: float) -> dict:
    def point(loss: float) -> dict:
        return {"loss": loss, "input_iou": 0.9, "heldout_iou": 0.8}

    return {"target": target, "x1": point(own), "x1r": point(own_refined), "x8": point(ref), "x8r": point(refined),
            "discrete_1": {"has_handle": 0}, "discrete_8": {"has_handle": 1}}


def test_the_table_names_the_fits_after_their_view_counts_and_judges_by_the_losses():
    # the vase: the reference lower as it is; the cup: lower only refined, but the fit refined as long is lower still
    rows = [_row("vase", 0.012, 0.011, 0.0073, 0.0060), _row("bowl", 0.010, 0.009, 0.011, 0.0105),
            _row("cup", 0.012, 0.007, 0.013, 0.008)]
    text = _table(rows, 200, 0.003, "experiments/table1.toml", views=4, against=("ipm", 2))
    assert text.startswith("# 4 views against 2 (experiments/table1.toml, seed 0; x2 and x4 refined 200 Adam steps")
    assert "| target | x4 loss | x4 input IoU | x4 held-out | x4r loss | x4r held-out | x2 loss |" in text
    assert "x2r loss" in text
    assert "x2: the 2-view fit (method ipm)" in text
    assert "| vase | 0.0120 |" in text and text.count("search missed") == 2  # once in the legend
    for target in ("bowl", "cup"):
        assert text.split(f"| {target} |")[1].splitlines()[0].endswith("prefers wrong |")
    assert "Discrete values (x4 / x2):" in text


def test_the_default_table_is_the_single_view_one():
    text = _table([_row("teapot", 0.03, 0.029, 0.031, 0.025)], 200, 0.003, "experiments/table_coverage.toml")
    assert text.startswith("# Single-view ambiguity (experiments/table_coverage.toml")
    assert "x8: the 8-view fit;" in text and "| teapot | 0.0300 |" in text


@pytest.mark.parametrize("text, want", [("ipm-bound:8", ("ipm-bound", 8)), ("ipm:2", ("ipm", 2))])
def test_against_reads_method_and_views(text, want):
    assert _against(text) == want


@pytest.mark.parametrize("text", ["ipm", "ipm:", ":2", "ipm:0", "ipm:two"])
def test_against_refuses_anything_else(text):
    with pytest.raises(argparse.ArgumentTypeError, match="expected METHOD:VIEWS"):
        _against(text)


def test_the_summary_takes_the_lower_loss_point_of_the_fits_own_objective():
    def point(loss: float, heldout: float) -> dict:
        return {"loss": loss, "input_iou": 0.9, "heldout_iou": heldout}

    def row(target, x1, x1r, x8, x8r):
        return {"target": target, "x1": point(*x1), "x1r": point(*x1r), "x8": point(*x8), "x8r": point(*x8r),
                "discrete_1": {}, "discrete_8": {}}

    # the mug: the reference's basin is lower refined (0.90 held out); the plate: the fit's own (0.85)
    rows = [row("mug", (0.02, 0.80), (0.015, 0.81), (0.03, 0.95), (0.012, 0.90)),
            row("plate", (0.01, 0.84), (0.008, 0.85), (0.02, 0.97), (0.009, 0.96))]
    text = _table(rows, 200, 0.003, "experiments/table1.toml")
    assert ("Mean held-out IoU over the 2 targets: x1 0.820; at the lower-loss point of x1r and x8r, the best point "
            "of the K = 1 objective known here (where a search that found it would end) 0.875; x8 0.960.") in text
