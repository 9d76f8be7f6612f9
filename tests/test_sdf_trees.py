"""Tree files: nested JSON <-> flat form <-> operator-built trees, and validation errors."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from ipm import sdf
from ipm.generators.sdftree import tree_presets
from ipm.sdf.tree import Tree, from_flat, load_tree, node_from_dict, node_to_dict, to_flat, tree_from_json


def classic_csg():
    cyl = sdf.cylinder(0.3, 1.2)
    holes = sdf.union_n(children=(cyl, cyl.rotate(90, 90, 0), cyl.rotate(90, 90, 90)))
    return (sdf.sphere(0.65) & sdf.box(1, 1, 1)) - holes


def points(n=2000, seed=0):
    return torch.as_tensor(np.random.default_rng(seed).uniform(-1.2, 1.2, size=(n, 3)))


def test_operator_tree_equals_preset_file():
    built = Tree(classic_csg())
    loaded = load_tree(tree_presets()["csg"])
    p = points()
    assert torch.equal(built.sdf(None, p), loaded.sdf(None, p))
    assert built.spec.names == loaded.spec.names


@pytest.mark.parametrize("preset", sorted(tree_presets()))
def test_nested_flat_roundtrip_is_exact(preset):
    tree = load_tree(tree_presets()[preset])
    nested = json.loads(json.dumps(node_to_dict(tree.root)))
    flat = json.loads(json.dumps(to_flat(tree.root)))
    a, b = Tree(node_from_dict(nested)), Tree(from_flat(flat))
    p = points()
    ref = tree.sdf(None, p)
    assert torch.equal(a.sdf(None, p), ref) and torch.equal(b.sdf(None, p), ref)
    # and back again: the files themselves are identical
    assert node_to_dict(a.root) == nested
    assert to_flat(b.root) == flat


def test_flat_form_of_classic_csg():
    flat = to_flat(classic_csg())
    assert flat["structure"] == ["subtraction", "intersection", "sphere", "box", "union_n:3", "cylinder",
                                 "rotate", "cylinder", "rotate", "cylinder"]
    assert flat["params"][:4] == [0.65, 1.0, 1.0, 1.0]


def test_sized_and_discrete_nodes_roundtrip():
    node = sdf.union(sdf.revolution(1.0, 0.3, 0.5, 0.2, 0.4, size=4),
                     sdf.box(0.2, 0.2, 0.2).repeat(1, 4, 0.3)) if False else (
        sdf.revolution(1.0, 0.3, 0.5, 0.2, 0.4, size=4) | sdf.box(0.2, 0.2, 0.2).repeat(1, 4, 0.3))
    flat = to_flat(node)
    assert "revolution:4" in flat["structure"]
    back = from_flat(flat)
    p = points()
    assert torch.equal(Tree(back).sdf(None, p), Tree(node).sdf(None, p))
    assert Tree(node).spec.discrete[0].name == "n2_repeat.axis"


def test_with_values_changes_discrete_counts():
    tree = Tree(sdf.box(0.2, 0.2, 0.2).repeat(0, 3, 0.5))
    five = tree.with_values({"n0_repeat.count": 5})
    p = torch.tensor([[1.0, 0.0, 0.0]], dtype=torch.float64)
    assert tree.sdf(None, p) > 0 and five.sdf(None, p) < 0


@pytest.mark.parametrize("data, message", [
    ({"node": "blob"}, "node root: unknown node type 'blob'; known:"),
    ({"node": "union", "children": [{"node": "sphere"}]}, "node root (union): expected 2 children, got 1"),
    ({"node": "circle"}, "node root (circle): the root must be a 3D node, got a 2D node"),
    ({"node": "extrude", "children": [{"node": "sphere"}]}, "node root (extrude): expected 2D children, got a 3D sphere"),
    ({"node": "union", "children": [{"node": "sphere"}, {"node": "sphere", "params": {"radius": -1}}]},
     "node root/1 (sphere): parameter 'radius': expected a value in [0.001, 20.0], got -1.0"),
    ({"node": "sphere", "params": {"size": 1}}, "node root (sphere): unknown parameter 'size'; valid names: radius"),
    ({"node": "sphere", "params": {"radius": float("nan")}}, "node root (sphere): parameter 'radius': expected a finite"),
    ({"node": "translate", "children": [{"node": "union", "children": [{"node": "sphere"}, {"node": "circle"}]}]},
     "node root/0 (union): children must all be 2D or all 3D"),
    ({"node": "sphere", "colour": "red"}, "node root: unknown field(s) colour"),
    ({"structure": ["union", "sphere"], "params": [0.5]}, "flat tree: structure ended early at node root/1"),
    ({"structure": ["sphere"], "params": [0.5, 1.0]}, "flat tree: 0 tokens and 1 values left over"),
    ({"structure": ["union_n", "sphere"], "params": [0.5]}, "node root (union_n): variadic nodes are written 'union_n:k'"),
])
def test_validation_errors_name_the_path(data, message):
    with pytest.raises(ValueError) as e:
        tree_from_json(data)
    assert str(e.value).startswith(message), str(e.value)
    assert "\n" not in str(e.value)


def test_missing_and_malformed_files(tmp_path):
    with pytest.raises(ValueError, match="tree file not found"):
        load_tree(tmp_path / "nope.json")
    bad = tmp_path / "bad.json"
    bad.write_text('{"node": "sphere",')
    with pytest.raises(ValueError, match="is not valid JSON"):
        load_tree(bad)


def test_chaining_picks_2d_variants():
    shape = sdf.rect(1, 0.5).rotate(30).translate(0.2, 0.1)
    assert shape.type_name == "translate2d" and shape.children[0].type_name == "rotate2d"
    with pytest.raises(AttributeError):
        sdf.sphere(1).extrudez()


def test_tree_gradients_flow_to_every_parameter():
    tree = load_tree(tree_presets()["csg"])
    theta = tree.theta().requires_grad_(True)
    p = points(20000)
    d = tree.sdf(theta, p)
    (torch.sigmoid(-d / 0.05)).sum().backward()
    assert torch.isfinite(theta.grad).all()
    # every continuous parameter changes the shape somewhere
    assert (theta.grad.abs() > 0).all(), theta.grad


def test_unknown_tree_preset_is_bad_input_listing_the_known_names():
    from ipm.errors import InputError
    from ipm.generators.sdftree import SdfTreeGenerator, tree_presets

    with pytest.raises(InputError, match="unknown tree preset 'nosuch'; known: .*mug"):
        SdfTreeGenerator.from_preset("nosuch")
    assert SdfTreeGenerator.from_preset("mug").name == "mug"
    assert "mug" in tree_presets()
