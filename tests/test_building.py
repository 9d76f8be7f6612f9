"""Panel-building generator: the bounding box the parameters promise, one closed part per window,
every part a closed box or prism, groups on every face, and Jacobians equal to central differences."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from ipm.generators import get_generator
from ipm.generators.building import GROUPS
from ipm.jacobian import check_mesh_jacobian, mesh_jacobian

GEN = get_generator("building")
PRESETS = sorted(GEN.presets)
# vertices per closed part: box 8, window (box with a pocket) 16, balcony (L prism) 12, roof flat 8,
# gable 6, hipped 6, mansard 10
PART_VERTS = {"walls": {8}, "windows": {16}, "balconies": {12}, "doors": {8}, "roof": {6, 8, 10}}


def build(values):
    theta, discrete = GEN.split(values)
    return GEN.mesh(theta, discrete)


def components(mesh, group):
    """The connected components (trimesh) of one face group (reference check, slow)."""
    g = mesh.group_names.index(group)
    faces = mesh.faces[mesh.groups == g].numpy()
    if len(faces) == 0:
        return []
    m = trimesh.Trimesh(mesh.verts.detach().double().numpy(), faces, process=False)
    return m.split(only_watertight=False)


def parts(mesh, group):
    """Vectorized per-component facts of one face group: (number of components, vertices per
    component, volume per component, smallest face area, closed and consistently wound)."""
    g = mesh.group_names.index(group)
    faces = mesh.faces[mesh.groups == g].numpy()
    if len(faces) == 0:
        return 0, np.zeros(0), np.zeros(0), np.inf, True
    v = mesh.verts.detach().double().numpy()
    used = np.unique(faces)
    n = v.shape[0]
    graph = coo_matrix((np.ones(faces.size), (np.repeat(faces[:, 0], 3), faces.reshape(-1))), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    comp = np.unique(label[used], return_inverse=True)[1]
    vert_comp = np.full(n, -1)
    vert_comp[used] = comp
    n_comp = comp.max() + 1
    a, b, c = v[faces[:, 0]], v[faces[:, 1]], v[faces[:, 2]]
    vol = np.bincount(vert_comp[faces[:, 0]], np.einsum("ij,ij->i", a, np.cross(b, c)) / 6.0, n_comp)
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1).min()
    # closed and consistently wound: every directed edge once, and its reverse once
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    key = e[:, 0] * n + e[:, 1]
    rev = e[:, 1] * n + e[:, 0]
    closed = len(np.unique(key)) == len(key) and np.array_equal(np.sort(key), np.sort(rev))
    return n_comp, np.bincount(comp, minlength=n_comp), vol, area, closed


def random_values(rng, max_floors=12):
    v = GEN.spec.random(rng)
    v["floors"] = int(rng.integers(1, max_floors + 1))        # keep the meshes small
    v["sections"] = int(rng.integers(1, 5))
    return v


def check_building(values, what):
    mesh = build(values)
    assert mesh.group_names == GROUPS
    assert mesh.groups.shape == (mesh.n_faces,)
    # bounding box exactly as documented
    lo, hi = GEN.extent(values)
    v = mesh.verts.detach().double()
    assert np.allclose(v.amin(0).numpy(), lo, atol=1e-9), f"{what}: min {v.amin(0)} != {lo}"
    assert np.allclose(v.amax(0).numpy(), hi, atol=1e-9), f"{what}: max {v.amax(0)} != {hi}"
    # every part is a closed, outward box or prism; counts per group as documented
    counts = GEN.counts(values)
    for group in GROUPS:
        n, nv, vol, area, closed = parts(mesh, group)
        assert n == counts[group], f"{what}: {n} {group}, expected {counts[group]}"
        assert closed, f"{what}: {group} parts are not closed or not consistently wound"
        assert np.all(vol > 0), f"{what}: inverted {group} part (volume {vol.min()})"
        assert set(nv.tolist()) <= PART_VERTS[group], f"{what}: {group} parts with {set(nv.tolist())} vertices"
        assert area > 1e-9, f"{what}: degenerate face in a {group} part"
    return mesh


@pytest.mark.parametrize("preset", PRESETS)
def test_presets_have_the_documented_box_and_closed_parts(preset):
    mesh = check_building(GEN.values(preset), preset)
    if preset == "house2":          # the vectorized check agrees with trimesh's
        for group in GROUPS:
            ref = components(mesh, group)
            assert len(ref) == parts(mesh, group)[0]
            assert all(c.is_watertight and c.is_winding_consistent and c.volume > 0 for c in ref)


def test_random_parameters_have_the_documented_box_and_closed_parts():
    rng = np.random.default_rng(11)
    for i in range(60):
        values = random_values(rng)
        check_building(values, f"random set {i}: {values}")


@pytest.mark.parametrize("preset", PRESETS)
def test_window_parts_are_sections_times_floors_times_windows_per_facade(preset):
    values = GEN.values(preset)
    for back in (0, 1):
        values = {**values, "back_windows": back}
        n = parts(build(values), "windows")[0]
        assert n == values["sections"] * values["floors"] * values["windows"] * (1 + back)


def test_height_is_plinth_plus_floors_plus_roof_and_length_is_sections_times_width():
    values = GEN.values("panel9", {"roof_overhang": 0.0, "frame_depth": 0.0, "balcony_pattern": 0,
                                   "has_door": 0})
    v = build(values).verts.detach().double()
    size = (v.amax(0) - v.amin(0)).tolist()
    assert size[0] == pytest.approx(values["sections"] * values["section_width"])
    assert size[1] == pytest.approx(values["plinth_height"] + values["floors"] * values["floor_height"]
                                    + values["roof_height"])
    assert size[2] == pytest.approx(values["depth"])


@pytest.mark.parametrize("roof_axis", [0, 1])
@pytest.mark.parametrize("roof_type", [0, 1, 2, 3])
def test_roof_types_reach_the_roof_height(roof_type, roof_axis):
    values = GEN.values("house2", {"roof_type": roof_type, "roof_axis": roof_axis})
    mesh = build(values)
    roof = components(mesh, "roof")
    assert len(roof) == 1 and roof[0].is_watertight and roof[0].volume > 0
    top = values["plinth_height"] + values["floors"] * values["floor_height"]
    assert roof[0].bounds[0][1] == pytest.approx(top)
    assert roof[0].bounds[1][1] == pytest.approx(top + values["roof_height"])


@pytest.mark.parametrize("roof_type", [1, 2, 3])
def test_roof_axis_turns_the_roof_of_the_block_turned(roof_type):
    """A ridge along Z (``roof_axis`` 1) on a block a long and b deep is the ridge along X of the block b long and
    a deep, turned a quarter about Y; the walls keep their footprint; faces and counts are the same."""
    base = {"sections": 1, "roof_type": roof_type, "roof_ridge": 0.4, "mansard_inset": 0.2}
    across = GEN.values("house2", {**base, "section_width": 11.0, "depth": 7.0, "roof_axis": 1})
    along = GEN.values("house2", {**base, "section_width": 7.0, "depth": 11.0, "roof_axis": 0})
    a, b = GEN.to_mesh(across), GEN.to_mesh(along)
    assert GEN.counts(across) == GEN.counts(along) and torch.equal(a.faces, b.faces)
    ra, rb = (np.concatenate([c.vertices for c in components(m, "roof")]) for m in (a, b))
    turned = np.stack([-rb[:, 2], rb[:, 1], rb[:, 0]], -1)
    assert np.allclose(ra, turned, atol=1e-9)
    ridge = ra[np.isclose(ra[:, 1], ra[:, 1].max())]
    assert np.ptp(ridge[:, 0]) < 1e-9 < np.ptp(ridge[:, 2])      # the ridge runs along Z
    walls = lambda m: np.concatenate([c.vertices for c in components(m, "walls")])  # noqa: E731
    assert np.ptp(walls(a)[:, 0]) == pytest.approx(11.0) and np.ptp(walls(a)[:, 2]) == pytest.approx(7.0)


@pytest.mark.parametrize("pattern,expected", [(0, 0), (1, 4 * 4), (2, 2 * 4), (3, 8)])
def test_balcony_patterns(pattern, expected):
    values = GEN.values("panel5", {"balcony_pattern": pattern, "sections": 1, "windows": 4})
    assert parts(build(values), "balconies")[0] == expected == GEN.counts(values)["balconies"]


def test_counts_depend_only_on_discrete_values():
    rng = np.random.default_rng(5)
    a = random_values(rng)
    b = {**GEN.spec.random(rng), **{p.name: a[p.name] for p in GEN.spec.discrete}}
    ma, mb = build(a), build(b)
    assert torch.equal(ma.faces, mb.faces) and torch.equal(ma.groups, mb.groups)


def test_clamped_sizes_keep_parts_valid_at_the_extremes():
    spec = GEN.spec
    hi = {p.name: p.hi for p in spec.continuous}
    lo = {p.name: p.lo for p in spec.continuous}
    for values in (hi, lo, {**hi, "section_width": 4.0, "floor_height": 2.2, "depth": 4.0}):
        check_building(GEN.values("panel5", values), f"extreme {values}")


@pytest.mark.parametrize("preset", PRESETS)
def test_jacobian_matches_float64_central_differences(preset):
    values = GEN.values(preset)
    if values["floors"] > 5:                       # same code path, smaller mesh
        values = {**values, "floors": 4}
    theta, discrete = GEN.split(values)
    check = check_mesh_jacobian(lambda t: GEN.mesh(t, discrete).verts, theta)
    assert check.max_rel_error <= 1e-6, check


def test_window_parameters_do_not_move_the_roof_and_roof_parameters_move_only_the_roof():
    values = GEN.values("house2", {"roof_type": 2})
    theta, discrete = GEN.split(values)
    mesh = GEN.mesh(theta, discrete)
    J = mesh_jacobian(lambda t: GEN.mesh(t, discrete).verts, theta).reshape(mesh.n_verts, 3, -1)
    names = [p.name for p in GEN.spec.continuous]
    roof_g = mesh.group_names.index("roof")
    roof_rows = torch.unique(mesh.faces[mesh.groups == roof_g])
    other = torch.ones(mesh.n_verts, dtype=torch.bool)
    other[roof_rows] = False
    for name in ("window_width", "window_height", "window_sill", "frame_width", "window_inset"):
        col = names.index(name)
        assert torch.count_nonzero(J[roof_rows, :, col]) == 0, name
        assert torch.count_nonzero(J[:, :, col]) > 0, name
    for name in ("roof_height", "roof_ridge", "roof_overhang"):
        col = names.index(name)
        assert torch.count_nonzero(J[other, :, col]) == 0, name
        assert torch.count_nonzero(J[roof_rows, :, col]) > 0, name


def test_discrete_values_are_validated():
    theta, _ = GEN.split(GEN.values())
    with pytest.raises(ValueError, match=r"parameter 'roof_type': expected a value in \[0, 3\], got 4"):
        GEN.mesh(theta, {"roof_type": 4})
    with pytest.raises(ValueError, match=r"parameter 'wings': expected a value in \[0, 3\], got 4"):
        GEN.mesh(theta, {"wings": 4})
