"""Every registered node type, automatically: values and Jacobians against float64 central
differences, |grad_p f| = 1 for exact nodes, and finite values and derivatives at singular points."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ipm import sdf
from ipm.jacobian import check_sdf_jacobian, sdf_jacobian
from ipm.sdf.node import Node, all_node_types
from ipm.sdf.tree import Tree

TYPES = all_node_types()
ANGLE_WORDS = ("angle", "tilt", "azimuth")


def random_values(cls, size, rng) -> dict:
    """Parameters near the defaults (angles within +-40 degrees), inside the bounds."""
    out = {}
    for p in cls.param_defs_for(size):
        if not p.continuous:
            continue
        if any(w in p.name for w in ANGLE_WORDS):
            v = p.default + rng.uniform(-40, 40)
        else:
            scale = max(abs(p.default), 0.3)
            v = p.default + rng.uniform(-0.2, 0.2) * scale
        # keep a margin from the bounds: some bounds are kinks (zero radius, zero elongation)
        out[p.name] = float(np.clip(v, p.lo + 1e-3, p.hi - 1e-3))
    return out


def children_for(cls) -> tuple[Node, ...]:
    n = cls.arity if cls.arity is not None else 3
    cdim = cls.child_dim or cls.dim or 3
    if cdim == 2:
        pool = [sdf.rect(0.7, 0.5).translate2d(0.55, 0.1), sdf.circle(0.35).translate2d(0.8, 0.3),
                sdf.rect(0.3, 0.9).translate2d(0.4, -0.2)]
    else:
        pool = [sdf.box(0.6, 0.5, 0.4).translate(0.1, 0.05, -0.05), sdf.sphere(0.4).translate(0.35, 0.1, 0.0),
                sdf.box(0.3, 0.8, 0.3).translate(-0.2, 0.0, 0.15)]
    return tuple(pool[:n])


def case(name: str, seed: int = 0) -> Tree:
    """A 3D tree exercising node type ``name`` with random parameters (2D nodes are extruded)."""
    cls = TYPES[name]
    rng = np.random.default_rng(seed)
    kids = children_for(cls) if cls.arity != 0 else ()
    node = cls.make(children=kids, **random_values(cls, cls.default_size, rng))
    if node.out_dim == 2:
        node = sdf.extrude(0.6, children=(node,))
    return Tree(node)


def sample_points(tree: Tree, rng, n: int = 1500) -> torch.Tensor:
    """Uniform points in the padded bounds plus points pulled near the surface."""
    lo, hi = tree.bounds()
    lo, hi = np.maximum(lo, -3.0), np.minimum(hi, 3.0)
    pad = 0.2 * (hi - lo).max()
    pts = torch.as_tensor(rng.uniform(lo - pad, hi + pad, size=(4 * n, 3)))
    d = tree.sdf(None, pts)
    near = pts[d.abs() < 0.05][: n // 3]
    return torch.cat([pts[:n], near])


def test_at_least_40_node_types():
    assert len(TYPES) >= 40


@pytest.mark.parametrize("name", sorted(TYPES))
def test_jacobian_matches_central_differences(name):
    tree = case(name)
    rng = np.random.default_rng(1)
    pts = sample_points(tree, rng)
    theta = tree.theta()
    f = tree.sdf
    for mode in ("fwd", "rev"):
        chk = check_sdf_jacobian(f, theta, pts, mode=mode)
        assert chk.max_rel_error <= 1e-6, (name, mode, chk)
    # the values themselves: float32 and float64 evaluations agree, and both are finite
    d64 = f(theta, pts)
    d32 = f(theta.float(), pts.float())
    assert torch.isfinite(d64).all()
    assert torch.allclose(d32.double(), d64, atol=1e-4)


EXACT = sorted(n for n, c in TYPES.items() if c.exact)


@pytest.mark.parametrize("name", EXACT)
def test_exact_nodes_have_unit_gradient(name):
    tree = case(name, seed=2)
    rng = np.random.default_rng(3)
    pts = sample_points(tree, rng, 1000)
    J = sdf_jacobian(tree.sdf, tree.theta(), pts, "rev")
    norm = J[:, -3:].norm(dim=1)
    # points on the medial axis (ridges, where two closest points tie) are a set of measure zero;
    # keep away from them by discarding points where a small step changes the gradient direction
    eps = 1e-4
    g2 = sdf_jacobian(tree.sdf, tree.theta(), pts + eps * J[:, -3:], "rev")[:, -3:]
    smooth = (g2 - J[:, -3:]).norm(dim=1) < 1e-2
    assert smooth.float().mean() > 0.8
    bad = (norm[smooth] - 1.0).abs()
    assert bad.max() <= 1e-3, (name, float(bad.max()))


def singular_points() -> torch.Tensor:
    """Centers, axes, box corners and edges of the test children, and the origin."""
    pts = [[0, 0, 0], [0, 0.3, 0], [0, -0.3, 0], [1e-12, 0, 0]]
    for sx in (-1, 1):
        for sy in (-1, 1):
            for sz in (-1, 1):
                pts.append([0.1 + 0.3 * sx, 0.05 + 0.25 * sy, -0.05 + 0.2 * sz])  # box corners
                pts.append([0.3 * sx, 0.25 * sy, 0.0])                               # edges
                pts.append([0.5 * sx, 0.5 * sy, 0.5 * sz])
    pts += [[0.1, 0.05, -0.05], [0.35, 0.1, 0.0], [0.55, 0.1, 0.0], [0.8, 0.3, 0.0]]  # child centers
    return torch.tensor(pts, dtype=torch.float64)


@pytest.mark.parametrize("name", sorted(TYPES))
def test_finite_at_singular_points(name):
    cls = TYPES[name]
    kids = children_for(cls) if cls.arity != 0 else ()
    node = cls.make(children=kids)  # defaults: symmetric shapes, so centers and axes are hit exactly
    if node.out_dim == 2:
        node = sdf.extrude(0.6, children=(node,))
    tree = Tree(node)
    pts = singular_points()
    for mode in ("fwd", "rev"):
        J = sdf_jacobian(tree.sdf, tree.theta(), pts, mode)
        assert torch.isfinite(J).all(), (name, mode)
    assert torch.isfinite(tree.sdf(None, pts)).all()
    # and a backward pass of a scalar loss
    theta = tree.theta().requires_grad_(True)
    tree.sdf(theta, pts.requires_grad_(True)).sum().backward()
    assert torch.isfinite(theta.grad).all()


UNBOUNDED = {"plane"}  # a half-space: its box is the parameter range, documented as such


@pytest.mark.parametrize("name", sorted(set(TYPES) - UNBOUNDED))
def test_bbox_contains_the_solid(name):
    tree = case(name, seed=5)
    lo, hi = tree.bounds()
    rng = np.random.default_rng(6)
    span = hi - lo
    pts = torch.as_tensor(rng.uniform(lo - 0.5 * span, hi + 0.5 * span, size=(20000, 3)))
    inside = tree.sdf(None, pts) < 0
    p = pts[inside]
    tol = 1e-9
    assert ((p >= torch.as_tensor(lo) - tol) & (p <= torch.as_tensor(hi) + tol)).all(), name


def test_primitive_values_against_closed_forms():
    p = torch.tensor([[2.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 3.0, 0.0]], dtype=torch.float64)
    assert torch.allclose(sdf.sphere(1.0)(p), torch.tensor([1.0, -1.0, 2.0], dtype=torch.float64))
    assert torch.allclose(sdf.box(2, 2, 2)(p), torch.tensor([1.0, -1.0, 2.0], dtype=torch.float64))
    # corner distance of a box is the Euclidean distance to the corner
    q = torch.tensor([[2.0, 2.0, 2.0]], dtype=torch.float64)
    assert torch.allclose(sdf.box(2, 2, 2)(q), torch.tensor([3 ** 0.5], dtype=torch.float64))
    # torus: ring radius 1, tube 0.25; the point (1, 0, 0) is on the ring
    assert torch.allclose(sdf.torus(1.0, 0.25)(torch.tensor([[1.0, 0, 0]], dtype=torch.float64)),
                          torch.tensor([-0.25], dtype=torch.float64))
    # revolution with a constant radius is a cylinder from y = 0 to y = h
    cyl = sdf.revolution(1.0, 0.5, 0.5, 0.5, size=3)
    pts = torch.tensor([[0.0, 0.5, 0.0], [1.0, 0.5, 0.0], [0.0, 2.0, 0.0]], dtype=torch.float64)
    assert torch.allclose(cyl(pts), torch.tensor([-0.5, 0.5, 1.0], dtype=torch.float64))
    # the pyramid's apex is on the surface and its base center is on the surface
    pyr = sdf.pyramid(1.0, 2.0)
    assert torch.allclose(pyr(torch.tensor([[0.0, 2.0, 0.0], [0.0, 0.0, 0.0]], dtype=torch.float64)),
                          torch.zeros(2, dtype=torch.float64), atol=1e-9)


def test_repeat_and_mirror_place_copies():
    shelf = sdf.box(0.2, 0.2, 0.2).repeat(0, 3, 1.0)
    pts = torch.tensor([[-1.0, 0, 0], [0.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0], [0.5, 0, 0]], dtype=torch.float64)
    d = shelf(pts)
    assert (d[:3] < 0).all() and d[3] > 0.8 and d[4] > 0.3
    m = sdf.sphere(0.2).translate(1.0, 0, 0).mirror(0, 0.0)
    assert m(torch.tensor([[-1.0, 0, 0]], dtype=torch.float64)) < 0
