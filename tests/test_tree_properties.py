"""The shared tree framework (ipm.tree), by properties over random trees of every registered node type
(hypothesis): JSON round trips of SDF and mesh trees, finite SDF values and gradients everywhere
(origin and axes included); a node type from a throwaway package; the depth limit; macro libraries
that repeat or contradict a shipped macro."""

from __future__ import annotations

import json
import shutil

import pytest
import torch
from conftest import throwaway_member
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ipm.errors import InputError
from ipm.generators.meshtree import MESH_NODES, MeshLod, mesh_tree_from_json, mesh_tree_to_json
from ipm.sdf.complex import LIBRARY_DIR, load_library
from ipm.sdf.node import NODES
from ipm.sdf.tree import Tree, from_flat, load_tree, to_flat, tree_from_json, tree_to_json
from ipm.tree import MAX_DEPTH, same_tree

SETTINGS = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
LOW = MeshLod(8, 4)


def values_for(draw, cls, size) -> dict:
    """Random in-range values for every parameter of ``cls`` at ``size``."""
    out = {}
    for p in cls.param_defs_for(size):
        if p.continuous:
            out[p.name] = draw(st.floats(float(p.lo), float(p.hi), allow_nan=False, allow_infinity=False))
        else:
            out[p.name] = draw(st.integers(int(p.lo), int(p.hi)))
    return out


def n_children(draw, cls) -> int:
    return cls.arity if cls.arity is not None else draw(st.integers(cls.min_children, cls.min_children + 1))


@st.composite
def sdf_nodes(draw, dim: int = 3, depth: int = 3, cls=None):
    """A random SDF node tree of output dimension ``dim`` with at most ``depth`` levels (its root of
    type ``cls`` if given)."""
    types = [cls for _, cls in NODES.items()
             if (cls.dim == dim or cls.dim == 0) and (depth > 1 or cls.arity == 0)]
    cls = cls or draw(st.sampled_from(types))
    size = draw(st.integers(cls.min_size, cls.min_size + 3)) if cls.sized else None
    kid_dim = cls.child_dim or cls.dim or dim
    kids = tuple(draw(sdf_nodes(kid_dim, depth - 1)) for _ in range(n_children(draw, cls)))
    name = draw(st.sampled_from([None, None, "part"]))
    return cls.from_values(values_for(draw, cls, size), children=kids, size=size, name=name)


def unique_names(node, seen=None):
    """Drop repeated names (labels must be unique in a tree)."""
    seen = set() if seen is None else seen
    name = node.name if node.name not in seen else None
    if name:
        seen.add(name)
    kids = tuple(unique_names(c, seen) for c in node.children)
    return type(node)._new(node.values, kids, node.size, name)


@st.composite
def sdf_trees(draw, cls=None):
    """A random 3D tree (with a root of type ``cls`` if given: 2D roots are extruded)."""
    node = draw(sdf_nodes((cls.dim or 3) if cls else 3, 3, cls))
    if node.out_dim == 2:
        node = NODES.get("extrude").make(0.5, children=(node,))
    return Tree(unique_names(node))


@st.composite
def mesh_nodes(draw, depth: int = 3):
    """A random mesh node tree; nodes whose random values are invalid (a revolve profile that goes down,
    a flat extrusion) fall back to their defaults."""
    types = [cls for _, cls in MESH_NODES.items() if depth > 1 or cls.arity == 0]
    cls = draw(st.sampled_from(types))
    size = draw(st.integers(cls.min_size, cls.min_size + 3)) if cls.sized else None
    kids = tuple(draw(mesh_nodes(depth - 1)) for _ in range(n_children(draw, cls)))
    values = values_for(draw, cls, size)
    try:
        return cls.from_values(values, children=kids, size=size)
    except InputError:
        return cls.make(children=kids)


def probe_points(seed: int) -> torch.Tensor:
    """Random points plus the origin and points on the axes, ``(N, 3)`` float64."""
    g = torch.Generator().manual_seed(seed)
    rand = (torch.rand(64, 3, generator=g, dtype=torch.float64) - 0.5) * 6.0
    t = torch.tensor([0.0, 0.5, -1.0, 2.0], dtype=torch.float64)
    axes = torch.cat([torch.stack([t, 0 * t, 0 * t], -1), torch.stack([0 * t, t, 0 * t], -1),
                      torch.stack([0 * t, 0 * t, t], -1)])
    return torch.cat([rand, axes])


# -- SDF trees -------------------------------------------------------------------------------------

@SETTINGS
@given(tree=sdf_trees(), seed=st.integers(0, 2**16))
def test_sdf_json_round_trip_gives_an_equal_tree_and_identical_values(tree, seed):
    again = tree_from_json(json.loads(json.dumps(tree_to_json(tree))))
    assert same_tree(again.root, tree.root)
    assert again.spec == tree.spec
    p = probe_points(seed)
    assert torch.equal(again.sdf(None, p), tree.sdf(None, p))
    flat = from_flat(json.loads(json.dumps(to_flat(tree.root))))
    assert torch.equal(Tree(flat).sdf(None, p), tree.sdf(None, p))


@SETTINGS
@given(tree=sdf_trees(), seed=st.integers(0, 2**16))
def test_sdf_values_and_gradients_are_finite_everywhere(tree, seed):
    check_finite(tree, seed)


@pytest.mark.parametrize("name", NODES.names())
@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_every_node_type_round_trips_and_stays_finite(name, data):
    """Each registered type at the root, random in-range values, random subtrees below."""
    tree = data.draw(sdf_trees(NODES.get(name)))
    again = tree_from_json(json.loads(json.dumps(tree_to_json(tree))))
    assert same_tree(again.root, tree.root)
    check_finite(tree, data.draw(st.integers(0, 2**16)))


def check_finite(tree: Tree, seed: int) -> None:
    """Values and gradients (points and parameters) are finite at random and axis points."""
    p = probe_points(seed).requires_grad_(True)
    theta = tree.theta().requires_grad_(True)
    d = tree.sdf(theta, p)
    assert d.shape == p.shape[:1] and torch.isfinite(d).all()
    gp, gt = torch.autograd.grad(d.sum(), (p, theta), allow_unused=True)
    assert torch.isfinite(gp).all()
    assert gt is None or torch.isfinite(gt).all()


# -- mesh trees ------------------------------------------------------------------------------------

@SETTINGS
@given(node=mesh_nodes())
def test_mesh_json_round_trip_gives_an_equal_tree_and_identical_meshes(node):
    from ipm.generators.meshtree import MeshTree

    tree = MeshTree(node)
    again = mesh_tree_from_json(json.loads(json.dumps(mesh_tree_to_json(tree))))
    assert same_tree(again.root, tree.root)
    assert again.spec == tree.spec
    a, b = tree.mesh(tree.theta(), LOW), again.mesh(again.theta(), LOW)
    assert torch.equal(a.verts, b.verts) and torch.equal(a.faces, b.faces)


def test_every_registered_node_type_is_drawn():
    """The strategies above sample from the registries: they hold every node family member."""
    assert {"sphere", "union", "translate2d", "extrude", "arched_window"} <= set(NODES.names())
    assert {"box", "merge", "rotate", "revolve"} <= set(MESH_NODES.names())


# -- a node type from a throwaway package ----------------------------------------------------------

BLOB = '''
from ipm.sdf._boxes import sym
from ipm.sdf._math import length3
from ipm.sdf.node import P, primitive


@primitive(3, "tmp_blob", P("radius", 0.3), box=lambda r: sym(r, r, r))
def TmpBlob(p, r):
    """A throwaway sphere (tests only)."""
    return length3(p[..., 0], p[..., 1], p[..., 2]) - r
'''


def test_a_node_type_is_one_file_in_a_registered_package(tmp_path, monkeypatch):
    with throwaway_member(NODES, "tmp_blob", BLOB, tmp_path, monkeypatch, "ipm_throwaway_nodes"):
        assert "tmp_blob" in NODES
        cls = NODES.get("tmp_blob")
        assert cls.__doc__.startswith("A throwaway sphere")
        tree = tree_from_json({"tree": {"node": "translate", "params": {"x": 0.5},
                                        "children": [{"node": "tmp_blob", "params": {"radius": 0.4}}]}})
        again = tree_from_json(json.loads(json.dumps(tree_to_json(tree))))
        assert same_tree(again.root, tree.root)
        p = torch.tensor([[0.5, 0.0, 0.0], [0.5, 0.4, 0.0]], dtype=torch.float64)
        assert torch.allclose(again.sdf(None, p), torch.tensor([-0.4, 0.0], dtype=torch.float64))


CUBE = '''
from ipm.generators.meshtree.node import register
from ipm.generators.meshtree.nodes.primitives import Box


@register
class TmpCube(Box):
    """A throwaway box (tests only)."""

    type_name = "tmp_cube"
'''


def test_a_mesh_node_type_is_one_file_in_a_registered_package(tmp_path, monkeypatch):
    with throwaway_member(MESH_NODES, "tmp_cube", CUBE, tmp_path, monkeypatch, "ipm_throwaway_mesh_nodes"):
        assert "tmp_cube" in MESH_NODES
        tree = mesh_tree_from_json({"tree": {"node": "merge", "children": [{"node": "tmp_cube"}, {"node": "box"}]}})
        again = mesh_tree_from_json(json.loads(json.dumps(mesh_tree_to_json(tree))))
        assert same_tree(again.root, tree.root) and again.root.children[0].type_name == "tmp_cube"
        a, b = again.mesh(again.theta(), LOW).verts, tree.mesh(tree.theta(), LOW).verts
        assert torch.equal(a, b) and torch.equal(a[:8], a[8:])


# -- the depth limit -------------------------------------------------------------------------------

def nested(depth: int, leaf: dict, wrap: str) -> dict:
    d = leaf
    for _ in range(depth - 1):
        d = {"node": wrap, "children": [d]}
    return d


def nested_text(depth: int) -> str:
    """A nested tree file as text (``json.dumps`` itself recurses too deep at 500 levels)."""
    text = '{"node": "sphere"}'
    for _ in range(depth - 1):
        text = '{"node": "translate", "children": [' + text + "]}"
    return '{"tree": ' + text + "}"


@pytest.mark.parametrize("depth", [MAX_DEPTH + 1, 500])
def test_deep_trees_are_refused_naming_the_limit(depth, tmp_path, capsys):
    path = tmp_path / "deep.json"
    path.write_text(nested_text(depth))
    with pytest.raises(InputError, match=f"at most {MAX_DEPTH} levels deep"):
        load_tree(path)
    from ipm.cli import main

    with pytest.raises(SystemExit) as e:
        main(["generate", str(path), "-o", str(tmp_path / "o.obj")])
    assert e.value.code == 2 and f"at most {MAX_DEPTH} levels deep" in capsys.readouterr().err
    if depth < 400:
        with pytest.raises(InputError, match=f"at most {MAX_DEPTH} levels deep"):
            tree_from_json({"tree": nested(depth, {"node": "sphere"}, "translate")})
    with pytest.raises(InputError, match=f"at most {MAX_DEPTH} levels deep"):
        tree_from_json({"structure": ["translate"] * (depth - 1) + ["sphere"], "params": [0.0] * 3 * (depth - 1)
                        + [0.5]})
    with pytest.raises(InputError, match=f"at most {MAX_DEPTH} levels deep"):
        mesh_tree_from_json({"tree": nested(depth, {"node": "box"}, "translate")})
    node = NODES.get("sphere").make()
    for _ in range(depth - 1):
        node = node.translate(0.0, 0.0, 0.0)
    with pytest.raises(InputError, match=f"at most {MAX_DEPTH} levels deep"):
        Tree(node)


def test_trees_at_the_depth_limit_work():
    tree = tree_from_json({"tree": nested(MAX_DEPTH, {"node": "sphere"}, "translate")})
    assert torch.isfinite(tree.sdf(None, torch.zeros(1, 3, dtype=torch.float64))).all()


# -- macro libraries -------------------------------------------------------------------------------

def test_a_library_copy_of_a_shipped_macro_is_accepted(tmp_path, capsys):
    shutil.copy(LIBRARY_DIR / "arched_window.json", tmp_path / "arched_window.json")
    assert load_library([tmp_path]) == []
    from ipm.cli import main

    with pytest.raises(SystemExit) as e:
        main(["list", "nodes", "--json", "--library", str(tmp_path)])
    out, err = capsys.readouterr()
    assert e.value.code == 0, err
    assert "arched_window" in [r["name"] for r in json.loads(out)]


@pytest.mark.parametrize("name", ["arched_window", "box"])
def test_a_different_definition_under_a_shipped_name_is_an_input_error(tmp_path, name):
    spec = json.loads((LIBRARY_DIR / "arched_window.json").read_text())
    spec["name"] = name
    spec["params"][0]["default"] = 0.7
    path = tmp_path / "mine.json"
    path.write_text(json.dumps(spec))
    with pytest.raises(InputError) as e:
        load_library([tmp_path])
    msg = str(e.value)
    assert str(path) in msg and repr(name) in msg and "\n" not in msg
    assert NODES.get("arched_window").source.endswith("arched_window.json")
