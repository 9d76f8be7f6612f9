"""Exact CSG meshes (ipm.sdf.exact) against the slow reference, the SDF itself: vertices on its zero set, the
analytic volume within the error of ``segments`` straight pieces per circle, a closed and consistently wound
surface, and every point away from the surface on the same side as the SDF says (by the mesh's winding
number). Then the presets, the fallback of nodes without an exact form, and ``ipm generate --mesher exact``."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
import trimesh

from ipm.sdf.exact import MAX_SEGMENTS, MIN_SEGMENTS, exact_mesh
from ipm.sdf.node import node_type
from ipm.sdf.tree import Tree
from tests.conftest import refusal, run_cli

PI = math.pi
CURVED = 1e-2  # relative volume error allowed at 64 segments (a 64-gon holds 99.84 % of its circle's area)
FLAT = 1e-9
FLAT_2D = 1e-7  # cross-sections (Clipper2 inside manifold3d) round their points to about 1e-8


def n(type_name: str, *values, children=(), **kw):
    """A node of type ``type_name`` (positional values in declaration order)."""
    return node_type(type_name).make(*values, children=tuple(children), **kw)


def winding(verts: np.ndarray, faces: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Generalized winding number ``(P,)`` of a closed mesh at points ``(P, 3)`` (Van Oosterom and Strackee's
    solid angle of each triangle, summed): about 1 inside, 0 outside."""
    out = np.empty(len(pts))
    for i in range(0, len(pts), 64):
        p = pts[i:i + 64, None, :]
        a, b, c = (verts[faces[:, k]][None] - p for k in range(3))
        la, lb, lc = (np.linalg.norm(x, axis=-1) for x in (a, b, c))
        det = np.einsum("pfi,pfi->pf", a, np.cross(b, c))
        den = la * lb * lc + np.einsum("pfi,pfi->pf", a, b) * lc + np.einsum("pfi,pfi->pf", b, c) * la \
            + np.einsum("pfi,pfi->pf", c, a) * lb
        out[i:i + 64] = 2.0 * np.arctan2(det, den).sum(1) / (4.0 * PI)
    return out


def check_against_sdf(node, volume: float | None, rel: float, *, on_surface: float = 1e-6, segments: int = 64):
    """The invariants of an exact mesh of ``node`` (see the module docstring); returns the ExactMesh."""
    tree = Tree(node)
    got = exact_mesh(tree, segments=segments)
    assert got.fallback == () and not got.grid_only
    tm = trimesh.Trimesh(got.mesh.verts.numpy(), got.mesh.faces.numpy(), process=False)
    assert tm.is_watertight and tm.is_winding_consistent and tm.volume > 0
    assert got.mesh.verts.dtype == torch.float64 and got.mesh.faces.dtype == torch.int64
    lo, hi = tree.bounds()
    size = float(np.max(hi - lo))
    assert tree.sdf(None, got.mesh.verts).abs().max().item() <= on_surface * size
    if volume is not None:
        assert tm.volume == pytest.approx(volume, rel=rel)
    pts = np.random.default_rng(0).uniform(lo - 0.1 * size, hi + 0.1 * size, (400, 3))
    d = tree.sdf(None, torch.from_numpy(pts)).numpy()
    away = np.abs(d) > 0.01 * size
    inside = winding(tm.vertices, tm.faces, pts[away]) > 0.5
    assert np.array_equal(inside, d[away] < 0)
    return got


def frustums(h, radii):
    """Volume of a revolution node's profile: cone frustums between even heights."""
    dy = h / (len(radii) - 1)
    return sum(PI * dy / 3 * (a * a + a * b + b * b) for a, b in zip(radii, radii[1:]))


def round_box_volume(sizes, r):
    a, b, c = (s - 2 * r for s in sizes)
    return a * b * c + 2 * r * (a * b + b * c + a * c) + PI * r * r * (a + b + c) + 4 / 3 * PI * r ** 3


PRIMITIVES = [
    ("box", (0.6, 0.8, 1.0), 0.48, FLAT),
    ("sphere", (0.5,), 4 / 3 * PI * 0.125, CURVED),
    ("round_box", (0.6, 0.8, 1.0, 0.1), round_box_volume((0.6, 0.8, 1.0), 0.1), CURVED),
    ("cylinder", (0.4, 1.0), PI * 0.16, CURVED),
    ("cone", (0.5, 0.2, 1.0), PI / 3 * (0.25 + 0.1 + 0.04), CURVED),
    ("cone", (0.5, 0.0, 0.8), PI / 3 * 0.25 * 0.8, CURVED),
    ("capsule", (0.25, 0.8), PI * 0.0625 * 0.8 + 4 / 3 * PI * 0.25 ** 3, CURVED),
    ("torus", (0.5, 0.15), 2 * PI * PI * 0.5 * 0.15 ** 2, CURVED),
    ("hex_prism", (0.4, 0.7), 2 * math.sqrt(3) * 0.16 * 0.7, FLAT),
    ("tri_prism", (0.5, 0.8), 3 * math.sqrt(3) / 4 * 0.25 * 0.8, FLAT),
    ("pyramid", (1.0, 0.8), 0.8 / 3, FLAT),
    ("octahedron", (0.5,), 4 / 3 * 0.125, FLAT),
    ("ellipsoid", (0.5, 0.3, 0.4), 4 / 3 * PI * 0.06, CURVED),
]


@pytest.mark.parametrize(("name", "values", "volume", "rel"), PRIMITIVES, ids=[f"{p[0]}{p[1]}" for p in PRIMITIVES])
def test_primitive_matches_its_sdf(name, values, volume, rel):
    check_against_sdf(n(name, *values), volume, rel)


def test_revolution_matches_its_sdf():
    radii = (0.3, 0.45, 0.2, 0.35)
    check_against_sdf(n("revolution", 1.2, *radii, size=4), frustums(1.2, radii), CURVED)


def test_flat_primitives_keep_their_vertices_exactly():
    """To rounding (the SDF adds 1e-20 under its square roots; sdHexPrism has its constants to 16 digits)."""
    for name, values, _, rel in PRIMITIVES:
        if rel == FLAT:
            got = exact_mesh(n(name, *values))
            assert Tree(n(name, *values)).sdf(None, got.mesh.verts).abs().max().item() < 1e-8, name


LIFTS_2D = [
    ("circle", (0.4,), PI * 0.16, CURVED),
    ("rect", (0.6, 0.9), 0.54, FLAT_2D),
    ("round_rect", (0.6, 0.9, 0.15), 0.54 - (4 - PI) * 0.15 ** 2, CURVED),
    ("triangle", (0.0, 0.5, 0.5, -0.4, -0.5, -0.4), 0.45, FLAT_2D),  # clockwise: either orientation works
    ("ellipse", (0.5, 0.3), PI * 0.15, CURVED),
    ("wind_rose", (0.5, 0.25) * 4, 8 * 0.5 * 0.5 * 0.25 * math.sin(PI / 4), FLAT_2D),
]


@pytest.mark.parametrize(("name", "values", "area", "rel"), LIFTS_2D, ids=[p[0] for p in LIFTS_2D])
def test_extruded_2d_primitive_matches_its_sdf(name, values, area, rel):
    check_against_sdf(n("extrude", 0.7, children=[n(name, *values)]), area * 0.7, rel)


def test_polygon_and_2d_transforms_and_booleans():
    square = n("polygon", 0.0, -0.3, 0.3, 0.0, 0.0, 0.3, -0.3, 0.0, size=4)  # a diamond, area 0.18
    turned = n("rotate2d", 30.0, children=[n("translate2d", 0.2, 0.1, children=[n("rect", 0.8, 0.2)])])
    section = n("subtraction", children=[n("union", children=[square, turned]), n("circle", 0.1)])
    check_against_sdf(n("extrude", 0.5, children=[section]), None, CURVED)
    placed = n("place2d", 0.1, -0.2, 1.5, children=[n("scale2d", 0.8, children=[square])])
    check_against_sdf(n("extrude", 0.5, children=[placed]), 0.18 * (0.8 * 1.5) ** 2 * 0.5, FLAT_2D)


def test_revolve_matches_its_sdf():
    """A circle of radius a at distance R from the axis: a torus, 2 pi^2 R a^2 (Pappus)."""
    ring = n("revolve", 0.5, children=[n("translate2d", 0.0, 0.2, children=[n("circle", 0.15)])])
    check_against_sdf(ring, 2 * PI * PI * 0.5 * 0.15 ** 2, CURVED)
    half = n("revolve", 0.0, children=[n("rect", 0.8, 0.5)])  # the part at x >= 0 only: a cylinder of radius 0.4
    check_against_sdf(half, PI * 0.16 * 0.5, CURVED)


def test_transforms_match_their_sdf():
    box = n("box", 0.6, 0.3, 0.2)
    v = 0.036
    check_against_sdf(n("translate", 0.3, -0.2, 0.1, children=[box]), v, FLAT)
    check_against_sdf(n("scale", 1.7, children=[box]), v * 1.7 ** 3, FLAT)
    check_against_sdf(n("place", 1.0, 2.0, -3.0, 0.5, children=[box]), v * 0.125, FLAT)
    check_against_sdf(n("rotate", 35.0, 40.0, 70.0, children=[box]), v, FLAT)
    check_against_sdf(n("scale3", 1.5, 0.5, 2.0, children=[n("sphere", 0.4)]), 4 / 3 * PI * 0.064 * 1.5, CURVED)


def test_mirror_matches_its_sdf():
    """The kept half and its reflection: a child astride the plane, and one wholly on the kept side."""
    astride = n("translate", 0.1, 0.0, 0.0, children=[n("box", 0.6, 0.3, 0.2)])
    check_against_sdf(n("mirror", 0, 0.0, children=[astride]), 2 * 0.4 * 0.06, FLAT)
    apart = n("translate", 0.0, 0.0, 0.6, children=[n("cylinder", 0.2, 0.5)])
    check_against_sdf(n("mirror", 2, 0.1, children=[apart]), 2 * PI * 0.04 * 0.5, CURVED)


def test_repeat_matches_its_sdf_when_the_child_fits_its_cell():
    check_against_sdf(n("repeat", 0, 4, 0.5, children=[n("sphere", 0.2)]), 4 * 4 / 3 * PI * 0.008, CURVED)


def test_planes_trim_exactly():
    box = n("box", 1.0, 1.0, 1.0)
    plane = n("plane", 0.0, 0.0, 0.2)  # y <= 0.2
    check_against_sdf(n("intersection", children=[plane, box]), 0.7, FLAT)
    check_against_sdf(n("subtraction", children=[box, plane]), 0.3, FLAT)
    moved = n("translate", 0.0, -0.3, 0.0, children=[n("plane", 30.0, 45.0, 0.0)])  # kept finite: its 40-cube
    check_against_sdf(n("intersection", children=[box, moved]), None, FLAT)


def test_csg_preset_is_closed_with_its_sharp_edges():
    """The rims of the three holes on the box's faces are 90-degree edges of the exact mesh (within the
    chord of a 64-gon), and not of the marching-cubes mesh."""
    from ipm.generators import get_generator

    gen = get_generator("csg")
    got = check_against_sdf(gen.tree.root, None, CURVED, on_surface=2e-3)
    t = np.linspace(0, 2 * PI, 97)[:-1]
    rims = np.concatenate([np.roll(np.stack([np.full_like(t, s * 0.5), 0.3 * np.cos(t), 0.3 * np.sin(t)], 1), k, 1)
                           for s in (-1, 1) for k in range(3)])
    assert _sharp_distance(got.mesh, rims, 80.0).max() < 0.3 * (1 - math.cos(PI / 64)) + 1e-6
    grid = gen.to_mesh(gen.values(), resolution=128)
    assert np.median(_sharp_distance(grid, rims, 80.0)) > 0.005


def _sharp_distance(mesh, pts: np.ndarray, angle: float) -> np.ndarray:
    """Distance ``(P,)`` from each point to the nearest edge whose faces meet at more than ``angle`` degrees."""
    tm = trimesh.Trimesh(mesh.verts.numpy(), mesh.faces.numpy(), process=False)
    edges = tm.face_adjacency_edges[np.degrees(tm.face_adjacency_angles) > angle]
    if len(edges) == 0:
        return np.full(len(pts), np.inf)
    a, b = tm.vertices[edges[:, 0]], tm.vertices[edges[:, 1]]
    ab = b - a
    s = np.clip(np.einsum("pei,ei->pe", pts[:, None] - a[None], ab) / np.einsum("ei,ei->e", ab, ab), 0, 1)
    return np.linalg.norm(pts[:, None] - (a[None] + s[..., None] * ab[None]), axis=-1).min(1)


@pytest.mark.parametrize("name", ["chair", "table", "shelf", "mug"])
def test_macro_presets_are_walked_exactly(name):
    from ipm.generators import get_generator

    check_against_sdf(get_generator(name).tree.root, None, CURVED, on_surface=2e-3)


def test_smooth_union_falls_back_and_is_named():
    blend = n("smooth_union", 0.1, children=[n("box", 0.6, 0.6, 0.6), n("sphere", 0.35)], name="blend")
    cut = n("subtraction", children=[blend, n("translate", 0.0, 0.3, 0.0, children=[n("box", 0.2, 0.4, 0.2)])])
    got = exact_mesh(cut, resolution=64)
    assert got.fallback == ("blend",) and not got.grid_only
    tm = got.mesh.to_trimesh()
    assert tm.is_watertight and tm.volume > 0
    assert exact_mesh(n("round", 0.05, children=[n("box", 0.5, 0.5, 0.5)]), resolution=32).fallback == ("n0_round",)
    lifted = n("extrude", 0.3, children=[n("shell2d", 0.05, children=[n("circle", 0.4)])])
    assert exact_mesh(lifted, resolution=32).fallback == ("n0_extrude (n1_shell2d)",)


def test_settings_are_checked():
    from ipm.cli import generate
    from ipm.errors import InputError

    for bad in (MIN_SEGMENTS - 1, MAX_SEGMENTS + 1, 2.5, True):
        with pytest.raises(InputError, match="segments"):
            exact_mesh(n("sphere", 0.5), segments=bad)
    assert (generate.MIN_SEGMENTS, generate.MAX_SEGMENTS) == (MIN_SEGMENTS, MAX_SEGMENTS)
    more = exact_mesh(n("cylinder", 0.5, 1.0), segments=200).mesh.to_trimesh().volume
    fewer = exact_mesh(n("cylinder", 0.5, 1.0), segments=8).mesh.to_trimesh().volume
    assert fewer < more < PI * 0.25


def test_cli_generate_exact(tmp_path, capsys):
    code, out, err = run_cli(["generate", "csg", "--mesher", "exact", "-o", tmp_path / "x.obj"], capsys)
    assert code == 0 and "faces" in out and err == ""
    mesh = trimesh.load(tmp_path / "x.obj", process=False)
    assert mesh.is_watertight and (tmp_path / "x.params.json").is_file()
    line = refusal("dishes", *run_cli(["generate", "dishes", "--mesher", "exact", "-o", tmp_path / "d.obj"], capsys))
    assert "SDF trees only" in line and not (tmp_path / "d.obj").exists()
    line = refusal("segments", *run_cli(["generate", "csg", "--mesher", "exact", "--segments", "2", "-o",
                                         tmp_path / "s.obj"], capsys))
    assert "--segments" in line
    refusal("mesher", *run_cli(["generate", "csg", "--mesher", "marching", "-o", tmp_path / "m.obj"], capsys))


def test_cli_warns_about_fallback_nodes(tmp_path, capsys):
    tree = {"tree": {"node": "union", "children": [
        {"node": "box"}, {"node": "smooth_union", "name": "soft", "params": {"k": 0.1}, "children": [
            {"node": "sphere", "params": {"radius": 0.3}}, {"node": "translate", "params": {"x": 0.4},
                                                            "children": [{"node": "sphere"}]}]}]}}
    path = tmp_path / "soft.json"
    path.write_text(json.dumps(tree))
    code, out, err = run_cli(["generate", path, "--mesher", "exact", "--resolution", "48", "-o", tmp_path / "s.obj"],
                             capsys)
    lines = err.strip().splitlines()
    assert code == 0 and len(lines) == 1 and lines[0].startswith("ipm: warning:") and "soft" in lines[0]


def test_a_refused_fallback_mesh_makes_the_whole_tree_marching_cubes(monkeypatch):
    from ipm.sdf import exact

    def refuse(walk, node):
        raise exact._GridRefused("not a 2-manifold")

    monkeypatch.setattr(exact._Walk, "grid", refuse)
    tree = n("union", children=[n("box", 0.5, 0.5, 0.5), n("round", 0.05, children=[n("sphere", 0.3)])])
    got = exact_mesh(tree, resolution=32)
    assert got.grid_only and got.fallback == ("n2_round",) and got.mesh.n_faces > 0
