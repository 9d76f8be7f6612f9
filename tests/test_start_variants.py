"""Start variants (:attr:`ipm.generators.base.Generator.start_variants`): shapes a generator's presets leave
out but any preset may take, added by :func:`ipm.optim.pose.preset_starts` to the starts of the pose and
discrete search, made of the fit's starting preset and under its fixed values."""

from __future__ import annotations

import json

import pytest
import torch

from ipm.generators import get_generator
from ipm.optim.fit import FitSettings, MaskTarget, Problem, preset_starts
from ipm.render.camera import orbit_camera

SECTION = ("section_squareness", "section_aspect")


def _starts(gen_name: str, **settings) -> tuple[Problem, torch.Tensor, list[tuple[torch.Tensor, dict]]]:
    """The problem, the posed start ``x`` and the named values of every preset start of a fit to a box's view."""
    gen = get_generator(gen_name)
    cam = orbit_camera(30.0, 20.0, 3.2, fov_deg=40.0, width=32)
    mask = torch.zeros(1, 32, 32)
    mask[:, 8:24, 10:22] = 1.0
    prob = Problem(gen, MaskTarget(mask, [cam]), FitSettings(**settings), dtype=torch.float64)
    x = prob.x0(yaw=25.0, scale=1.1, t=(0.1, 0.0, -0.05))
    return prob, x, [(xs, prob.values(xs, d)) for xs, d in preset_starts(prob, x)]


def _same(a: dict, b: dict, but=()) -> bool:
    return all(abs(float(a[k]) - float(b[k])) < 1e-6 for k in a if k not in but)


def test_dishes_starts_add_a_square_and_a_flat_section_of_the_starting_preset():
    """After the other presets, the starting preset twice more: square (squareness 0.7) and flat (aspect 0.6,
    squareness 0.3), every other value the preset's, posed like the start."""
    gen = get_generator("dishes")
    prob, x, starts = _starts("dishes", preset="plate")
    others = [n for n in sorted(gen.presets) if n != "plate"]
    assert len(starts) == len(others) + len(gen.start_variants) == len(others) + 2
    for (_, vals), name in zip(starts, others):
        assert _same(vals, gen.values(name))
    plate = gen.values("plate")
    for (xs, vals), (sq, asp) in zip(starts[len(others):], ((0.7, 1.0), (0.3, 0.6))):
        assert (vals["section_squareness"], vals["section_aspect"]) == pytest.approx((sq, asp))
        assert _same(vals, plate, but=SECTION)
        torch.testing.assert_close(xs[prob.n:], x[prob.n:])   # the pose of the start


def test_the_fits_fixed_values_win_over_a_variant():
    """A fixed squareness stays in every variant; with both section values fixed the variants are the preset
    itself and are left out."""
    gen = get_generator("dishes")
    _, _, starts = _starts("dishes", preset="mug", fix={"section_squareness": 0.2})
    variants = [v for _, v in starts[len(gen.presets) - 1:]]
    got = [v[name] for v in variants for name in SECTION]
    assert got == pytest.approx([0.2, 1.0, 0.2, 0.6])
    _, _, both = _starts("dishes", preset="mug", fix={"section_squareness": 0.2, "section_aspect": 0.9})
    assert len(both) == len(gen.presets) - 1


def test_without_a_preset_the_variants_are_of_the_defaults():
    gen = get_generator("dishes")
    _, _, starts = _starts("dishes")
    defaults = gen.values(None)
    variants = [v for _, v in starts[len(gen.presets):]]
    assert len(variants) == 2 and all(_same(v, defaults, but=SECTION) for v in variants)


def test_generators_without_variants_start_from_their_presets_only():
    gen = get_generator("building")
    assert gen.start_variants == ()
    _, _, starts = _starts("building", preset="house2")
    assert len(starts) == len(gen.presets) - 1


def _sample_views(preset: str, overrides: dict, size: int = 64) -> MaskTarget:
    """Two of the protocol's views (azimuths 30 and 120 degrees, elevation 25) of a dishes sample in its unit
    bounding sphere."""
    from ipm.metrics import unit_sphere_frame
    from ipm.render.raster import rasterize_mesh
    from ipm.types import TriMesh

    gen = get_generator("dishes")
    mesh = gen.to_mesh(gen.values(preset, overrides))
    center, scale = unit_sphere_frame(mesh.verts.double().numpy())
    mesh = TriMesh((mesh.verts.double() - torch.as_tensor(center)) * scale, mesh.faces)
    cams = [orbit_camera(a, 25.0, 3.2, fov_deg=40.0, width=size) for a in (30.0, 120.0)]
    return MaskTarget(torch.stack([rasterize_mesh(mesh, c).mask.float() for c in cams]),
                      [c.to(torch.float32) for c in cams])


@pytest.mark.parametrize("preset, section, name, reached", [
    ("bowl", {"section_squareness": 0.9, "section_aspect": 1.0}, "section_squareness", lambda v: v > 0.5),
    ("bottle", {"section_squareness": 0.3, "section_aspect": 0.6}, "section_aspect", lambda v: v < 0.8)])
def test_a_fit_from_round_presets_reaches_a_square_or_flat_section(preset, section, name, reached):
    """Two views of a square bowl and of a flat bottle, fitted from their round preset (150 evaluations, 64 px):
    with the variants the fit ends square (flat) at well under half the loss; without them (the same generator with
    ``start_variants`` emptied) it stays round. Measured: squareness 0.72 against 0.03 (loss 0.058 against 0.143),
    aspect 0.59 against 0.97 (0.048 against 0.119)."""
    from ipm.optim.fit import run_fit

    target = _sample_views(preset, section)
    ends = {}
    for variants in (True, False):
        gen = get_generator("dishes")
        if not variants:
            gen.start_variants = ()
        res, prob, best = run_fit(gen, target, FitSettings(preset=preset, budget=150))
        ends[variants] = (res.loss, prob.values(best["x"], best["discrete"])[name])
    assert reached(ends[True][1]) and not reached(ends[False][1]), ends
    assert ends[True][0] < 0.5 * ends[False][0], ends


# -- SDF trees: variants declared in the tree file; with nothing discrete the multistart refines them ------------------

def _tree_file(tmp_path, variants) -> str:
    path = tmp_path / "stool.json"
    path.write_text(json.dumps({"tree": {"node": "chair", "name": "chair"}, "start_variants": variants}))
    return str(path)


def test_a_tree_file_declares_its_start_variants(tmp_path):
    """``"start_variants"`` beside the tree: read from a file as from a shipped preset (the chair's backless one)."""
    from ipm.generators.sdftree import SdfTreeGenerator

    gen = get_generator(_tree_file(tmp_path, [{"chair.back_height": 0.05, "chair.seat_height": 0.6}]))
    assert gen.start_variants == ({"chair.back_height": 0.05, "chair.seat_height": 0.6},)
    assert SdfTreeGenerator.from_preset("chair").start_variants == ({"chair.back_height": 0.05},)
    assert SdfTreeGenerator.from_preset("csg").start_variants == ()


@pytest.mark.parametrize("variants, says", [
    ([{"chair.armrest": 0.1}], "unknown parameter 'chair.armrest'"),
    ([{"chair.back_height": 9.0}], "chair.back_height"),
    ({"chair.back_height": 0.05}, "expected a list of non-empty objects"),
    ([{}], "expected a list of non-empty objects")])
def test_a_tree_files_bad_start_variants_are_refused_naming_the_file(tmp_path, variants, says):
    from ipm.errors import InputError

    path = _tree_file(tmp_path, variants)
    with pytest.raises(InputError) as e:
        get_generator(path)
    assert path in str(e.value) and "start_variants" in str(e.value) and says in str(e.value)
    assert "\n" not in str(e.value)


def _stool_view(size: int = 64) -> MaskTarget:
    """One view (azimuth 30, elevation 25) of the chair tree with no back: a stool."""
    from ipm.render.raster import rasterize_mesh

    gen = get_generator("chair")
    vals = {"chair.back_height": 0.05, "chair.seat_width": 0.6, "chair.seat_depth": 0.6, "chair.seat_height": 0.8,
            "chair.leg_thickness": 0.1}
    mesh = gen.to_mesh(gen.values(None, vals), resolution=64)
    verts = mesh.verts.double()
    center = (verts.min(0).values + verts.max(0).values) / 2
    from ipm.types import TriMesh

    mesh = TriMesh((verts - center) / float((verts - center).norm(dim=1).max()), mesh.faces)
    cam = orbit_camera(30.0, 25.0, 3.2, fov_deg=40.0, width=size)
    return MaskTarget(rasterize_mesh(mesh, cam).mask.float()[None], [cam.to(torch.float32)])


def test_a_fit_with_nothing_discrete_refines_the_variants_too():
    """A stool seen from one view, fitted by the chair tree from its defaults (a chair with a back; 200 evaluations,
    64 px): with the backless variant the back stays low and the loss ends far lower; without it (the generator's
    ``start_variants`` emptied) the back stands in for the seat."""
    from ipm.optim.fit import run_fit

    target = _stool_view()
    ends = {}
    for variants in (True, False):
        gen = get_generator("chair")
        if not variants:
            gen.start_variants = ()
        res, prob, best = run_fit(gen, target, FitSettings(budget=200, seed=0))
        ends[variants] = (res.loss, prob.values(best["x"], best["discrete"])["chair.back_height"])
    assert ends[True][1] < 0.2 < ends[False][1], ends
    assert ends[True][0] < 0.6 * ends[False][0], ends


def test_a_small_budget_leaves_the_variants_out():
    """Their pose grids (16 evaluations each) may take at most a tenth of the budget (``pose.VARIANT_SHARE``): at
    150 evaluations the chair's one variant is left out, and the fit is the one without variants, evaluation for
    evaluation."""
    from ipm.optim.fit import run_fit

    target = _stool_view()
    runs = []
    for variants in (True, False):
        gen = get_generator("chair")
        if not variants:
            gen.start_variants = ()
        records: list[dict] = []
        res, _, _ = run_fit(gen, target, FitSettings(budget=150, seed=0), sink=records.append)
        runs.append((res.loss, [r["phase"] for r in records]))
    assert runs[0] == runs[1]
    assert "init:variants" not in runs[0][1]
