"""Macro nodes defined as data: expressions, slots, Jacobians through them, user libraries."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from ipm import sdf
from ipm.jacobian import check_sdf_jacobian
from ipm.sdf.complex import eval_expr, load_library, macro_type
from ipm.sdf.node import all_node_types
from ipm.sdf.tree import Tree

SHIPPED = ["chair", "table", "mug", "shelf", "arched_window", "rotate_about", "rotate_about2d"]


def pts(n=1500, seed=0, lo=-1.5, hi=2.0):
    return torch.as_tensor(np.random.default_rng(seed).uniform(lo, hi, size=(n, 3)))


def test_shipped_macros_are_registered():
    types = all_node_types()
    for name in SHIPPED:
        assert name in types and hasattr(types[name], "template")
    assert len(types["chair"].params) == 6


def test_expressions():
    env = {"a": torch.tensor(2.0), "b": 3}
    assert eval_expr({"add": ["a", "b", 1]}, env) == 6
    assert eval_expr({"min": ["a", {"neg": "b"}]}, env) == -3
    assert eval_expr({"div": [{"mul": ["a", 3]}, {"sub": ["b", 1]}]}, env) == 3
    assert eval_expr({"max": [{"const": 7}, "a"]}, env) == 7


def test_rotate_about_equals_its_expansion():
    child = sdf.box(0.4, 0.2, 0.3)
    macro = sdf.rotate_about(35.0, 20.0, 10.0, 0.3, 0.2, -0.1, children=(child,))
    manual = child.translate(-0.3, -0.2, 0.1).rotate(35.0, 20.0, 10.0).translate(0.3, 0.2, -0.1)
    p = pts()
    assert torch.allclose(Tree(macro).sdf(None, p), Tree(manual).sdf(None, p), atol=1e-12)


def test_rotate_about_point_is_fixed():
    child = sdf.box(0.4, 0.2, 0.3).translate(0.3, 0.2, 0.0)
    macro = sdf.rotate_about(80.0, 0.0, 0.0, 0.3, 0.2, 0.0, children=(child,))
    centre = torch.tensor([[0.3, 0.2, 0.0]], dtype=torch.float64)
    assert torch.allclose(Tree(macro).sdf(None, centre), Tree(child).sdf(None, centre))


@pytest.mark.parametrize("name", ["chair", "table", "mug", "shelf", "arched_window"])
def test_macro_jacobian_through_expressions(name):
    tree = Tree(all_node_types()[name].make())
    lo, hi = tree.bounds()
    p = torch.as_tensor(np.random.default_rng(1).uniform(lo - 0.2, hi + 0.2, size=(1500, 3)))
    chk = check_sdf_jacobian(tree.sdf, tree.theta(), p)
    assert chk.max_rel_error <= 1e-6, chk
    # every outer parameter matters
    theta = tree.theta().requires_grad_(True)
    torch.sigmoid(-tree.sdf(theta, p) / 0.02).sum().backward()
    assert (theta.grad.abs() > 0).all(), theta.grad


def test_chair_dimensions_follow_parameters():
    chair = Tree(sdf.chair(seat_height=1.0, seat_thickness=0.1, back_height=0.8))
    top = torch.tensor([[0.0, 1.85, -0.35]], dtype=torch.float64)
    above = torch.tensor([[0.0, 1.95, -0.35]], dtype=torch.float64)
    assert chair.sdf(None, top) < 0 < chair.sdf(None, above)


def test_shelf_board_count_is_discrete():
    tree = Tree(sdf.shelf(boards=3))
    assert [p.name for p in tree.spec.discrete] == ["n0_shelf.boards"]
    mid = torch.tensor([[0.0, 0.8, 0.0]], dtype=torch.float64)  # middle board exists for 3 boards
    assert tree.sdf(None, mid) < 0
    assert tree.with_values({"n0_shelf.boards": 2}).sdf(None, mid) > 0


def test_user_library_folder(tmp_path):
    spec = {
        "name": "test_pillar", "params": [{"name": "h", "default": 1.0, "lo": 0.1, "hi": 3.0}],
        "tree": {"node": "translate", "params": {"y": {"mul": ["h", 0.5]}},
                 "children": [{"node": "cylinder", "params": {"radius": 0.1, "height": "h"}}]},
    }
    (tmp_path / "pillar.json").write_text(json.dumps(spec))
    assert load_library([tmp_path]) == ["test_pillar"]
    tree = Tree(sdf.test_pillar(h=2.0))
    assert tree.sdf(None, torch.tensor([[0.0, 1.95, 0.0]], dtype=torch.float64)) < 0
    assert tree.bounds()[1][1] == pytest.approx(2.0)


@pytest.mark.parametrize("spec, message", [
    ({"params": [], "tree": {"node": "sphere"}}, "missing the 'name' field"),
    ({"name": "m1", "params": [], "tree": {"node": "sphere", "params": {"radius": "r"}}}, "unknown name 'r'"),
    ({"name": "m2", "params": [{"name": "r", "default": 1, "lo": 0, "hi": 2}],
      "tree": {"node": "sphere", "params": {"radius": {"pow": ["r", 2]}}}}, "unknown operation 'pow'"),
    ({"name": "m3", "params": [{"name": "r", "default": 1, "lo": 0, "hi": 2}],
      "tree": {"node": "sphere", "params": {"radius": {"sub": ["r"]}}}}, "sub takes 2"),
    ({"name": "m4", "params": [{"name": "r", "default": 1, "lo": 0, "hi": 2}],
      "tree": {"node": "sphere", "params": {"size": "r"}}}, "node sphere has no parameter 'size'"),
    ({"name": "m5", "params": [{"name": "r", "default": 1.0, "lo": 0, "hi": 2}],
      "tree": {"node": "repeat", "params": {"count": "r"}, "children": [{"node": "sphere"}]}},
     "discrete parameter repeat.count depends on a continuous parameter"),
    ({"name": "m6", "params": [], "tree": {"node": "union", "children": [{"node": "sphere"}]}},
     "expected 2 children"),
])
def test_bad_macro_files(spec, message):
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")):
        macro_type(spec, "test.json")
