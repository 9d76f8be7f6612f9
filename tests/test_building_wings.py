"""Building wings, roof-top boxes and mansard roofs: the old meshes unchanged at the default switches,
L/T/U and side-wing footprints where the docstring puts them, closed parts and the documented box for
any parameters (property tests), counts from the discrete values alone, and Jacobians with respect to
every new size equal to float64 central differences."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from test_building import GEN, build, check_building, components, parts

from ipm.generators._roofs import ROOF_VERTS
from ipm.generators.building import GROUPS, MAX_ROOF_BOXES, MAX_WINGS
from ipm.jacobian import check_mesh_jacobian, mesh_jacobian
from ipm.params import load_param_file, param_file_json
from tests.test_meshgen_common import slow_path_hits

# The generator before wings (commit b86de4d): its 21 continuous parameters in their order, and per
# case (vertices, sha256 of faces and groups, sum of the vertices' coordinates weighted by random
# signs times uniform [1, 2] (seed 0), sum of squares), computed from the meshes that code made.
# Cases: the four presets, and eight random vectors (old_values) over the old parameters.
OLD_CONTINUOUS = ("floor_height", "section_width", "depth", "wall_thickness", "plinth_height", "window_width",
                  "window_height", "window_sill", "window_inset", "frame_width", "frame_depth", "balcony_width",
                  "balcony_depth", "balcony_height", "balcony_thickness", "door_width", "door_height",
                  "door_depth", "roof_height", "roof_overhang", "roof_ridge")
OLD_MESHES = {
    "house2": (494, "66047a9a77bb9d57", 118.93106509294583, 20793.9192),
    "panel5": (4840, "ce39d49c82ca31ab", -1398.1026277100445, 2351159.3219999997),
    "panel9": (7552, "b62e9f47b145a37a", 802.9899873076336, 4133213.9814999998),
    "tower": (4014, "1795620a44fd5b7e", 3210.0465259531775, 3707461.6129000005),
    "random0": (78, "5bd3d00b405f079b", -25.786798722672316, 4480.231279969697),
    "random1": (436, "f256cb438900b94f", -543.1257897619676, 90692.38674114109),
    "random2": (1862, "b346f781b8bf388e", -519.2005403156911, 477331.0964326457),
    "random3": (1148, "8ec3f016bfc3b406", 760.128077028804, 233562.61823413175),
    "random4": (1528, "c012a612e6bf0dd8", -1139.8377099394345, 1039576.0005455281),
    "random5": (388, "f99b747354d5af1f", -942.2246969760785, 446263.27404366655),
    "random6": (646, "cb423e74ac694611", -922.3368987253725, 193811.57162319781),
    "random7": (408, "a5feace880f708b4", -1739.2872158689522, 543867.1075856762),
}
TOL = 5e-11
NEW_CONTINUOUS = [p.name for p in GEN.spec.continuous if p.name not in OLD_CONTINUOUS]
WING_SIZES = ("width", "length", "offset", "height", "roof_height")


def old_values(seed: int) -> dict:
    """A random vector over the old parameters only (the new ones at their defaults)."""
    rng = np.random.default_rng(seed)
    v = {name: float(rng.uniform(GEN.spec[name].lo, GEN.spec[name].hi)) for name in OLD_CONTINUOUS}
    v.update(sections=int(rng.integers(1, 4)), floors=int(rng.integers(1, 7)), windows=int(rng.integers(1, 6)),
             balcony_pattern=int(rng.integers(0, 4)), roof_type=int(rng.integers(0, 3)),
             has_door=int(rng.integers(0, 2)), back_windows=int(rng.integers(0, 2)))
    return GEN.values(None, v)


def fingerprint(mesh):
    v = mesh.verts.detach().double().numpy()
    rng = np.random.default_rng(0)
    w = rng.choice([-1.0, 1.0], v.shape) * rng.uniform(1.0, 2.0, v.shape)      # |w| >= 1: no vertex is missed
    digest = hashlib.sha256(mesh.faces.numpy().astype(np.int64).tobytes()
                            + mesh.groups.numpy().astype(np.int64).tobytes()).hexdigest()[:16]
    return v.shape[0], digest, float((v * w).sum()), float((v * v).sum())


@pytest.mark.parametrize("case", sorted(OLD_MESHES))
def test_default_switches_reproduce_the_meshes_before_wings(case):
    """No wings, no roof-top boxes, roof types 0-2: the same faces and the same vertices (a change of 1e-10
    in any coordinate moves the weighted sum by at least twice its tolerance)."""
    values = GEN.values(case) if case in GEN.presets else old_values(int(case.removeprefix("random")))
    assert values["wings"] == 0 and values["roof_boxes"] == 0
    n, digest, weighted, squares = fingerprint(build(values))
    ref = OLD_MESHES[case]
    assert (n, digest) == ref[:2]
    assert weighted == pytest.approx(ref[2], rel=0, abs=TOL)
    assert squares == pytest.approx(ref[3], rel=1e-14)


def test_the_fingerprint_sees_a_tiny_change():
    """The reference above can fail: a 1e-10 nudge of any one coordinate moves the weighted sum past its
    tolerance."""
    mesh = build(GEN.values("panel5"))
    base = fingerprint(mesh)[2]
    for i, k in ((17, 1), (4000, 0), (4839, 2)):
        mesh.verts[i, k] += 1e-10
        assert abs(fingerprint(mesh)[2] - base) > TOL
        mesh.verts[i, k] -= 1e-10


def test_wings_and_boxes_only_add_parts():
    """The main block's parts do not move when wings and roof-top boxes are switched on: theirs are appended
    to the walls group and to the roof group."""
    plain = GEN.values("house2", {"roof_type": 3})
    more = {**plain, "wings": 2, "wing2_side": 1, "wing1_roof": 3, "roof_boxes": 2}
    a, b = build(plain), build(more)
    n_main, n_walls = GEN.counts(plain)["walls"], GEN.counts(more)["walls"]
    wing_roofs = ROOF_VERTS[3] + ROOF_VERTS[more["wing2_roof"]]
    keep = torch.cat([torch.arange(8 * n_main), torch.arange(8 * n_walls, b.n_verts - wing_roofs)])
    assert torch.equal(b.verts[keep], a.verts)


# -- footprints --------------------------------------------------------------------------------------------

BASE = {"sections": 1, "section_width": 12.0, "depth": 8.0, "floors": 2, "windows": 3, "roof_overhang": 0.0,
        "balcony_pattern": 0, "has_door": 0}


def wing_rects(values):
    """The footprints ``[(x0, x1, z0, z1)]`` of the wings' walls (the boxes after the main block's walls)."""
    mesh = build(values)
    n = GEN.counts(values)["walls"]
    k = values["wings"]
    first = n - values["roof_boxes"] - k
    v = mesh.verts.detach().double()[: 8 * n].reshape(n, 8, 3)[first: first + k]
    return [(float(b[:, 0].min()), float(b[:, 0].max()), float(b[:, 2].min()), float(b[:, 2].max())) for b in v]


@pytest.mark.parametrize(("shape", "wings", "expected"), [
    # hx = 6, hz = 4: the wings reach min(hx, hz) = 4 into the block (to its ridge line)
    ("L", [(0, 1.0, 5.0, 3.0)], [(1.0, 6.0, 0.0, 7.0)]),
    ("T", [(0, 0.0, 4.0, 5.0)], [(-2.0, 2.0, 0.0, 9.0)]),
    ("U", [(2, -1.0, 3.0, 4.0), (2, 1.0, 3.0, 4.0)], [(-6.0, -3.0, -8.0, 0.0), (3.0, 6.0, -8.0, 0.0)]),
    ("side", [(1, 0.0, 8.0, 6.0)], [(2.0, 12.0, -4.0, 4.0)]),            # lengthens the block along +X
    ("left, offset", [(3, 0.5, 4.0, 2.0)], [(-8.0, -2.0, -1.0, 3.0)]),     # center 0.5 x (4 - 2)
    ("too wide: clamped", [(0, 0.7, 30.0, 2.0)], [(-6.0, 6.0, 0.0, 6.0)]),
])
def test_wings_make_l_t_u_and_side_footprints(shape, wings, expected):
    values = dict(BASE, wings=len(wings))
    for i, (side, offset, width, length) in enumerate(wings, 1):
        values.update({f"wing{i}_side": side, f"wing{i}_offset": offset, f"wing{i}_width": width,
                       f"wing{i}_length": length})
    got = wing_rects(GEN.values(None, values))
    assert np.allclose(got, expected, atol=1e-12), (shape, got)


@pytest.mark.parametrize(("side", "along"), [(0, 2), (2, 2), (1, 0), (3, 0)])
def test_a_wing_roof_ridge_runs_along_the_wing(side, along):
    """Gable and hipped wing roofs: the top vertices (the ridge) differ along the wing's axis only."""
    for roof in (1, 2, 3):
        values = GEN.values(None, dict(BASE, wings=1, wing1_side=side, wing1_roof=roof, wing1_offset=0.3))
        mesh = build(values)
        v = mesh.verts.detach().double()[-(10 if roof == 3 else 6):]
        ridge = v[v[:, 1] > v[:, 1].max() - 1e-9]
        assert ridge.shape[0] == 2
        spread = (ridge[0] - ridge[1]).abs()
        assert spread[along] > 0.5 and spread[2 - along] < 1e-12 and spread[1] < 1e-12
        top = values["wing1_height"] + values["wing1_roof_height"]
        assert float(v[:, 1].max()) == pytest.approx(top)
        assert float(v[:, 1].min()) == pytest.approx(values["wing1_height"])


def test_roof_boxes_stay_on_the_roof():
    """Any position and size: the box stands on the top of the walls, inside the main block's footprint."""
    rng = np.random.default_rng(3)
    names = [f"roof_box{k}_{s}" for k in (1, 2) for s in ("width", "depth", "height", "x", "z")]
    for _ in range(20):
        sizes = {n: float(rng.uniform(GEN.spec[n].lo, GEN.spec[n].hi)) for n in names}
        v = GEN.values(None, dict(BASE, roof_boxes=2, **sizes))
        n = GEN.counts(v)["walls"]
        boxes = build(v).verts.detach().double()[8 * (n - 2): 8 * n]
        T = v["plinth_height"] + v["floors"] * v["floor_height"]
        hx, hz = v["section_width"] / 2, v["depth"] / 2
        assert float(boxes[:, 1].min()) == pytest.approx(T)
        assert float(boxes[:, 0].abs().max()) <= hx + 1e-12 and float(boxes[:, 2].abs().max()) <= hz + 1e-12


@pytest.mark.parametrize("preset", ["house_l", "block_stair"])
def test_new_presets_have_their_wing_and_stair_tower(preset):
    values = GEN.values(preset)
    mesh = check_building(values, preset)
    counts = GEN.counts(values)
    if preset == "house_l":
        assert counts["roof"] == 2 and values["wing1_roof"] == values["roof_type"] == 1
        (x0, x1, z0, z1), = wing_rects(values)
        assert x1 == pytest.approx(values["section_width"] / 2) and z1 > values["depth"] / 2   # an L
    else:
        lo, hi = GEN.extent(values)
        assert hi[1] == pytest.approx(values["plinth_height"] + values["floors"] * values["floor_height"]
                                      + values["roof_box1_height"])
    for group in GROUPS:       # the vectorized check agrees with trimesh's
        ref = components(mesh, group)
        assert len(ref) == parts(mesh, group)[0]
        assert all(c.is_watertight and c.is_winding_consistent and c.volume > 0 for c in ref)


@pytest.mark.parametrize("preset", sorted(GEN.presets))
def test_presets_round_trip_through_parameter_files(preset, tmp_path):
    values = GEN.values(preset)
    path = tmp_path / "p.json"
    path.write_text(param_file_json("building", values))
    gen, raw = load_param_file(path)
    back = GEN.values(None, raw)
    assert gen == "building" and back == values
    theta, discrete = GEN.split(values)
    assert GEN.spec.from_vector(theta, discrete) == values
    assert torch.equal(build(back).verts, build(values).verts)


# -- any parameters: closed parts, the documented box, counts ---------------------------------------------

@st.composite
def building_values(draw):
    """Any in-range values, with small counts of floors, sections and windows (small meshes)."""
    out = {}
    for p in GEN.spec.params:
        if p.continuous:
            out[p.name] = draw(st.floats(float(p.lo), float(p.hi), allow_nan=False))
        else:
            out[p.name] = draw(st.integers(int(p.lo), int(p.hi)))
    out.update(floors=draw(st.integers(1, 4)), sections=draw(st.integers(1, 3)), windows=draw(st.integers(1, 4)),
               wings=draw(st.integers(0, MAX_WINGS)), roof_boxes=draw(st.integers(0, MAX_ROOF_BOXES)))
    return GEN.values(None, out)


@settings(max_examples=60, deadline=None)
@given(values=building_values())
def test_any_parameters_give_closed_parts_and_the_documented_box(values):
    check_building(values, f"{values}")


@settings(max_examples=15, deadline=None)
@given(a=building_values(), b=building_values())
def test_counts_depend_only_on_the_discrete_values(a, b):
    b = {**b, **{p.name: a[p.name] for p in GEN.spec.discrete}}
    ma, mb = build(a), build(b)
    assert ma.n_verts == mb.n_verts
    assert torch.equal(ma.faces, mb.faces) and torch.equal(ma.groups, mb.groups)


def test_extremes_with_wings_and_boxes_keep_parts_valid():
    spec = GEN.spec
    switches = {"wings": 3, "wing1_side": 0, "wing2_side": 0, "wing3_side": 1, "wing1_roof": 3, "wing2_roof": 2,
                "wing3_roof": 1, "roof_boxes": 2, "roof_type": 3, "floors": 2, "sections": 1}
    hi = {p.name: p.hi for p in spec.continuous}
    lo = {p.name: p.lo for p in spec.continuous}
    narrow = {**lo, "wing1_width": 40.0, "roof_box1_width": 40.0}          # clamped to the narrow block
    for values in (hi, lo, {**hi, "section_width": 4.0, "depth": 4.0}, narrow):
        check_building(GEN.values("panel5", {**values, **switches}), f"extreme {values}")


# -- Jacobians -----------------------------------------------------------------------------------------------

def jacobian_case(roof_type: int, roof_axis: int = 0) -> dict:
    """Three wings (front, right, left), two roof-top boxes, every roof type somewhere (the main roof
    ``roof_type`` with its ridge along ``roof_axis``, wing i ``roof_type + i`` mod 4), sizes away from every
    clamp."""
    v = dict(GEN.presets["house2"], floors=1, windows=2, section_width=9.0, depth=7.0, roof_type=roof_type,
             roof_axis=roof_axis, wings=3, roof_boxes=2, roof_ridge=0.5, mansard_break=0.65, mansard_inset=0.2)
    for i, (side, offset, width, length, height, rh) in enumerate(
            [(0, 0.4, 3.0, 3.0, 4.0, 1.5), (1, -0.3, 2.5, 2.0, 5.0, 2.0), (3, 0.6, 4.0, 4.0, 3.0, 1.0)], 1):
        v.update({f"wing{i}_side": side, f"wing{i}_roof": (roof_type + i) % 4, f"wing{i}_offset": offset,
                  f"wing{i}_width": width, f"wing{i}_length": length, f"wing{i}_height": height,
                  f"wing{i}_roof_height": rh})
    for k, (w, d, h, x, z) in enumerate([(2.0, 1.5, 2.0, 0.5, -0.2), (1.5, 2.0, 3.0, -0.6, 0.3)], 1):
        v.update({f"roof_box{k}_width": w, f"roof_box{k}_depth": d, f"roof_box{k}_height": h,
                  f"roof_box{k}_x": x, f"roof_box{k}_z": z})
    return GEN.values(None, v)


@pytest.mark.parametrize("roof_type,roof_axis", [(0, 0), (1, 0), (2, 0), (3, 0), (1, 1), (3, 1)])
def test_jacobian_matches_float64_central_differences_with_wings_and_boxes(roof_type, roof_axis):
    values = jacobian_case(roof_type, roof_axis)
    theta, discrete = GEN.split(values)
    f = lambda t: GEN.mesh(t, discrete).verts  # noqa: E731
    J = mesh_jacobian(f, theta)
    check = check_mesh_jacobian(f, theta, J)
    assert check.max_rel_error <= 1e-6, check
    # every new size moves the mesh (the mansard's only where a mansard is)
    names = [p.name for p in GEN.spec.continuous]
    for name in NEW_CONTINUOUS:
        assert torch.count_nonzero(J[:, names.index(name)]) > 0, name


def test_wing_sizes_move_only_their_wing():
    """Wing i's sizes move its walls box and its roof, nothing else."""
    values = jacobian_case(1)
    theta, discrete = GEN.split(values)
    mesh = GEN.mesh(theta, discrete)
    J = mesh_jacobian(lambda t: GEN.mesh(t, discrete).verts, theta).reshape(mesh.n_verts, 3, -1)
    names = [p.name for p in GEN.spec.continuous]
    first_box = GEN.counts(values)["walls"] - MAX_ROOF_BOXES - 3           # the wings' walls, then the boxes
    sizes = [ROOF_VERTS[values[f"wing{i}_roof"]] for i in (1, 2, 3)]
    roof_ends = mesh.n_verts - sum(sizes) + np.cumsum([0, *sizes])        # the wings' roofs come last
    for i in (1, 2, 3):
        rows = torch.zeros(mesh.n_verts, dtype=torch.bool)
        box = first_box + i - 1
        rows[8 * box: 8 * box + 8] = True
        rows[int(roof_ends[i - 1]): int(roof_ends[i])] = True
        for s in WING_SIZES:
            col = J[:, :, names.index(f"wing{i}_{s}")]
            assert torch.count_nonzero(col[~rows]) == 0, (i, s)
            assert torch.count_nonzero(col[rows]) > 0, (i, s)


def test_jacfwd_with_wings_never_takes_torchs_slow_mixed_operand_path():
    """As tests/test_meshgen_common.py checks at the defaults: the wings' and boxes' code too."""
    theta, discrete = GEN.split(jacobian_case(3))
    hits = slow_path_hits(lambda t: GEN.mesh(t, discrete).verts.reshape(-1), theta)
    assert not hits, dict(hits)
