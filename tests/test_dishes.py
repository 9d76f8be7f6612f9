"""Dishes generator: closed, outward, non-degenerate bodies and handles for every preset and for random
parameters; counts fixed by the discrete values and the level of detail; sizes as the parameters
say; Jacobians equal to float64 central differences. The superelliptic section: its defaults give the
round meshes of before, its rings are the superellipses it names, and it keeps all of the above."""

from __future__ import annotations

import itertools

import igl
import numpy as np
import pytest
import torch
import trimesh
from torch.func import jacfwd

from ipm.generators import get_generator
from ipm.generators.dishes import LODS, DishesGenerator, DishLod, resolve_lod
from ipm.jacobian import check_mesh_jacobian, mesh_jacobian

GEN = get_generator("dishes")
PRESETS = sorted(GEN.presets)
LOW = LODS["low"]


def build(values, lod=LOW):
    theta, discrete = GEN.split(values)
    return GEN.mesh(theta, discrete, lod)


def part(mesh, name):
    """(verts (n, 3) float64 numpy, faces (m, 3) numpy) of one group, re-indexed from 0."""
    g = mesh.group_names.index(name)
    faces = mesh.faces.numpy()[mesh.groups.numpy() == g]
    lo, hi = faces.min(), faces.max()
    return mesh.verts.detach().numpy().astype(np.float64)[lo:hi + 1], faces - lo


def winding_number(v, f, points):
    """Generalized winding number (sum of solid angles, van Oosterom and Strackee) of a closed mesh
    at ``points (P, 3)``: 1 inside, 0 outside."""
    a, b, c = (v[f[:, i]][None] - points[:, None] for i in range(3))              # (P, F, 3)
    la, lb, lc = (np.linalg.norm(x, axis=-1) for x in (a, b, c))
    det = np.einsum("pfi,pfi->pf", a, np.cross(b, c))
    den = la * lb * lc + np.einsum("pfi,pfi->pf", a, b) * lc + np.einsum("pfi,pfi->pf", b, c) * la \
        + np.einsum("pfi,pfi->pf", c, a) * lb
    return (2 * np.arctan2(det, den)).sum(1) / (4 * np.pi)


def check_closed_solid(v, f, what):
    """Reference check with trimesh: watertight, consistently wound, outward, no degenerate face."""
    m = trimesh.Trimesh(v, f, process=False)
    assert m.is_watertight, f"{what}: not watertight"
    assert m.is_winding_consistent, f"{what}: inconsistent winding"
    assert m.volume > 0, f"{what}: volume {m.volume} (faces point inwards)"
    areas = m.area_faces
    assert areas.min() > 1e-12 * max(1.0, areas.max()), f"{what}: degenerate face, area {areas.min()}"
    return m


def check_closed_solid_fast(v, f, what):
    """The same facts, vectorized (for the random sweeps): every directed edge once and its reverse
    once (closed and consistently wound), positive signed volume, no degenerate face."""
    n = len(v)
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    key, rev = e[:, 0] * n + e[:, 1], e[:, 1] * n + e[:, 0]
    assert len(np.unique(key)) == len(key), f"{what}: an edge is used twice in the same direction"
    assert np.array_equal(np.sort(key), np.sort(rev)), f"{what}: open or inconsistently wound"
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    assert np.einsum("ij,ij->", a, np.cross(b, c)) > 0, f"{what}: faces point inwards"
    areas = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    assert areas.min() > 1e-12 * max(1.0, areas.max()), f"{what}: degenerate face, area {areas.min()}"


def check_handle_touches_body(mesh, what, radial, name="handle"):
    """Both handle end centers (the caps' pole vertices; the spout tube's root only) lie in the body solid, or,
    where the wall is thinner than the polygon's sag (then the wall's inside is ill-defined), on its surface."""
    bv, bf = part(mesh, "body")
    hv, _ = part(mesh, name)
    ends = hv[[0, -1]] if name == "handle" else hv[:1]
    inside = winding_number(bv, bf, ends) > 0.5
    if inside.all():
        return
    dist = np.sqrt(igl.point_mesh_squared_distance(ends, bv, bf)[0])
    sag = np.linalg.norm(bv[:, [0, 2]], axis=1).max() * (1 - np.cos(np.pi / radial))
    assert np.all(inside | (dist <= 2 * sag + 1e-9)), f"{what}: handle ends {ends} are off the body (distance {dist})"


@pytest.mark.parametrize("preset", PRESETS)
def test_presets_are_closed_solids_with_a_touching_handle(preset):
    values = GEN.values(preset)
    mesh = build(values, "medium")
    check_closed_solid(*part(mesh, "body"), f"{preset} body")
    assert ("handle" in mesh.group_names) == bool(values["has_handle"])
    assert ("spout" in mesh.group_names) == bool(values["has_spout"])
    assert ("knob" in mesh.group_names) == bool(values["has_knob"])
    if values["has_knob"]:
        check_closed_solid(*part(mesh, "knob"), f"{preset} knob")
    if values["has_spout"]:
        check_closed_solid(*part(mesh, "spout"), f"{preset} spout")
        check_handle_touches_body(mesh, preset, LODS["medium"].radial, "spout")
    if values["has_handle"]:
        check_closed_solid(*part(mesh, "handle"), f"{preset} handle")
        check_handle_touches_body(mesh, preset, LODS["medium"].radial)
        bv, bf = part(mesh, "body")
        ends = part(mesh, "handle")[0][[0, -1]]
        assert np.all(igl.winding_number(bv, bf, ends) > 0.5), "preset handle ends are embedded in the wall"
        assert np.allclose(winding_number(bv, bf, ends), igl.winding_number(bv, bf, ends))


def test_random_parameters_always_give_closed_solids():
    rng = np.random.default_rng(7)
    for i in range(200):
        values = GEN.spec.random(rng)
        mesh = build(values)
        what = f"random set {i}: {values}"
        check_closed_solid_fast(*part(mesh, "body"), what)
        if values["has_handle"]:
            check_closed_solid_fast(*part(mesh, "handle"), what)
            check_handle_touches_body(mesh, what, LOW.radial)
        if values["has_spout"]:
            check_closed_solid_fast(*part(mesh, "spout"), what)
            check_handle_touches_body(mesh, what, LOW.radial, "spout")
        if values["has_knob"]:
            check_closed_solid_fast(*part(mesh, "knob"), what)


def test_counts_depend_only_on_discrete_values_and_lod():
    rng = np.random.default_rng(3)
    a, b = GEN.spec.random(rng), GEN.spec.random(rng)
    for combo in itertools.product((0, 1), repeat=3):
        d = dict(zip(("has_handle", "has_spout", "has_knob"), combo))
        a.update(d)
        b.update(d)
        ma, mb = build(a), build(b)
        assert torch.equal(ma.faces, mb.faces) and torch.equal(ma.groups, mb.groups)
        assert (ma.n_verts, ma.n_faces) == GEN.counts(d, LOW)
    assert build(a, "high").n_verts > build(a, "low").n_verts


def test_height_and_profile_radii_match_the_parameters():
    values = GEN.values("vase", {"spout": 0.0})
    lod = DishLod(radial=16, wall=33, rim=5, bottom=3, handle_sections=8, handle_ring=6)
    v = build(values, lod).verts.detach().double()
    assert float(v[:, 1].max()) == pytest.approx(values["height"], abs=1e-12)
    assert float(v[:, 1].min()) == pytest.approx(0.0, abs=1e-12)
    # the outer wall rings at the control heights have exactly the control radii
    rings = v[1:-1].reshape(-1, lod.radial, 3)
    wall = rings[lod.bottom - 1: lod.bottom - 1 + lod.wall]
    radius = torch.linalg.vector_norm(wall[..., [0, 2]], dim=-1)                  # (wall, radial)
    k = 9
    want = torch.tensor([values[f"radius_{i}"] for i in range(k)], dtype=torch.float64)
    got = radius[:: (lod.wall - 1) // (k - 1)]
    assert torch.allclose(got, want[:, None].expand_as(got), atol=1e-12)
    assert float(radius.max()) >= float(want.max()) - 1e-12


def test_mug_bounding_box_matches_the_radius_and_the_handle_reach():
    values = GEN.values("mug")
    body_v = torch.as_tensor(part(build(values, "high"), "body")[0])
    r = torch.linalg.vector_norm(body_v[:, [0, 2]], dim=-1)
    assert float(r.max()) == pytest.approx(values["radius_8"], rel=1e-9)      # radii grow upwards
    hv = torch.as_tensor(part(build(values, "high"), "handle")[0])
    assert float(hv[:, 0].max()) > values["radius_8"] + 0.5 * values["handle_reach"]


def test_spout_bulges_the_lip_opposite_the_handle_only():
    plain, spouted = GEN.values("pitcher", {"spout": 0.0}), GEN.values("pitcher", {"spout": 0.2})
    a, b = (torch.as_tensor(part(build(x), "body")[0]) for x in (plain, spouted))
    shift = (b - a).norm(dim=-1)
    assert torch.all(shift[a[:, 1] < (1 - plain["spout_length"]) * plain["height"] - 1e-9] == 0)
    moved = shift > 0.01 * shift.max()           # the angular profile is a Gaussian: tiny elsewhere
    assert float(shift.max()) == pytest.approx(0.2, rel=0.05)
    assert torch.all(b[moved, 0] < 0), "the spout is on the -X side"


def test_lod_changes_counts_not_the_object():
    values = GEN.values("teacup")
    lo = build(values, "low").verts.detach()
    hi = build(values, "high").verts.detach()
    assert hi.shape[0] > 3 * lo.shape[0]
    assert torch.allclose(lo.amin(0), hi.amin(0), atol=0.02) and torch.allclose(lo.amax(0), hi.amax(0), atol=0.02)


def test_lod_accepts_names_dicts_and_dataclasses_and_rejects_the_rest():
    assert resolve_lod("high") == LODS["high"] and resolve_lod(None) == LODS["medium"]
    assert resolve_lod({"radial": 12}).radial == 12
    with pytest.raises(ValueError, match="lod rim: expected an odd number"):
        DishLod(rim=4)
    with pytest.raises(ValueError, match="lod: expected one of low, medium, high, got 'ultra'"):
        resolve_lod("ultra")
    with pytest.raises(ValueError, match="unknown field"):
        resolve_lod({"segments": 3})
    glass = GEN.values("glass")
    assert GEN.to_mesh(glass, resolution=20).n_verts == GEN.to_mesh(glass).n_verts == GEN.counts(glass)[0]


def test_other_profile_resolutions_resample_the_presets():
    g = DishesGenerator(n_radii=5)
    assert "radius_4" in g.spec and "radius_5" not in g.spec
    m = g.to_mesh(g.values("bottle"), lod="low")
    check_closed_solid(*part(m, "body"), "5-radius bottle")


@pytest.mark.parametrize("preset", PRESETS)
def test_jacobian_matches_float64_central_differences(preset):
    theta, discrete = GEN.split(GEN.values(preset))
    check = check_mesh_jacobian(lambda t: GEN.mesh(t, discrete, LOW).verts, theta)
    assert check.max_rel_error <= 1e-6, check


def test_jacobian_with_handle_offsets_and_azimuth_matches_central_differences():
    values = GEN.values("mug", {"handle_azimuth": 35.0, "handle_widen_2": 0.02, "handle_thicken_5": -0.01,
                                "spout": 0.1, "handle_taper": 0.3, "bottom_dome": 0.5})
    theta, discrete = GEN.split(values)
    check = check_mesh_jacobian(lambda t: GEN.mesh(t, discrete, LOW).verts, theta)
    assert check.max_rel_error <= 1e-6, check


def test_without_handle_there_are_no_handle_rows_and_handle_parameters_do_nothing():
    values = GEN.values("mug", {"has_handle": 0})
    theta, discrete = GEN.split(values)
    mesh = GEN.mesh(theta, discrete, LOW)
    assert mesh.group_names == ("body",)
    assert mesh.n_verts == GEN.counts({"has_handle": 0}, LOW)[0]
    J = mesh_jacobian(lambda t: GEN.mesh(t, discrete, LOW).verts, theta)
    names = [p.name for p in GEN.spec.continuous]
    handle_cols = [i for i, n in enumerate(names) if n.startswith("handle_")]
    assert J.shape == (3 * mesh.n_verts, len(names))
    assert torch.count_nonzero(J[:, handle_cols]) == 0
    assert torch.count_nonzero(J[:, names.index("height")]) > 0


def test_handle_parameters_move_only_the_handle():
    theta, discrete = GEN.split(GEN.values("mug"))
    mesh = GEN.mesh(theta, discrete, LOW)
    J = mesh_jacobian(lambda t: GEN.mesh(t, discrete, LOW).verts, theta).reshape(mesh.n_verts, 3, -1)
    names = [p.name for p in GEN.spec.continuous]
    n_body = GEN.counts({"has_handle": 0}, LOW)[0]
    for i, n in enumerate(names):
        if n.startswith("handle_"):
            assert torch.count_nonzero(J[:n_body, :, i]) == 0, n
            assert torch.count_nonzero(J[n_body:, :, i]) > 0, n


@pytest.mark.parametrize("preset, overrides", [("mug", {}), ("pitcher", {}), ("bowl", {}),
                                               ("mug", {"spout": 0.15, "handle_azimuth": 20.0}),
                                               ("mug", {"has_handle": 0}), ("teapot", {}),
                                               ("teapot", {"has_handle": 0, "handle_azimuth": -40.0})])
@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_structured_jacobian_equals_jacfwd_of_the_mesh(preset, overrides, dtype):
    theta, discrete = GEN.split(GEN.values(preset, overrides), dtype)
    J = GEN.jacobian(theta, discrete, LOW)
    ref = jacfwd(lambda t: GEN.mesh(t, discrete, LOW).verts.reshape(-1))(theta)
    assert J.dtype == dtype and J.shape == ref.shape
    tol = 1e-12 if dtype == torch.float64 else 1e-5
    assert torch.allclose(J, ref, rtol=tol, atol=tol * float(ref.abs().max()))


def test_per_height_wall_thickness():
    """Equal ``wall_thicken_i`` add to ``wall_thickness`` exactly (a spline through equal values is that
    value); one raised value thickens the wall near its height only, never the outer wall."""
    k = GEN.k
    base = GEN.values("mug", {"has_handle": 0})  # (a handle's ends follow the inner wall)
    even = GEN.to_mesh({**base, **{f"wall_thicken_{i}": 0.02 for i in range(k)}})
    thick = GEN.to_mesh({**base, "wall_thickness": base["wall_thickness"] + 0.02})
    assert torch.allclose(even.verts, thick.verts, atol=1e-12)
    plain = GEN.to_mesh(base)
    bump = GEN.to_mesh({**base, "wall_thicken_2": 0.15})
    moved = (bump.verts - plain.verts).norm(dim=1) > 1e-9
    r = plain.verts[:, [0, 2]].norm(dim=1)
    y = plain.verts[:, 1]
    assert moved.any()
    assert float(r[moved].max()) < 0.9 * float(r.max())   # inner wall only (the outer one is wider)
    assert float(y[moved].max()) < 0.6 * float(y.max())   # near height 2/8, not at the rim


# ----------------------------------------------------------------------------------------------
# The superelliptic section
# ----------------------------------------------------------------------------------------------

ROUND = {"section_squareness": 0.0, "section_aspect": 1.0}
# (vertices, sum of coordinates, sum of squares) of each preset at the low level of detail, as the round-only
# generator made them before the section was added (commit b86de4d)
ROUND_DIGESTS = {
    "bottle": (938, 871.60941125497, 1209.626383950634),
    "bowl": (938, 242.877674204038, 556.348090878518),
    "glass": (938, 599.254138812258, 615.640983786005),
    "mug": (1068, 627.038601491819, 565.339206710792),
    "pitcher": (1068, 856.997793546534, 974.841860287921),
    "plate": (938, 50.553128443284, 712.964275057225),
    "teacup": (1068, 405.153909193354, 332.318367518565),
    "vase": (938, 780.637858506218, 1012.046967729236),
}


def ring_grid(mesh, lod):
    """The body's ring vertices ``(rings, radial, 3)`` float64 (the two poles dropped)."""
    v = torch.as_tensor(part(mesh, "body")[0])
    return v[1:-1].reshape(-1, lod.radial, 3)


@pytest.mark.parametrize("preset", sorted(ROUND_DIGESTS))
def test_the_default_section_is_the_round_vessel_of_before(preset):
    assert all(GEN.spec[n].default == v for n, v in ROUND.items())
    v = build(GEN.values(preset)).verts.detach().double()
    n, total, squares = ROUND_DIGESTS[preset]
    assert v.shape[0] == n
    assert float(v.sum()) == pytest.approx(total, abs=1e-9)
    assert float((v * v).sum()) == pytest.approx(squares, abs=1e-9)


@pytest.mark.parametrize("preset", PRESETS)
def test_a_round_section_revolves_the_profile_on_circles(preset):
    """With the section forced round, the body equals the profile revolved on exact circles (the
    revolution the generator used before it had a section), and the handle is as with rho = 1."""
    from ipm.generators import _meshkit as mk
    from ipm.generators.dishes import _handle, _Named, _profile

    theta, discrete = GEN.split(GEN.values(preset, ROUND))
    st = GEN._stage(theta, GEN._check(theta, discrete, LOW)[0], LOW)
    assert torch.allclose(st["rho"], torch.ones_like(st["rho"]), rtol=0, atol=1e-15)
    body = mk.revolve(st["r"], st["y"], LOW.radial, bottom=st["y_bottom"], top=st["y_top"],
                      bulge=(st["q"], st["w"]))
    mesh = GEN.mesh(theta, discrete, LOW)
    assert torch.allclose(mesh.verts[:body.shape[0]], body, rtol=0, atol=1e-14)
    if discrete["has_handle"]:
        p = _Named(theta, GEN._index)
        v = {key: theta[sl] for key, sl in GEN._slices.items()}
        v["sections"] = v["sections"].reshape(2, -1).T
        prof = _profile(p, v["radii"], LOW, v["thicken"])
        handle = _handle(p, v, prof, torch.ones(LOW.radial, dtype=theta.dtype), LOW)
        assert torch.allclose(mesh.verts[body.shape[0]:body.shape[0] + handle.shape[0]], handle, rtol=0, atol=1e-14)


@pytest.mark.parametrize("squareness, power", [(0.0, 2.0), (0.5, 1 / 0.3), (1.0, 10.0)])
@pytest.mark.parametrize("aspect", [0.4, 1.0, 1.6])
def test_rings_are_superellipses_with_the_given_exponent_and_aspect(squareness, power, aspect):
    values = GEN.values("glass", {"section_squareness": squareness, "section_aspect": aspect})
    lod = DishLod(radial=40, wall=33, rim=5, bottom=3)
    rings = ring_grid(build(values, lod), lod)
    wall = rings[lod.bottom - 1: lod.bottom - 1 + lod.wall: (lod.wall - 1) // 8]      # control heights
    radii = torch.tensor([values[f"radius_{i}"] for i in range(9)], dtype=torch.float64)[:, None]
    a, b = radii / aspect ** 0.5, radii * aspect ** 0.5         # half width along X, half depth along Z
    x, z = wall[..., 0] / a, wall[..., 2] / b
    assert torch.allclose(x.abs() ** power + z.abs() ** power, torch.ones_like(x), atol=1e-12)
    # the ring's vertices 0 and radial / 4 lie on the axes
    assert torch.allclose(wall[:, 0, 0], a[:, 0], atol=1e-12)
    assert torch.allclose(-wall[:, lod.radial // 4, 2], b[:, 0], atol=1e-12)
    # the diagonal of a square section stands out by 2^(1/2 - 1/n)
    if aspect == 1.0:
        diag = torch.linalg.vector_norm(wall[:, lod.radial // 8, [0, 2]], dim=-1)
        assert torch.allclose(diag, radii[:, 0] * 2 ** (0.5 - 1 / power), atol=1e-12)


def test_flat_sides_of_a_square_section_are_as_thick_as_the_wall():
    """The inner ring is the outer one scaled, so the flat sides of a square section keep
    ``wall_thickness`` (measured along X at several depths z; a round section's wall is 1 / cos 30 deg
    = 1.15 times as thick along X at z = R / 2)."""
    t = 0.03
    values = GEN.values("glass", {"section_squareness": 1.0, "wall_thickness": t})
    bv, bf = part(build(values, "medium"), "body")
    R, y = values["radius_4"], 0.5 * values["height"]
    xs = np.linspace(0.7 * R, 1.1 * R, 801)
    for z in (0.0, 0.25 * R, 0.5 * R):
        pts = np.stack([xs, np.full_like(xs, y), np.full_like(xs, z)], -1)
        width = (igl.winding_number(bv, bf, pts) > 0.5).sum() * (xs[1] - xs[0])
        assert width == pytest.approx(t, rel=0.06), z


SQUARE = {"section_squareness": 1.0, "section_aspect": 1.0}
OVAL = {"section_squareness": 0.0, "section_aspect": 0.55}


@pytest.mark.parametrize("preset, overrides", [
    ("mug", {**SQUARE, "handle_azimuth": 35.0, "spout": 0.1}),       # azimuths off the ring's vertices:
    ("pitcher", {**OVAL, "handle_azimuth": -100.0}),                  # the handle's ends have kinks there
    ("teacup", {"section_squareness": 0.45, "section_aspect": 1.4, "handle_azimuth": 128.0}),
    ("tumbler", {}),
    ("glass", {"section_squareness": 1.0, "section_aspect": 0.4}),
])
def test_jacobian_of_square_and_oval_sections_matches_central_differences(preset, overrides):
    theta, discrete = GEN.split(GEN.values(preset, overrides))
    check = check_mesh_jacobian(lambda t: GEN.mesh(t, discrete, LOW).verts, theta)
    assert check.max_rel_error <= 1e-6, check
    J = GEN.jacobian(theta, discrete, LOW)
    names = [p.name for p in GEN.spec.continuous]
    for name in ROUND:  # the section moves the body (and the handle's ends)
        assert torch.count_nonzero(J[:, names.index(name)]) > 0, name


@pytest.mark.parametrize("preset", ["mug", "glass"])
@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_section_derivatives_are_finite_where_cos_or_sin_vanish(preset, dtype):
    """|cos|^n and |sin|^n at the ring vertices on the axes (cos or sin 0: d/dn of |x|^n is x^n log|x|)
    and at the extreme exponents and aspects: finite everywhere, and zero on the axes, where rho is 1 (or
    the aspect) whatever the exponent."""
    names = [p.name for p in GEN.spec.continuous]
    for squareness in (0.0, 1.0):
        for aspect in (0.4, 1.0, 1.6):
            values = GEN.values(preset, {"section_squareness": squareness, "section_aspect": aspect,
                                         "handle_azimuth": 7.0})
            theta, discrete = GEN.split(values, dtype)
            J = GEN.jacobian(theta, discrete, LOW)
            assert torch.isfinite(J).all()
            rings = J[3:3 * (GEN.counts({"has_handle": 0}, LOW)[0] - 1)].reshape(-1, LOW.radial, 3, len(names))
            d_sq = rings[..., names.index("section_squareness")]
            for j in range(0, LOW.radial, LOW.radial // 4):
                assert float(d_sq[:, j].abs().max()) <= 1e-5 * float(d_sq.abs().max()) + 1e-30, j


@pytest.mark.parametrize("preset, overrides", [("mug", SQUARE), ("pitcher", OVAL), ("teacup", {"section_aspect": 1.6}),
                                               ("tumbler", {}), ("mug", {**SQUARE, "has_handle": 0})])
@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_structured_jacobian_equals_jacfwd_under_a_section(preset, overrides, dtype):
    theta, discrete = GEN.split(GEN.values(preset, {"handle_azimuth": 50.0, **overrides}), dtype)
    J = GEN.jacobian(theta, discrete, LOW)
    ref = jacfwd(lambda t: GEN.mesh(t, discrete, LOW).verts.reshape(-1))(theta)
    tol = 1e-12 if dtype == torch.float64 else 1e-5
    assert torch.allclose(J, ref, rtol=tol, atol=tol * float(ref.abs().max()))


def test_random_sections_at_the_extremes_give_closed_solids_with_touching_handles():
    """Random parameters with the section at the corners of its range (and anywhere inside), handles
    on: closed, consistently wound, outward, non-degenerate; the handle's ends in the wall."""
    rng = np.random.default_rng(17)
    corners = [(s, a) for s in (0.0, 1.0) for a in (0.4, 1.6)]
    for i in range(120):
        values = GEN.spec.random(rng)
        values["has_handle"] = 1
        if i % 2 == 0:
            values["section_squareness"], values["section_aspect"] = corners[(i // 2) % 4]
        mesh = build(values)
        what = f"random set {i}: {values}"
        check_closed_solid_fast(*part(mesh, "body"), what)
        check_closed_solid_fast(*part(mesh, "handle"), what)
        check_handle_touches_body(mesh, what, LOW.radial)


@pytest.mark.parametrize("section", [SQUARE, OVAL, {"section_squareness": 1.0, "section_aspect": 0.4},
                                     {"section_squareness": 0.6, "section_aspect": 1.6}])
def test_handle_ends_are_embedded_in_square_and_oval_walls(section):
    """At every azimuth (on and between the ring's vertices) and level of detail, the preset handles'
    ends lie inside the wall of the section's body."""
    for lod in ("low", "medium"):
        for preset in ("mug", "teacup", "pitcher"):
            for azimuth in np.arange(8) * 46.9 - 180.0:  # from a vertex (-180) to between them
                mesh = build(GEN.values(preset, {**section, "handle_azimuth": float(azimuth)}), lod)
                bv, bf = part(mesh, "body")
                ends = part(mesh, "handle")[0][[0, -1]]
                assert np.all(igl.winding_number(bv, bf, ends) > 0.5), (preset, lod, azimuth)


def test_tumbler_preset_is_a_tapered_square_cup_without_handle():
    values = GEN.values("tumbler")
    assert values["has_handle"] == 0 and values["section_squareness"] > 0.5
    rings = ring_grid(build(values, "medium"), LODS["medium"])
    top, foot = rings[LODS["medium"].bottom - 2 + LODS["medium"].wall], rings[LODS["medium"].bottom - 1]
    assert float(top[:, 0].max()) > 1.3 * float(foot[:, 0].max())              # wider at the top
    diag = torch.linalg.vector_norm(top[LODS["medium"].radial // 8, [0, 2]])
    assert float(diag) > 1.15 * float(top[0, 0])                                 # square: corners stand out


def test_spout_tube_parameters_move_only_the_spout_tube():
    """The spout tube's parameters move its vertices only; it goes where they say: the tip's centre
    ``spout_reach`` beyond the wall (at least: the wall's polygon lies inside the circle) at ``spout_rise``
    times the height, opposite the handle, and its sections shrink from ``spout_root`` to ``spout_tip``."""
    from ipm.generators.dishes import SPOUT_TUBE

    values = GEN.values("teapot")
    theta, discrete = GEN.split(values)
    mesh = GEN.mesh(theta, discrete, LOW)
    J = GEN.jacobian(theta, discrete, LOW).reshape(mesh.n_verts, 3, -1)
    names = [p.name for p in GEN.spec.continuous]
    first = GEN.counts({"has_handle": 1}, LOW)[0]
    for n in SPOUT_TUBE:
        i = names.index(n)
        assert torch.count_nonzero(J[:first, :, i]) == 0, n
        assert torch.count_nonzero(J[first:, :, i]) > 0, n
    sv, _ = part(mesh, "spout")
    tip = sv[-1]
    assert tip[1] == pytest.approx(values["spout_rise"] * values["height"], abs=1e-9)
    hv, _ = part(mesh, "handle")
    assert tip[0] < 0 < hv[len(hv) // 2, 0]          # handle_azimuth 0: the handle at +X, the spout at -X
    wall = float(np.linalg.norm(part(mesh, "body")[0][:, [0, 2]], axis=1).max())
    assert -tip[0] >= values["spout_reach"] + 0.9 * values["radius_0"] - 1e-9 and -tip[0] <= wall + values["spout_reach"]
    ring = LOW.handle_ring
    first_ring, last_ring = sv[1:1 + ring], sv[-1 - ring:-1]
    r0 = np.linalg.norm(first_ring - first_ring.mean(0), axis=1)
    r1 = np.linalg.norm(last_ring - last_ring.mean(0), axis=1)
    assert np.allclose(r0, values["spout_root"], rtol=1e-9) and np.allclose(r1, values["spout_tip"], rtol=1e-9)


def test_knob_parameters_move_only_the_knob():
    """The knob's parameters move its vertices only, and it is where they say: on the axis, ``knob_radius``
    wide, from ``knob_sink`` of its height below the top of the rim to ``knob_height`` above that."""
    from ipm.generators.dishes import KNOB

    values = GEN.values("teapot", {"knob_radius": 0.09, "knob_height": 0.12, "knob_sink": 0.25})
    theta, discrete = GEN.split(values)
    mesh = GEN.mesh(theta, discrete, LOW)
    J = GEN.jacobian(theta, discrete, LOW).reshape(mesh.n_verts, 3, -1)
    names = [p.name for p in GEN.spec.continuous]
    first = GEN.counts({"has_handle": 1, "has_spout": 1}, LOW)[0]
    for n in KNOB:
        i = names.index(n)
        assert torch.count_nonzero(J[:first, :, i]) == 0, n
        assert torch.count_nonzero(J[first:, :, i]) > 0, n
    kv, kf = part(mesh, "knob")
    check_closed_solid(kv, kf, "knob")
    bottom = values["height"] - 0.25 * 0.12
    assert kv[:, 1].min() == pytest.approx(bottom, abs=1e-12)
    assert kv[:, 1].max() == pytest.approx(bottom + 0.12, abs=1e-12)
    width = np.linalg.norm(kv[:, [0, 2]], axis=1)
    assert 0.09 * np.cos(np.pi / LOW.handle_sections) <= width.max() <= 0.09 + 1e-12  # sampled meridian
    assert np.allclose(kv[:, [0, 2]].mean(0), 0.0, atol=1e-12)        # on the axis
    # the presets without a knob have none; the teapot's stands above its rim
    assert "knob" not in build(GEN.values("mug"), "low").group_names
    top = part(build(GEN.values("teapot"), "low"), "knob")[0][:, 1].max()
    assert top > GEN.values("teapot")["height"]


def test_spout_tube_bend_turns_the_tip_upwards():
    """At bend 1 the curve leaves the wall level and reaches the tip going straight up; at 0 it is straight."""
    for bend, check in ((1.0, "curved"), (0.0, "straight")):
        mesh = build(GEN.values("teapot", {"spout_bend": bend}), "medium")
        sv, _ = part(mesh, "spout")
        ring = LODS["medium"].handle_ring
        centres = np.stack([sv[1 + k * ring:1 + (k + 1) * ring].mean(0) for k in range(LODS["medium"].handle_sections)])
        d0, d1 = centres[1] - centres[0], centres[-1] - centres[-2]
        if check == "curved":
            assert abs(d0[1]) < 0.05 * np.linalg.norm(d0) and np.hypot(d1[0], d1[2]) < 0.05 * np.linalg.norm(d1)
        else:
            steps = np.diff(centres, axis=0)
            unit = steps / np.linalg.norm(steps, axis=1, keepdims=True)
            assert np.allclose(unit, unit[0], atol=1e-9)
