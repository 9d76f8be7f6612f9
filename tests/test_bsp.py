"""BSP generator (planes, selection, union) and the mesh -> BSP conversion: Jacobians against float64
central differences, the stage-2 field against the exact polytope, cube and L-shape recovery with at
most two convexes, files, and the fitting machinery."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
import trimesh

from ipm.generators import get_generator
from ipm.generators.bsp import BspGenerator, hard_field, plane_distances, polytope_mesh, relaxed_field
from ipm.jacobian import check_sdf_jacobian
from ipm.metrics import inside, iou_3d, normalize_vertices
from ipm.types import TriMesh


def _box(size, center=(0.0, 0.0, 0.0)) -> trimesh.Trimesh:
    return trimesh.creation.box(size, trimesh.transformations.translation_matrix(center))


@pytest.fixture(scope="module")
def l_shape() -> trimesh.Trimesh:
    """An L-shaped prism: a 2 x 1 x 1 bar and a 1 x 1 x 1 cube on its left end (two convex parts)."""
    L = trimesh.boolean.union([_box((2, 1, 1), (0.5, 0, 0)), _box((1, 1, 1), (0, 1, 0))], engine="manifold")
    assert L.is_watertight and abs(L.volume - 3.0) < 1e-9
    return L


@pytest.fixture
def one_thread():
    """Conversions and fits are loops of small tensor ops: intra-op threads save little, and on a loaded
    2-core machine their synchronization costs up to 10x (measured: the cube 4 s on one thread, 40 s
    and more on two while another job keeps both cores busy)."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


def _points(n: int, seed: int = 0, scale: float = 1.3) -> torch.Tensor:
    return torch.as_tensor(np.random.default_rng(seed).uniform(-scale, scale, size=(n, 3)))


# -- the generator -------------------------------------------------------------------------------

def test_registered_with_relaxed_defaults():
    g = get_generator("bsp")
    assert g.kind == "sdf" and g.relaxed
    p, c = g.n_planes, g.n_convexes
    assert g.spec.n_continuous == 4 * p + p * c + c
    # the default start for fits is a non-empty shape inside the domain
    m = g.to_mesh(g.spec.defaults(), resolution=40)
    assert m.n_faces > 0 and float(m.verts.abs().max()) <= g.extent + 1e-6


@pytest.mark.parametrize("stage", ["relaxed", "binary"])
def test_jacobian_matches_central_differences(stage):
    rng = np.random.default_rng(3)
    p, c = 7, 3
    if stage == "relaxed":
        # T and W strictly inside (0, 1): the clamp is inactive and the field is smooth there
        vals = {f"sel{i}.{j}": float(rng.uniform(0.2, 0.95)) for i in range(p) for j in range(c)}
        vals.update({f"conv{j}.w": float(rng.uniform(0.6, 0.95)) for j in range(c)})
        g = BspGenerator(p, c, values=vals, temperature=0.05, seed=1)
    else:
        g = BspGenerator(p, c, selection=rng.random((p, c)) < 0.6, seed=1)
    theta = g.tree.theta()
    pts = _points(64, seed=4)
    chk = check_sdf_jacobian(lambda th, x: g.sdf(th, x), theta, pts)
    assert chk.max_rel_error <= 1e-6, chk
    # and the reverse mode agrees too (vmap over single points)
    chk_rev = check_sdf_jacobian(lambda th, x: g.sdf(th, x), theta, pts, mode="rev")
    assert chk_rev.max_rel_error <= 1e-6, chk_rev


def test_field_is_one_lipschitz_and_negative_inside():
    g = get_generator("bsp")
    x = _points(2000, seed=5).requires_grad_(True)
    f = g.sdf(g.tree.theta(), x)
    (grad,) = torch.autograd.grad(f.sum(), x)
    assert float(grad.norm(dim=-1).max()) <= 1.0 + 1e-9
    # a binary selection: negative exactly inside the polytope (the exact export of the same shape)
    cube = np.array([[1, 0, 0, 0.5], [-1, 0, 0, 0.5], [0, 1, 0, 0.5], [0, -1, 0, 0.5], [0, 0, 1, 0.5], [0, 0, -1, 0.5],
                     [1, 1, 0, 0.3]], dtype=np.float64)
    sel = np.zeros((7, 2), bool)
    sel[:6, 0] = True                      # a unit cube ...
    sel[[0, 1, 2, 3, 4, 5, 6], 1] = True   # ... and the same cube with a corner cut off
    sel[6, 1] = True
    pts = _points(4000, seed=6, scale=0.8)
    mask = torch.as_tensor(np.vstack([sel, np.ones((6, 2), bool)]))
    f = hard_field(torch.as_tensor(cube), mask, pts, 1.5).numpy()
    poly = polytope_mesh(cube, sel, 1.5)
    V, F = poly.mesh.verts.numpy(), poly.mesh.faces.numpy()
    assert np.array_equal(f < 0, inside(pts.numpy(), V, F))
    assert poly.convexes == [0, 1] and poly.planes == [0, 1, 2, 3, 4, 5, 6]


def test_relaxed_field_reduces_to_the_hard_one():
    """T, W binary and a small temperature: the relaxed field approaches the hard one (within tau log k)."""
    rng = np.random.default_rng(7)
    p, c = 6, 3
    planes = torch.as_tensor(np.hstack([rng.normal(size=(p, 3)), rng.uniform(0.3, 0.8, size=(p, 1))]))
    sel = rng.random((p, c)) < 0.7
    sel[0] = True
    pts = _points(500, seed=8)
    tau = 1e-3
    f_rel = relaxed_field(planes, torch.as_tensor(sel, dtype=torch.float64), torch.ones(c, dtype=torch.float64),
                          pts, 1.5, 1.0, tau)
    f_hard = hard_field(planes, torch.as_tensor(np.vstack([sel, np.ones((6, c), bool)])), pts, 1.5)
    bound = tau * (np.log(p + 6) + np.log(c)) + 1e-12
    assert float((f_rel - f_hard).abs().max()) <= bound
    # W = 0 removes a convex from the union
    W = torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64)
    one = hard_field(planes, torch.as_tensor(np.vstack([sel, np.ones((6, c), bool)])[:, :1]), pts, 1.5)
    f_w = relaxed_field(planes, torch.as_tensor(sel, dtype=torch.float64), W, pts, 1.5, 1.0, tau)
    inside_any = (one < -2 * bound) | (one > 2 * bound)
    assert torch.equal((f_w < 0)[inside_any], (one < 0)[inside_any])
    assert plane_distances(planes, pts, 1.5).shape == (500, p + 6)


def test_file_round_trip_and_generate(tmp_path):
    rng = np.random.default_rng(9)
    g = BspGenerator(5, 2, selection=rng.random((5, 2)) < 0.8, seed=2)
    path = tmp_path / "shape.json"
    path.write_text(json.dumps(g.to_json(g.spec.defaults())))
    h = get_generator(str(path))
    assert isinstance(h, BspGenerator) and not h.relaxed
    assert np.array_equal(h.selection, g.selection) and h.spec.names == g.spec.names
    pts = _points(100)
    assert torch.equal(h.sdf(h.tree.theta(), pts), g.sdf(g.tree.theta(), pts))
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"generator": "bsp", "planes": 2, "convexes": 1}))
    with pytest.raises(ValueError, match="missing params"):
        get_generator(str(bad))
    bad.write_text(json.dumps({"generator": "bsp", "planes": 2, "convexes": 1, "selection": [[2], [0]], "params": {}}))
    with pytest.raises(ValueError, match="binary"):
        get_generator(str(bad))


# -- conversion ----------------------------------------------------------------------------------

FAST = {"planes": 12, "convexes": 4, "steps": 150, "batch": 2048, "samples": 20_000}   # the defaults, halved


@pytest.mark.parametrize("shape", ["cube", "l_shape"])
def test_conversion_recovers_cube_and_l_shape(shape, l_shape, one_thread):
    from ipm.convert.bsp import fit_bsp

    mesh = _box((1.0, 1.0, 1.0)) if shape == "cube" else l_shape
    res = fit_bsp(mesh, seed=0, **FAST)
    assert res.stats["convexes"] <= (1 if shape == "cube" else 2), res.stats
    poly = res.generator.polytope(res.values)
    tm = poly.mesh.to_trimesh()
    assert tm.is_watertight and tm.is_winding_consistent and tm.volume > 0
    target = TriMesh(torch.as_tensor(normalize_vertices(mesh.vertices)), torch.as_tensor(mesh.faces))
    assert iou_3d(poly.mesh, target, resolution=64) >= 0.99
    # sharp edges: the exact polytope has the few vertices of the shape, not a marching-cubes soup
    assert tm.volume == pytest.approx(mesh.volume * res.data["frame"]["scale"] ** 3, rel=0.02)
    assert len(poly.planes) == res.stats["planes"] <= (6 if shape == "cube" else 10)
    # the exported polytope and the field agree on which points are inside
    pts = _points(3000, seed=11, scale=1.1)
    f = res.generator.sdf(res.generator.tree.theta(), pts).numpy()
    assert np.array_equal(f < 0, inside(pts.numpy(), tm.vertices, tm.faces))


def test_conversion_rejects_bad_input():
    from ipm.convert.bsp import fit_bsp

    with pytest.raises(ValueError, match="expected a mesh with faces"):
        fit_bsp((np.zeros((3, 3)), np.zeros((0, 3), dtype=np.int64)))
    with pytest.raises(ValueError, match="planes: expected an integer >= 1"):
        fit_bsp(_box((1, 1, 1)), planes=0)


# -- the fitting machinery -----------------------------------------------------------------------

def test_fit_plugs_into_the_fit_machinery(one_thread):
    from ipm.optim.fit import FitSettings, MaskTarget, MeshTarget, run_fit
    from ipm.render import camera
    from ipm.render.raster import rasterize_mesh

    box = _box((1.6, 1.0, 1.2))
    target = TriMesh(torch.as_tensor(normalize_vertices(box.vertices)), torch.as_tensor(box.faces))
    g = BspGenerator(12, 3, seed=0)
    res, prob, best = run_fit(g, MeshTarget(target, samples=800), FitSettings(budget=25, discrete="none", lr=0.03))
    assert res.evaluations == 25 and np.isfinite(res.loss)
    start_loss, _, _ = prob.objective(prob.x0(), dict(prob.d0), False)
    assert res.loss <= float(start_loss)             # the start is among the evaluated points
    # silhouettes: one view, a tiny image, a few evaluations
    cams = [c.to(torch.float32) for c in camera.input_views(1, 32)]
    masks = torch.stack([rasterize_mesh(target, c).mask.float() for c in cams])
    res2, _, _ = run_fit(g, MaskTarget(masks, cams), FitSettings(budget=6, discrete="none", lr=0.03))
    assert np.isfinite(res2.loss) and 0.0 <= res2.loss < 1.0
