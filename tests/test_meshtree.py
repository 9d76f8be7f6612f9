"""Mesh node trees: primitives and transforms as data, JSON files, closed parts, and the block-structured
analytic Jacobian against jacfwd and float64 central differences."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
import trimesh

from ipm.generators import get_generator
from ipm.generators.meshtree import (
    MESH_NODES,
    MeshLod,
    MeshTree,
    MeshTreeGenerator,
    is_mesh_tree_file,
    load_mesh_tree,
    mesh_node_from_dict,
    mesh_node_type,
    mesh_tree_from_json,
    mesh_tree_presets,
    mesh_tree_to_json,
    resolve_lod,
    rotation,
)
from ipm.jacobian import check_mesh_jacobian, mesh_jacobian
from ipm.sdf._math import axis_from_tilt, rotation_matrix

LOW = MeshLod(12, 6)
PRIMITIVES = ("box", "cylinder", "cone", "uv_sphere", "revolve", "extrude")
TRANSFORMS = {"translate": {"x": 0.3, "y": -0.2, "z": 0.5}, "rotate": {"angle": 30.0, "tilt": 40.0, "azimuth": 70.0},
              "scale": {"factor": 1.7}, "scale3": {"sx": 0.5, "sy": 2.0, "sz": 1.3}}


def tree_of(d) -> MeshTree:
    return mesh_tree_from_json(d)


def check_closed_parts(mesh):
    tm = trimesh.Trimesh(mesh.verts.detach().double().numpy(), mesh.faces.numpy(), process=False)
    comps = tm.split(only_watertight=False)
    assert len(comps) == len(mesh.group_names)
    for c in comps:
        assert c.is_watertight and c.is_winding_consistent and c.volume > 0
    return comps


# -- nodes -----------------------------------------------------------------------------------------

def test_registry_has_the_primitives_transforms_and_merge():
    assert set(PRIMITIVES) | set(TRANSFORMS) | {"merge"} <= set(MESH_NODES)
    with pytest.raises(ValueError, match="unknown mesh node type 'torus'; known: box, cone"):
        mesh_node_type("torus")


@pytest.mark.parametrize("name", PRIMITIVES)
def test_every_primitive_is_a_closed_outward_solid(name):
    node = mesh_node_type(name).make()
    mesh = MeshTree(node).mesh(MeshTree(node).theta(), LOW)
    check_closed_parts(mesh)
    assert mesh.n_verts == node.n_verts(LOW)


def test_primitive_volumes_match_their_polyhedra():
    s = LOW.segments
    ring = 0.5 * s * math.sin(2 * math.pi / s)                   # area of a unit-radius s-gon
    cases = [({"node": "box", "params": {"size_x": 1.0, "size_y": 2.0, "size_z": 3.0}}, 6.0),
             ({"node": "cylinder", "params": {"radius": 0.5, "height": 2.0}}, ring * 0.25 * 2.0),
             ({"node": "extrude", "size": 4, "params": {"height": 2.0, "x0": 1, "z0": 0, "x1": 0, "z1": -1,
                                                        "x2": -1, "z2": 0, "x3": 0, "z3": 1}}, 4.0)]
    for d, vol in cases:
        t = tree_of(d)
        mesh = t.mesh(t.theta(), LOW)
        assert check_closed_parts(mesh)[0].volume == pytest.approx(vol)


def test_sphere_approaches_the_ball_volume_with_the_level_of_detail():
    t = tree_of({"node": "uv_sphere", "params": {"radius": 1.0}})
    vol = [check_closed_parts(t.mesh(t.theta(), lod))[0].volume for lod in ("low", "high")]
    assert vol[0] < vol[1] < 4 / 3 * math.pi
    assert vol[1] == pytest.approx(4 / 3 * math.pi, rel=0.01)


def test_clockwise_extrusions_are_still_outward():
    d = {"node": "extrude", "size": 3, "params": {"x0": 0, "z0": 0, "x1": 1, "z1": 0, "x2": 0, "z2": 1}}
    for pts in (d, {**d, "params": {"x0": 0, "z0": 0, "x1": 0, "z1": 1, "x2": 1, "z2": 0}}):
        t = tree_of(pts)
        assert check_closed_parts(t.mesh(t.theta(), LOW))[0].volume == pytest.approx(0.5 * 0.5)


def test_node_validation_errors_name_the_problem():
    with pytest.raises(ValueError, match=r"node root/0 \(box\): unknown parameter 'size'"):
        mesh_node_from_dict({"node": "translate", "children": [{"node": "box", "params": {"size": 1}}]})
    with pytest.raises(ValueError, match=r"node root \(translate\): expected 1 child, got 0"):
        mesh_node_from_dict({"node": "translate"})
    with pytest.raises(ValueError, match="expected the profile to end above its start"):
        mesh_node_from_dict({"node": "revolve", "size": 2, "params": {"r0": 1, "y0": 1, "r1": 1, "y1": 0}})
    with pytest.raises(ValueError, match=r"radius': expected a value in \[0.001, 20.0\], got -1"):
        mesh_node_from_dict({"node": "uv_sphere", "params": {"radius": -1}})
    with pytest.raises(ValueError, match="node names must be unique"):
        tree_of({"node": "merge", "children": [{"node": "box", "name": "a"}, {"node": "box", "name": "a"}]})


@pytest.mark.parametrize("tilt,azimuth,angle", [(0, 0, 37), (90, 0, 90), (90, 90, -60), (33, 121, 250)])
def test_rotation_matches_the_sdf_rotate_convention(tilt, azimuth, angle):
    th = [torch.tensor([float(x)], dtype=torch.float64) for x in (angle, tilt, azimuth)]
    ref = rotation_matrix(axis_from_tilt(torch.tensor(float(tilt), dtype=torch.float64),
                                         torch.tensor(float(azimuth), dtype=torch.float64)),
                          torch.tensor(float(angle), dtype=torch.float64))
    assert torch.allclose(rotation(*th), ref)


@pytest.mark.parametrize("name,params", sorted(TRANSFORMS.items()))
def test_transforms_map_every_vertex_by_their_affine_map(name, params):
    base = {"node": "cone", "params": {"radius_bottom": 0.4, "radius_top": 0.2, "height": 0.8}}
    plain, moved = tree_of(base), tree_of({"node": name, "params": params, "children": [base]})
    v0 = plain.mesh(plain.theta(), LOW).verts
    v1 = moved.mesh(moved.theta(), LOW).verts
    node = moved.root
    A, b = node.affine(moved.theta()[:len(node.param_defs())])
    assert torch.allclose(v1, v0 @ A.T + b)
    check_closed_parts(moved.mesh(moved.theta(), LOW))      # rotations and positive scales keep faces outward


# -- trees and files -------------------------------------------------------------------------------

def test_parameters_are_named_by_label_and_pre_order_index():
    t = tree_of({"node": "merge", "children": [
        {"node": "translate", "params": {"y": 1.0}, "children": [{"node": "box"}]},
        {"node": "uv_sphere", "name": "ball"}]})
    assert t.spec.names == ("n1_translate.x", "n1_translate.y", "n1_translate.z", "n2_box.size_x",
                            "n2_box.size_y", "n2_box.size_z", "ball.radius")
    assert t.labels == ["n0_merge", "n1_translate", "n2_box", "ball"]


@pytest.mark.parametrize("preset", mesh_tree_presets())
def test_json_round_trip_is_exact(preset, tmp_path):
    tree = MeshTreeGenerator.from_preset(preset).tree
    path = tmp_path / f"{preset}.json"
    path.write_text(json.dumps(mesh_tree_to_json(tree)))
    assert is_mesh_tree_file(path)
    again = load_mesh_tree(path)
    assert again.spec == tree.spec
    assert torch.equal(again.mesh(again.theta(), LOW).verts, tree.mesh(tree.theta(), LOW).verts)
    gen = MeshTreeGenerator.from_file(path)
    assert gen.spec.names == tree.spec.names and gen.source == str(path)


def test_sdf_tree_files_are_not_mesh_tree_files(tmp_path):
    path = tmp_path / "csg.json"
    path.write_text(json.dumps({"tree": {"node": "sphere"}}))
    assert not is_mesh_tree_file(path)
    with pytest.raises(ValueError, match="expected generator 'meshtree', got 'sdftree'"):
        mesh_tree_from_json({"generator": "sdftree", "tree": {"node": "box"}})
    with pytest.raises(ValueError, match="mesh tree file not found"):
        load_mesh_tree(tmp_path / "missing.json")


def test_with_values_replaces_parameters_by_name():
    gen = get_generator("meshtree")
    tall = gen.tree.with_values({"top_at.y": 1.5})
    v = tall.mesh(tall.theta(), LOW).verts.detach()
    assert float(v[:, 1].max()) == pytest.approx(1.53)
    with pytest.raises(ValueError, match="unknown parameter"):
        gen.tree.with_values({"nope.x": 1})


# -- presets and generator -------------------------------------------------------------------------

@pytest.mark.parametrize("preset", mesh_tree_presets())
def test_presets_are_closed_parts_one_group_per_primitive(preset):
    gen = MeshTreeGenerator.from_preset(preset)
    mesh = gen.to_mesh(gen.values(), lod="medium")
    check_closed_parts(mesh)
    assert mesh.groups.max() == len(mesh.group_names) - 1


def test_table_value_presets_set_the_table_height():
    gen = get_generator("meshtree")
    heights = {}
    for variant in ("coffee_table", "table", "bar_table"):
        mesh = gen.to_mesh(gen.values(variant), lod="low")
        check_closed_parts(mesh)
        heights[variant] = float(mesh.verts[:, 1].max())
        assert float(mesh.verts[:, 1].min()) == pytest.approx(0.0, abs=1e-9)   # legs stand on the floor
    assert heights["coffee_table"] < heights["table"] < heights["bar_table"]


def test_lod_changes_counts_only():
    gen = MeshTreeGenerator.from_preset("snowman")
    theta, _ = gen.split(gen.values())
    a, b = gen.mesh(theta, {}, "low"), gen.mesh(theta, {}, "high")
    assert b.n_verts > a.n_verts
    assert torch.allclose(a.verts.amax(0), b.verts.amax(0), atol=0.02)
    assert resolve_lod({"segments": 5}).segments == 5
    with pytest.raises(ValueError, match="lod segments: expected an integer >= 3"):
        MeshLod(segments=2)


# -- Jacobians -------------------------------------------------------------------------------------

@pytest.mark.parametrize("preset", mesh_tree_presets())
def test_block_jacobian_equals_jacfwd_and_central_differences(preset):
    gen = MeshTreeGenerator.from_preset(preset)
    theta, _ = gen.split(gen.values())
    f = lambda t: gen.mesh(t, {}, LOW).verts          # noqa: E731
    J = gen.jacobian(theta, {}, LOW)
    J_fwd = mesh_jacobian(f, theta)
    assert J.shape == J_fwd.shape == (3 * f(theta).shape[0], theta.shape[0])
    assert torch.allclose(J, J_fwd, atol=1e-12, rtol=1e-10)
    check = check_mesh_jacobian(f, theta, J=J)
    assert check.max_rel_error <= 1e-6, check


def test_block_jacobian_through_nested_transforms_of_every_kind():
    leaf = {"node": "revolve", "size": 3, "params": {"r0": 0.3, "y0": 0.0, "r1": 0.5, "y1": 0.4, "r2": 0.2, "y2": 0.9}}
    d = leaf
    for name, params in TRANSFORMS.items():
        d = {"node": name, "params": params, "children": [d]}
    d = {"node": "merge", "children": [d, {"node": "rotate", "params": TRANSFORMS["rotate"], "children": [
        {"node": "extrude", "size": 5}]}]}
    tree = tree_of(d)
    theta = tree.theta()
    J = tree.jacobian(theta, LOW)
    J_fwd = mesh_jacobian(lambda t: tree.mesh(t, LOW).verts, theta)
    assert torch.allclose(J, J_fwd, atol=1e-12, rtol=1e-10)
    assert check_mesh_jacobian(lambda t: tree.mesh(t, LOW).verts, theta, J=J).max_rel_error <= 1e-6


def test_parameters_move_only_their_own_subtree():
    gen = get_generator("meshtree")
    theta, _ = gen.split(gen.values())
    mesh = gen.mesh(theta, {}, LOW)
    J = gen.jacobian(theta, {}, LOW).reshape(mesh.n_verts, 3, -1)
    names = list(gen.spec.names)
    top = mesh.group_names.index("top")
    top_rows = torch.unique(mesh.faces[mesh.groups == top])
    leg_rows = torch.unique(mesh.faces[mesh.groups == mesh.group_names.index("leg1")])
    col = names.index("top.size_x")
    assert torch.count_nonzero(J[top_rows, :, col]) > 0
    assert torch.count_nonzero(J[leg_rows, :, col]) == 0
    col = names.index("leg1_at.x")
    assert torch.count_nonzero(J[top_rows, :, col]) == 0
    assert torch.all(J[leg_rows, 0, col] == 1)


def test_float32_block_jacobian_matches_float64():
    gen = MeshTreeGenerator.from_preset("snowman")
    theta, _ = gen.split(gen.values())
    J64 = gen.jacobian(theta, {}, LOW)
    J32 = gen.jacobian(theta.float(), {}, LOW)
    assert J32.dtype == torch.float32
    assert np.allclose(J32.numpy(), J64.numpy(), atol=1e-4)
