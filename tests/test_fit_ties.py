"""The fit's tie rule (issue #11, item 2): discrete values that no input view can tell apart go back to
the preset's (:func:`ipm.optim.fit.break_ties`).

The target of the fits is the dishes ``mug`` (handle towards +X) seen by one camera on the -X axis at
the height of the mug's center, so that the body hides the handle. :func:`part_difference` is the
measurement behind :data:`ipm.optim.fit.TIE_SHARE`. From views that hide the handle (elevation 0° at
azimuth 270°, 10° at 240° and 255°, 25° at 90° and 270°) at 64, 96 and 256 px, the handle moved no
pixel of the exact silhouettes nor of the soft ones thresholded at 0.5, at the search's blur (1 px²)
or the polish's (0.03 px²), while the soft-IoU loss without the handle was higher by

    size  elevation  blur 1 px^2            blur 0.03 px^2
    64    0          -4e-9  (0.00 px)       2.8e-5 (0.04 px)
    64    25         2.1e-7 (0.00 px)       3.2e-4 (0.46 px, 1.2 % of the loss)
    96    25         1.6e-5 (0.05 px)       6.9e-5 (0.23 px)
    256   0          5.2e-5 (1.2 px)        4.1e-7 (0.01 px)
    256   25         4.5e-4 (10 px, 1.2 %)  6.2e-5 (1.4 px)

(in parentheses: times the target's area, the number of pixels the difference is worth). Inside a
soft silhouette the values are not quite 1 (down to 0.94), and a hidden part's extra layers fill them.
The building's back windows lie inside its outline from every view and leave the exact silhouettes
alone too, but re-triangulate the walls: the soft silhouettes thresholded at 0.5 move by up to 3 px at
256 px at the polish's blur (0.024 % of the target's pixels) and up to 38 px at the search's.
"""

from __future__ import annotations

import pytest
import torch

from ipm import losses as L
from ipm.generators import get_generator
from ipm.metrics import unit_sphere_frame
from ipm.optim.evaluator import Evaluator
from ipm.optim.fit import TIE_SHARE, FitSettings, MaskTarget, Problem, break_ties, hard_scores, run_fit
from ipm.optim.strategies.memetic import MemeticSettings
from ipm.render.camera import orbit_camera
from ipm.render.raster import rasterize_mesh
from ipm.render.soft import soft_silhouette
from ipm.types import TriMesh

SIZE = 64
HIDDEN = 270.0   # camera azimuth on the -X axis: the body hides the handle
VISIBLE = 0.0    # on the +Z axis: the handle shows in profile


def variants(gen: str, preset: str, name: str, values=(1, 0)) -> list[TriMesh]:
    """A preset with discrete parameter ``name`` at each of ``values``, all in the unit-sphere frame of
    the first (the object is the same, only a part differs)."""
    g = get_generator(gen)
    meshes = [g.to_mesh(g.values(preset, {name: v})) for v in values]
    center, scale = unit_sphere_frame(meshes[0].verts.double().numpy())
    return [TriMesh((m.verts.double() - torch.as_tensor(center)) * scale, m.faces) for m in meshes]


def view(azimuth: float, size: int = SIZE, elevation: float = 0.0):
    return orbit_camera(azimuth, elevation, 3.2, fov_deg=40.0, width=size)


def part_difference(meshes: list[TriMesh], cam, sigma: float) -> dict:
    """How much a part changes one view, ``meshes`` = [with, without]: pixels apart of the exact
    silhouettes and of the soft ones thresholded at 0.5, and the soft-IoU losses of both against the
    exact silhouette of the first."""
    target = rasterize_mesh(meshes[0], cam).mask
    exact = int((rasterize_mesh(meshes[1], cam).mask != target).sum())
    soft = [soft_silhouette(m.verts, m.faces, cam, sigma=sigma) for m in meshes]
    losses = [float(L.soft_iou_loss(s, target.double())) for s in soft]
    return {"exact_px": exact, "soft_px": int(((soft[0] > 0.5) != (soft[1] > 0.5)).sum()),
            "loss_with": losses[0], "loss_without": losses[1], "area": int(target.sum())}


def mug_target(azimuth: float) -> MaskTarget:
    cam = view(azimuth)
    mug = variants("dishes", "mug", "has_handle")[0]
    return MaskTarget(rasterize_mesh(mug, cam).mask.float()[None], [cam.to(torch.float32)])


@pytest.mark.parametrize("sigma", [1.0, 0.03])
def test_the_view_hides_the_handle(sigma):
    """A real tie: the silhouettes with and without the handle are the same pixels, exact or soft; only
    the soft loss tells them apart, by less than a pixel's worth here."""
    mugs = variants("dishes", "mug", "has_handle")
    d = part_difference(mugs, view(HIDDEN), sigma)
    assert d["exact_px"] == 0 and d["soft_px"] == 0, d
    assert abs(d["loss_without"] - d["loss_with"]) * d["area"] < 0.5, d
    shown = part_difference(mugs, view(VISIBLE), sigma)
    assert shown["exact_px"] > 20 and shown["soft_px"] > 20, shown


def test_a_hidden_part_that_retriangulates_stays_within_the_tolerance():
    """The building's back windows, inside its outline, seen at 256 px from the side they are on: the
    exact silhouettes are the same, and the soft ones at the polish's blur move, by less than
    ``TIE_SHARE`` of the target's pixels."""
    buildings = variants("building", "panel5", "back_windows")
    d = part_difference(buildings, view(180.0, 256, 10.0), 0.03)
    assert d["exact_px"] == 0 and 0 < d["soft_px"] <= TIE_SHARE * d["area"], d


def test_repose_keeps_the_shape_in_place():
    """The canonical frame depends on the discrete values (the handle makes the mug wider): re-encoded
    for the other value, the body stays where it was, vertex for vertex."""
    gen = get_generator("dishes")
    prob = Problem(gen, mug_target(HIDDEN), FitSettings(preset="mug"))
    x = prob.x0(yaw=40.0, scale=1.3, t=(0.1, -0.2, 0.05))
    with_ = prob.mesh_world(x, {"has_handle": 1}).verts
    without = prob.mesh_world(prob.repose(x, {"has_handle": 1}, {"has_handle": 0}), {"has_handle": 0}).verts
    assert not torch.allclose(prob.mesh_world(x, {"has_handle": 0}).verts, without)
    torch.testing.assert_close(without, with_[: len(without)], atol=1e-5, rtol=0)


@pytest.mark.parametrize("azimuth, tie", [(HIDDEN, True), (VISIBLE, False)])
def test_the_rule_sets_back_only_what_no_view_shows(azimuth, tie):
    """A fit started from the glass (no handle) whose winner has the mug's handle: the handle goes back
    to the preset's "none" when the view hides it, and stays when the view shows it."""
    gen = get_generator("dishes")
    prob = Problem(gen, mug_target(azimuth), FitSettings(preset="glass", discrete="enumerate"))
    theta, _ = gen.split(gen.values("mug"), torch.float64)
    ev = Evaluator(prob.objective, 2)
    ev(prob.x0(theta=theta), {"has_handle": 1}, grad=False)
    _, d, loss, tied = break_ties(prob, ev, ev.best)
    assert ev.count == 2 and torch.isfinite(torch.tensor(loss))
    assert (d["has_handle"], tied) == ((0, ("has_handle",)) if tie else (1, ()))


@pytest.mark.slow
@pytest.mark.parametrize("strategy", ["enumerate", "memetic"])
@pytest.mark.parametrize("preset, handle", [("mug", 1), ("glass", 0)])
def test_a_hidden_handle_keeps_the_presets_value(preset, handle, strategy):
    """Fits of the mug seen from behind its handle keep the preset's ``has_handle``: the mug's handle
    from the mug, none from the glass. Without the rule, every glass fit measured (enumerate and memetic,
    seeds 0-2, budgets 200 and 300) switched the handle on: at equal continuous values its layers lower
    the soft loss (by 0.5 % to 4.4 % in those fits), and the candidates with it got more of the search."""
    target = mug_target(HIDDEN)
    settings = FitSettings(budget=200, seed=0, preset=preset, discrete=strategy,
                           search={"memetic": MemeticSettings(population=4, refine_steps=10)})
    res, prob, best = run_fit(get_generator("dishes"), target, settings)
    assert best["discrete"]["has_handle"] == handle, (res.loss, res.tied)
    # what the rule set back: discrete values that no view shows, and hidden parts' own parameters
    assert res.params["has_handle"] == handle
    assert set(res.tied) <= {"has_handle", "has_spout", "has_knob", "handle", "spout", "knob"}, res.tied
    assert res.evaluations == 200
    assert hard_scores(prob, best)["iou_mean"] >= 0.9


def test_a_parts_own_parameters_are_those_that_shape_it_alone():
    """The handle's own parameters move the handle and nothing else; its azimuth and its depth in the wall
    move every vertex of it (they place it) and stay fitted; a part the shape lacks owns nothing."""
    from ipm.optim.ties import owned_parameters

    gen = get_generator("dishes")
    names = [p.name for p in gen.spec.continuous]
    for preset in ("mug", "teapot"):
        prob = Problem(gen, mug_target(HIDDEN), FitSettings(preset=preset))
        own = {part: {names[prob.layout.free[j]] for j in cols}
               for part, cols in owned_parameters(prob, prob.x0(), dict(prob.d0)).items()}
        handle = {n for n in names if n.startswith("handle_")} - {"handle_azimuth", "handle_embed"}
        assert own["handle"] == handle, preset
        if preset == "teapot":  # the spout's root height moves all of it, as the knob's height and sink do
            assert own["spout"] == {"spout_rise", "spout_reach", "spout_root", "spout_tip", "spout_bend"}
            assert own["knob"] == {"knob_radius"}
        else:
            assert set(own) == {"handle"}


@pytest.mark.parametrize("azimuth, tie", [(HIDDEN, True), (VISIBLE, False)])
def test_a_hidden_parts_shape_goes_back_to_the_presets(azimuth, tie):
    """A mug fit whose winner's handle stands out farther and is thicker than the preset's, turned by 10
    degrees: where the view hides the handle its own parameters go back to the preset's and its azimuth stays;
    where the view shows it nothing changes."""
    gen = get_generator("dishes")
    prob = Problem(gen, mug_target(azimuth), FitSettings(preset="mug"))
    values = gen.values("mug", {"handle_reach": 0.45, "handle_width": 0.1, "handle_lift_3": 0.2,
                                "handle_azimuth": 10.0})
    theta, d = gen.split(values, torch.float64)
    ev = Evaluator(prob.objective, 2)
    x = prob.x0(theta=theta)
    ev(x, d, grad=False)
    xt, dt, loss, tied = break_ties(prob, ev, ev.best)
    assert ev.count == 2 and dt == d and torch.isfinite(torch.tensor(loss))
    names = [p.name for p in gen.spec.continuous]
    at = {n: j for j, n in enumerate(names[i] for i in prob.layout.free)}
    x0 = prob.x0()
    if tie:
        assert tied == ("handle",)
        for n in ("handle_reach", "handle_width", "handle_lift_3"):
            assert float(xt[at[n]]) == pytest.approx(float(x0[at[n]]), abs=1e-12), n
        assert float(xt[at["handle_azimuth"]]) == float(x[at["handle_azimuth"]])
        rest = [j for n, j in at.items() if not n.startswith("handle_")]
        assert torch.equal(xt[rest], x[rest]) and torch.equal(xt[prob.n:], x[prob.n:])
    else:
        assert tied == () and torch.equal(xt, x)
