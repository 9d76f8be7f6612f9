"""Fitting machinery without a renderer: mesh targets, budget accounting, determinism, resume by replay."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from ipm.generators import get_generator
from ipm.metrics import normalize_vertices, shape_scores
from ipm.optim.evaluator import BudgetExhausted, Evaluator, ReplayMismatch
from ipm.optim.fit import FitSettings, MeshTarget, run_fit
from ipm.types import TriMesh


@pytest.fixture(scope="module")
def mug_target():
    g = get_generator("mug")
    vals = g.values(overrides={"mug.height": 1.3, "mug.radius": 0.35, "mug.handle_radius": 0.3})
    m = g.to_mesh(vals, resolution=64)
    return MeshTarget(TriMesh(torch.as_tensor(normalize_vertices(m.verts.numpy())), m.faces), samples=2000)


def test_sdf_generator_recovers_mesh_target(mug_target):
    g = get_generator("mug")
    res, prob, best = run_fit(g, mug_target, FitSettings(budget=150, discrete="none", lr=0.03))
    assert res.evaluations == 150
    s = shape_scores(prob.mesh_world(best["x"], best["discrete"]), mug_target.mesh, n=3000, resolution=48)
    assert s.fscore_005 >= 0.98 and s.fscore_002 >= 0.9, s


def test_same_seed_same_result_and_resume_by_replay(mug_target):
    g = get_generator("mug")
    settings = dict(budget=60, discrete="none", lr=0.03, seed=7)
    full: list[dict] = []
    a, _, best_a = run_fit(g, mug_target, FitSettings(**settings), sink=full.append)
    again: list[dict] = []
    b, _, best_b = run_fit(g, mug_target, FitSettings(**settings), sink=again.append)
    assert a.loss == b.loss and torch.equal(best_a["x"], best_b["x"])
    assert [r["x"] for r in full] == [r["x"] for r in again]
    # interrupted after 23 evaluations, then resumed: the replayed records are not recomputed
    tail: list[dict] = []
    c, _, best_c = run_fit(g, mug_target, FitSettings(**settings), sink=tail.append, replay=full[:23])
    assert len(tail) == 60 - 23
    assert c.loss == a.loss and torch.equal(best_c["x"], best_a["x"])
    assert [r["x"] for r in tail] == [r["x"] for r in full[23:]]


def test_evaluator_budget_and_replay_mismatch():
    calls = []

    def objective(x, d, grad):
        calls.append(1)
        return (x ** 2).sum(), 2 * x, {}

    ev = Evaluator(objective, 3)
    for _ in range(3):
        ev(torch.full((2,), 0.5), {})
    with pytest.raises(BudgetExhausted):
        ev(torch.full((2,), 0.5), {})
    assert ev.best.loss == pytest.approx(0.5) and len(calls) == 3
    rec = []
    Evaluator(objective, 2, sink=rec.append)(torch.full((2,), 0.25), {})
    ev2 = Evaluator(objective, 2, replay=rec)
    with pytest.raises(ReplayMismatch):
        ev2(torch.full((2,), 0.3), {})
    with pytest.raises(ValueError, match="at least 1"):
        Evaluator(objective, 0)


def test_non_finite_loss_is_steered_away():
    def objective(x, d, grad):
        return torch.tensor(math.nan), torch.full_like(x, math.nan), {}

    ev = Evaluator(objective, 2)
    loss, g = ev(torch.zeros(3), {})
    assert loss == 1e6 and torch.equal(g, torch.zeros(3, dtype=torch.float64))


def test_settings_validation():
    for bad, msg in [(dict(budget=0), "budget: expected an integer >= 1, got 0"),
                     (dict(discrete="random"), "discrete search"),
                     (dict(camera="maybe"), "camera"), (dict(loss="l7"), "loss"), (dict(local="sgd"), "local"),
                     (dict(lr=0.0), r"lr: expected a learning rate in \(0, 1\]")]:
        with pytest.raises(ValueError, match=msg):
            FitSettings(**bad).check()
    with pytest.raises(ValueError, match=r"memetic settings: unknown setting\(s\) popsize"):
        FitSettings(search={"memetic": {"popsize": 4}})


def test_nested_settings_from_dicts_and_the_learning_rate():
    from ipm.optim.fit import MESH_LR, MaskTarget, fit_lr
    from ipm.optim.strategies.memetic import MemeticSettings

    s = FitSettings(search={"memetic": {"lr": 0.01, "population": 4}, "nlopt": {"algorithm": "GN_ESCH"}})
    assert s.strategy("memetic") == MemeticSettings(lr=0.01, population=4)
    assert s.strategy("nlopt").algorithm == "GN_ESCH" and s.strategy("enumerate") is None
    assert FitSettings().strategy() == MemeticSettings()  # the default strategy's defaults
    dishes, building = get_generator("dishes"), get_generator("building")
    from ipm.render.camera import input_views

    masks = MaskTarget(torch.eye(8)[None], [c.to(torch.float32) for c in input_views(1, 8)])
    assert fit_lr(dishes, masks, FitSettings()) == dishes.mask_lr == 0.005
    assert fit_lr(building, masks, FitSettings()) == 0.02
    assert fit_lr(dishes, masks, FitSettings(lr=0.03)) == 0.03
    import trimesh

    ball = trimesh.creation.icosphere(1)
    mesh = MeshTarget(TriMesh(torch.as_tensor(ball.vertices), torch.as_tensor(ball.faces)))
    assert fit_lr(dishes, mesh, FitSettings()) == MESH_LR


def test_enumerate_refuses_too_many_combinations():
    from ipm.optim.discrete import Space
    from ipm.optim.strategies.enumeration import enumerate_discrete
    from ipm.params import Param

    space = Space(2, np.arange(2), [Param("a", 0, 0, 9, "int"), Param("b", 0, 0, 9, "int")],
                  [(torch.zeros(2, dtype=torch.float64), {"a": 0, "b": 0})])
    ev = Evaluator(lambda x, d, g: (x.sum(), torch.ones_like(x), {}), 10)
    with pytest.raises(ValueError, match="100 combinations"):
        enumerate_discrete(ev, space, lambda x, d, s: (x, 0.0), np.random.default_rng(0))


def test_pose_starts_spread_over_tied_yaws():
    from ipm.optim.fit import spread_starts, yaw_free

    yaws = [0.0, 45.0, 90.0, 135.0, 180.0, 225.0, 270.0, 315.0]
    tied = [(0.2, i, y, None) for i, y in enumerate(yaws)]  # a body of revolution: every yaw alike
    kept = spread_starts(tied, keep=4)
    assert [e[2] for e in kept][:4] == [0.0, 180.0, 90.0, 270.0] and len(kept) == 8  # all ties kept
    assert yaw_free(kept)
    graded = [(0.1 + 0.01 * i, i, y, None) for i, y in enumerate(yaws)][::-1]  # the yaw matters
    kept = spread_starts(graded, keep=4)
    assert [e[0] for e in kept] == sorted(e[0] for e in graded)[:4] and not yaw_free(kept)
    pair = [(0.1, 0, 0.0, None), (0.1, 1, 180.0, None), (0.3, 2, 90.0, None)]  # front and back alike
    assert not yaw_free(spread_starts(pair, keep=4))
