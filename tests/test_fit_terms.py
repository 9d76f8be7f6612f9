"""Each loss term of the fit alone (:mod:`ipm.optim.terms`): its value where it is known, its gradient against
float64 central differences, and the objective as the sum of the terms a phase keeps, in their order."""

from __future__ import annotations

import pytest
import torch

from ipm.generators import get_generator
from ipm.optim.phases import OUTLINE, SEARCH
from ipm.optim.problem import Problem
from ipm.optim.settings import FitSettings
from ipm.optim.targets import MaskTarget, MeshTarget
from ipm.optim.terms import TERMS, Evaluation
from ipm.render import deferred as R
from ipm.render.camera import orbit_camera
from ipm.render.raster import rasterize_mesh, view_maps

SIZE = 40
LIGHT = torch.tensor([0.4, 0.8, 0.45], dtype=torch.float64)


@pytest.fixture(autouse=True)
def exact_soft_silhouettes(monkeypatch):
    """Soft silhouettes without the renderer's skipping of pairs below 1e-6 (a step of a central difference
    can cross that cut), so that their gradients are compared with the function they are the gradient of."""
    import functools

    from ipm.render import soft

    exact = functools.partial(soft.soft_silhouette, eps=1e-12)
    monkeypatch.setattr(soft, "soft_silhouette", exact)


def _blob(k: int) -> torch.Tensor:
    """``k`` masks with a square in the middle: a probe target whose problem gives the posed start's mesh."""
    m = torch.zeros(k, SIZE, SIZE, dtype=torch.float64)
    m[:, SIZE // 4: 3 * SIZE // 4, SIZE // 4: 3 * SIZE // 4] = 1
    return m


def _term(prob: Problem, name: str):
    found = [t for t in prob.terms if t.name == name]
    assert found, f"term {name} does not apply; active: {[t.name for t in prob.terms]}"
    return found[0]


def _value(prob: Problem, name: str, x: torch.Tensor, need_grad: bool = False):
    """The term's value at ``x`` (and the evaluation, for its records)."""
    x = x.detach().clone().requires_grad_(need_grad)
    ev = Evaluation(prob, x, {}, SEARCH, need_grad)
    return _term(prob, name)(ev), ev, x


def _check_gradient(prob: Problem, name: str, x: torch.Tensor, coords: list[int]):
    """The term's autograd gradient along ``coords`` against float64 central differences, of steps 1e-6 and
    1e-7: terms that see the exact raster (which faces are visible) jump where a step crosses a pixel's
    edge, so the closer of the two must agree."""
    value, _, xg = _value(prob, name, x, need_grad=True)
    (g,) = torch.autograd.grad(value, xg, allow_unused=True)
    g = torch.zeros_like(x) if g is None else g
    for i in coords:
        fds = []
        for eps in (1e-6, 1e-7):
            e = torch.zeros_like(x)
            e[i] = eps
            fds.append((float(_value(prob, name, x + e)[0]) - float(_value(prob, name, x - e)[0])) / (2 * eps))
        fd = min(fds, key=lambda v: abs(v - float(g[i])))
        assert float(g[i]) == pytest.approx(fd, rel=1e-4, abs=1e-7), (name, i, fds)


@pytest.fixture(scope="module")
def mug():
    """The dishes mug seen from two views at 40 px: its exact masks, depth, part labels of every part and a
    Lambert image under :data:`LIGHT`, rendered from the problem's own posed mesh at the start; the problem
    over them in float64 (prior, part cost and the crop's outside term on)."""
    gen = get_generator("dishes")
    cams = [orbit_camera(az, 20.0, 3.2, width=SIZE) for az in (30.0, 150.0)]
    cams = [c.to(torch.float64) for c in cams]
    blank = MaskTarget(_blob(2), cams)
    probe = Problem(gen, blank, FitSettings(preset="mug"), dtype=torch.float64)
    mesh = probe.mesh_world(probe.x0(), probe.d0, pose_grad=False)
    maps = [view_maps(rasterize_mesh(mesh, c), mesh) for c in cams]
    masks = torch.stack([m["mask"] for m in maps]).double()
    depth = torch.stack([m["depth"] for m in maps]).double()
    parts = torch.stack([m["groups"] for m in maps])
    image = []
    for c in cams:
        rast = R.rasterize(mesh.verts, mesh.faces, c)
        n = R.vertex_normal_image(mesh.verts, mesh.faces, rast)
        image.append(torch.where(rast.mask, 0.2 + 0.7 * (n @ LIGHT).clamp_min(0), torch.zeros(())))
    target = MaskTarget(masks, cams, depth=depth, parts=parts, part_names=tuple(mesh.group_names),
                        image=torch.stack(image).double(), outside_is_background=True)
    settings = FitSettings(preset="mug", prior_weight=0.5, part_cost=0.01)
    return Problem(gen, target, settings, dtype=torch.float64)


def test_every_cue_term_applies_to_a_target_with_every_cue(mug):
    names = [t.name for t in mug.terms]
    assert names == sorted(names, key=lambda n: (TERMS[n].order, n))
    assert set(names) == {"silhouette", "outside", "depth", "parts", "shading", "prior", "part_cost"}


def test_each_term_is_at_its_floor_on_the_shape_that_made_the_target(mug):
    x0 = mug.x0()
    sil, ev, _ = _value(mug, "silhouette", x0)
    hard, want = (ev.silhouettes > 0.5).numpy(), (mug.target.masks > 0.5).numpy()
    for k in range(2):  # the records count the soft silhouettes' pixels over 0.5
        inter, union = int((hard[k] & want[k]).sum()), int((hard[k] | want[k]).sum())
        assert ev.extras["iou_px"][k] == [inter, union]
        assert ev.extras["iou"][k] == pytest.approx(inter / union, abs=1e-5)
    depth, ev, _ = _value(mug, "depth", x0)
    assert float(depth) == pytest.approx(0.0, abs=1e-9)
    assert ev.extras["depth_px"] == [int(m.sum()) for m in mug.target.masks]
    shading, ev, _ = _value(mug, "shading", x0)
    assert float(shading) == pytest.approx(0.0, abs=1e-9)
    assert float(_value(mug, "outside", x0)[0]) == 0.0
    assert float(_value(mug, "prior", x0)[0]) == pytest.approx(0.0, abs=1e-12)
    # moved off the target, each one grows
    moved = x0.clone()
    moved[mug.layout.pose.start] += 0.15  # translation x
    for name in ("silhouette", "depth", "parts"):
        assert float(_value(mug, name, moved)[0]) > float(_value(mug, name, x0)[0]) + 1e-3, name
    far = x0.clone()
    far[mug.layout.pose.start] += 3.0  # out of both images
    assert float(_value(mug, "outside", far)[0]) > 0.1
    shaped = x0.clone()
    shaped[0] += 0.1
    assert float(_value(mug, "prior", shaped)[0]) > 0


def test_the_part_cost_charges_each_part_the_discrete_values_add(mug):
    adds = [p.name for p in mug.gen.spec.discrete if p.adds]
    assert adds
    value = _value(mug, "part_cost", mug.x0())[0]
    assert value == pytest.approx(0.01 * sum(mug.d0[n] for n in adds))
    ev = Evaluation(mug, mug.x0(), {n: 0 for n in adds}, SEARCH, False)
    assert _term(mug, "part_cost")(ev) == 0.0


@pytest.mark.parametrize("name", ["silhouette", "depth", "shading", "prior", "outside"])
def test_term_gradient_matches_finite_differences_in_shape_and_pose(mug, name):
    x = mug.x0().clone()
    x[: mug.n] += 0.03 * torch.linspace(-1, 1, mug.n, dtype=x.dtype)
    if name == "outside":
        x[mug.layout.pose.start] += 1.1  # partly out of the images
    pose = list(range(mug.layout.pose.start, mug.layout.pose.stop))
    _check_gradient(mug, name, x, [0, mug.n // 2, mug.n - 1] + pose[:2])


def test_parts_gradient_matches_finite_differences_in_shape_and_holds_the_pose(mug):
    """Part labels move the shape only: their pose gradient is zero by construction."""
    x = mug.x0().clone()
    x[: mug.n] += 0.03 * torch.linspace(-1, 1, mug.n, dtype=x.dtype)
    _check_gradient(mug, "parts", x, [0, mug.n // 2, mug.n - 1])
    value, _, xg = _value(mug, "parts", x, need_grad=True)
    (g,) = torch.autograd.grad(value, xg)
    assert float(g[mug.layout.pose].abs().max()) == 0.0


def test_the_objective_is_the_sum_of_the_terms_its_phase_keeps(mug):
    x = mug.x0().clone()
    x[: mug.n] += 0.02
    each = {t.name: float(_value(mug, t.name, x)[0]) for t in mug.terms}
    loss, _, extras = mug.objective(x, {}, False, SEARCH)
    assert float(loss) == pytest.approx(sum(each.values()), rel=1e-12)
    assert {"iou", "depth_px", "parts_px", "light"} <= set(extras)
    outline, _, extras = mug.objective(x, {}, False, OUTLINE)
    assert float(outline) == pytest.approx(sum(v for k, v in each.items() if k != "parts"), rel=1e-12)
    assert "parts_px" not in extras


def test_anchor_charges_anchored_parameters_of_a_single_view_without_depth():
    gen = get_generator("dishes")
    cam = orbit_camera(30.0, 20.0, 3.2, width=SIZE).to(torch.float64)
    blank = MaskTarget(_blob(1), [cam])
    prob = Problem(gen, blank, FitSettings(preset="mug", anchor=0.3), dtype=torch.float64)
    assert prob.anchored, "dishes declares anchored parameters (Param.anchored)"
    x0 = prob.x0()
    assert float(_value(prob, "anchor", x0)[0]) == pytest.approx(0.0, abs=1e-12)
    moved = x0.clone()
    moved[prob.anchored[0]] += 0.2
    moved[[i for i in range(prob.n) if i not in prob.anchored][0]] += 0.2  # not anchored: free
    assert float(_value(prob, "anchor", moved)[0]) == pytest.approx(0.3 * 0.2, rel=1e-9)


def test_surface_term_is_least_on_its_own_mesh_and_its_gradient_matches():
    gen = get_generator("dishes")
    probe_target = MeshTarget(gen.to_mesh(gen.values("mug")), samples=500)
    probe = Problem(gen, probe_target, FitSettings(preset="mug"), dtype=torch.float64)
    own = probe.mesh_world(probe.x0(), probe.d0, pose_grad=False)
    prob = Problem(gen, MeshTarget(own, samples=500), FitSettings(preset="mug"), dtype=torch.float64)
    x0 = prob.x0()
    at = float(_value(prob, "surface", x0)[0])
    moved = x0.clone()
    moved[0] += 0.1
    assert at < float(_value(prob, "surface", moved)[0])
    _check_gradient(prob, "surface", moved, [0, prob.n - 1, prob.layout.pose.start])


@pytest.mark.parametrize("budget", [1, 17, 30])
def test_a_budget_the_pose_grid_nearly_uses_up_still_judges_the_result_on_the_full_objective(mug, budget):
    """With depth and part labels the outline (a phase of another objective) comes first; it takes at most all
    but one of the evaluations left, so the result's loss is a recorded loss of the fit's own objective."""
    from ipm.optim.fit import run_fit

    records = []
    settings = FitSettings(preset="mug", budget=budget, discrete="memetic", seed=0)
    res, prob, best = run_fit(mug.gen, mug.target, settings, sink=records.append)
    assert res.evaluations == budget == len(records)
    assert res.loss == pytest.approx(min(r["loss"] for r in records if r["phase"] != "outline"))


def test_json_output_is_strict_json_with_null_for_numbers_that_are_not_finite(capsys):
    import json

    from ipm.cli.common import emit

    emit({"loss": float("inf"), "scores": [1.0, float("nan")], "n": 3}, True)
    out = capsys.readouterr().out
    assert json.loads(out, parse_constant=lambda c: pytest.fail(f"non-standard JSON constant {c}")) == {
        "loss": None, "scores": [1.0, None], "n": 3}
