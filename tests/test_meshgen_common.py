"""Shared mesh-building blocks (ipm.generators._meshkit) and what all mesh generators promise:
registry names, validation messages, and Jacobians that stay on torch's fast forward-mode path."""

from __future__ import annotations

import collections
import math
import sys

import numpy as np
import pytest
import torch
import trimesh
from torch.func import jacfwd

from ipm.generators import _meshkit as mk
from ipm.generators import get_generator

MESH_GENERATORS = ("dishes", "building", "meshtree")


def as_trimesh(v: torch.Tensor, f: torch.Tensor) -> trimesh.Trimesh:
    return trimesh.Trimesh(v.detach().double().numpy(), f.numpy(), process=False)


# -- lofts ---------------------------------------------------------------------------------------

def test_boxes_are_closed_outward_and_have_the_right_volume():
    lo = torch.tensor([[0.0, 0.0, 0.0], [2.0, -1.0, 0.5]], dtype=torch.float64)
    hi = torch.tensor([[1.0, 2.0, 3.0], [3.0, 1.0, 1.0]], dtype=torch.float64)
    m = as_trimesh(mk.box_verts(lo, hi), mk.box_faces(2))
    assert m.is_watertight and m.is_winding_consistent
    assert m.volume == pytest.approx(6.0 + 1.0)
    assert float(mk.signed_volume(mk.box_verts(lo, hi), mk.box_faces(2))) == pytest.approx(7.0)


@pytest.mark.parametrize("segments", [3, 8, 64])
def test_revolved_cylinder_has_the_polygon_prism_volume(segments):
    r, h = 0.7, 1.3
    v = mk.revolve(torch.tensor([r, r], dtype=torch.float64), torch.tensor([0.0, h], dtype=torch.float64),
                   segments, bottom=torch.tensor([0.0], dtype=torch.float64),
                   top=torch.tensor([h], dtype=torch.float64))
    m = as_trimesh(v, mk.loft_faces(2, segments, "pole", "pole"))
    assert m.is_watertight and m.is_winding_consistent
    assert m.volume == pytest.approx(0.5 * segments * r * r * math.sin(2 * math.pi / segments) * h)


def test_revolve_bulge_moves_ring_vertices_radially():
    r = torch.tensor([1.0, 1.0], dtype=torch.float64)
    y = torch.tensor([0.0, 1.0], dtype=torch.float64)
    q, w = torch.tensor([0.0, 0.5], dtype=torch.float64), torch.linspace(0, 1, 8, dtype=torch.float64)
    v = mk.revolve(r, y, 8, bulge=(q, w)).reshape(2, 8, 3)
    radius = torch.linalg.vector_norm(v[..., [0, 2]], dim=-1)
    assert torch.allclose(radius[0], torch.ones(8, dtype=torch.float64))
    assert torch.allclose(radius[1], 1.0 + 0.5 * w)


def test_swept_tube_is_closed_and_outward():
    s = torch.linspace(0, 1, 12, dtype=torch.float64)
    centers = torch.stack([torch.cos(2 * s), torch.sin(2 * s), 0 * s], -1)
    tang = torch.stack([-torch.sin(2 * s), torch.cos(2 * s), 0 * s], -1)
    binorm = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).expand(12, 3)
    normal = torch.linalg.cross(binorm, tang)          # normal x binormal = tangent
    v = mk.tube(centers, normal, binorm, 0.1 + 0 * s, 0.2 + 0 * s, 10)
    m = as_trimesh(v, mk.loft_faces(12, 10, "pole", "pole"))
    assert m.is_watertight and m.is_winding_consistent and m.volume > 0


def test_loft_face_counts_and_errors():
    assert mk.loft_faces(5, 7, "pole", "pole").shape == (2 * 7 * 4 + 2 * 7, 3)
    assert mk.loft_faces(2, 4, "fan", "fan").shape == (12, 3)
    assert mk.loft_n_verts(5, 7, "pole", "fan") == 36
    with pytest.raises(ValueError, match="expected at least 1 loop of at least 3 vertices"):
        mk.loft_faces(1, 2)


def test_assemble_offsets_faces_and_checks_counts():
    v = mk.box_verts(torch.zeros(2, 3), torch.ones(2, 3))
    m = mk.assemble([v[:8], v[8:]], [mk.box_faces(1), mk.box_faces(1)], [8, 8], ["a", "b"])
    assert m.faces.max() == 15 and m.group_names == ("a", "b") and m.groups.tolist() == [0] * 12 + [1] * 12
    with pytest.raises(ValueError, match="expected 8 vertices, got 16"):
        mk.assemble([v], [mk.box_faces(1)], [8], ["a"])


# -- splines -------------------------------------------------------------------------------------

def test_catmull_rom_interpolates_and_matches_its_matrix_form():
    ctrl = torch.tensor([1.0, 2.0, 0.0, 3.0, 1.0], dtype=torch.float64)
    u = torch.linspace(0, 1, 17, dtype=torch.float64)
    val = mk.catmull_rom(ctrl, u)
    assert torch.allclose(val[::4], ctrl)
    assert torch.allclose(mk.catmull_rom_matrix(5, 17) @ ctrl, val)


def test_catmull_rom_reproduces_straight_lines():
    ctrl = torch.linspace(-1, 2, 6, dtype=torch.float64)
    u = torch.rand(50, dtype=torch.float64)
    assert torch.allclose(mk.catmull_rom(ctrl, u), -1 + 3 * u)


def test_catmull_rom_derivative_matches_finite_differences():
    ctrl = torch.tensor([[0.0, 1.0], [1.0, 3.0], [2.0, 2.0], [4.0, 0.0]], dtype=torch.float64)
    u = torch.tensor([0.05, 0.3, 0.5, 0.71, 0.95], dtype=torch.float64)
    _, d = mk.catmull_rom(ctrl, u, derivative=True)
    eps = 1e-6
    fd = (mk.catmull_rom(ctrl, u + eps) - mk.catmull_rom(ctrl, u - eps)) / (2 * eps)
    assert torch.allclose(d, fd, atol=1e-7)
    pad = torch.cat([2 * ctrl[:1] - ctrl[1:2], ctrl, 2 * ctrl[-1:] - ctrl[-2:-1]])
    D = mk.catmull_rom_pad_matrix(4, 9, derivative=True)
    _, d9 = mk.catmull_rom(ctrl, torch.linspace(0, 1, 9, dtype=torch.float64), derivative=True)
    assert torch.allclose(D @ pad, d9)


def test_scalar_helpers_and_lift_compute_the_plain_values():
    x = torch.tensor([1.0, -2.0])
    assert torch.equal(mk.smul(x, 3.0), x * 3.0) and torch.equal(mk.sadd(x, 0.5), x + 0.5)
    assert torch.equal(mk.ssub(1.0, x), 1.0 - x)
    c = mk.lift(torch.arange(6, dtype=torch.float64).reshape(2, 3), x)
    assert c.dtype == torch.float32 and c.shape == (2, 3) and c[1, 2] == 5


# -- the generators --------------------------------------------------------------------------------

@pytest.mark.parametrize("name", MESH_GENERATORS)
def test_generators_are_registered_as_mesh_generators(name):
    g = get_generator(name)
    assert g.name == name and g.kind == "mesh"
    v = g.values()
    theta, discrete = g.split(v)
    m = g.mesh(theta, discrete)
    assert m.verts.shape[1] == 3 and m.faces.dtype == torch.int64 and m.groups is not None
    assert g.to_mesh(v).n_verts == m.n_verts
    assert g.metadata(v)["generator"] == name


def test_values_reports_whole_number_errors_like_the_cli_expects():
    with pytest.raises(ValueError, match=r"parameter 'floors' is int: expected a whole number in \[1, 30\], got 2.5"):
        get_generator("building").values(overrides={"floors": 2.5})
    with pytest.raises(ValueError, match="unknown preset 'castle'"):
        get_generator("building").values("castle")
    with pytest.raises(ValueError, match="unknown parameter 'radius'"):
        get_generator("dishes").values(overrides={"radius": 1.0})


@pytest.mark.parametrize("name", MESH_GENERATORS)
def test_theta_shape_is_checked_at_the_boundary(name):
    g = get_generator(name)
    n = g.spec.n_continuous
    with pytest.raises(ValueError, match=rf"theta: expected shape \({n},\), got \({n + 1},\)"):
        g.mesh(torch.zeros(n + 1, dtype=torch.float64), {})


@pytest.mark.parametrize("name", MESH_GENERATORS)
def test_float32_generation_and_jacobian_stay_float32(name):
    g = get_generator(name)
    theta, discrete = g.split(g.values(), torch.float32)
    m = g.mesh(theta, discrete, "low")
    J = jacfwd(lambda t: g.mesh(t, discrete, "low").verts.reshape(-1))(theta)
    assert m.verts.dtype == torch.float32 and J.dtype == torch.float32
    assert J.shape == (3 * m.n_verts, theta.shape[0])


def slow_path_hits(f, theta: torch.Tensor) -> collections.Counter:
    """Where (ipm file:line) ``jacfwd(f)(theta)`` calls torch's Python reference code for an operation (the
    slow path of a dual-with-constant op), after a warm-up call that is not traced."""
    jacfwd(f)(theta)     # warm-up: not traced
    hits: collections.Counter = collections.Counter()

    def tracer(frame, event, arg):
        if event == "call" and frame.f_code.co_name == "_fn" and "_prims_common" in frame.f_code.co_filename:
            caller = frame.f_back
            if caller is not None and "/ipm/" in caller.f_code.co_filename:
                hits[f"{caller.f_code.co_filename.split('/ipm/')[-1]}:{caller.f_lineno}"] += 1
        return None

    sys.setprofile(tracer)
    try:
        jacfwd(f)(theta)
    finally:
        sys.setprofile(None)
    return hits


@pytest.mark.parametrize("name", MESH_GENERATORS)
def test_jacfwd_never_takes_torchs_slow_mixed_operand_path(name):
    """A dual-with-constant op without the _meshkit helpers runs Python reference code (~1 ms/op)."""
    g = get_generator(name)
    theta, discrete = g.split(g.values())
    hits = slow_path_hits(lambda t: g.mesh(t, discrete, "low").verts.reshape(-1), theta)
    assert not hits, dict(hits)


def test_sanity_of_the_slow_path_detector():
    """The detector above does see a plain `x * 0.5` inside jacfwd (so its silence means something)."""
    seen = []

    def tracer(frame, event, arg):
        if event == "call" and frame.f_code.co_name == "_fn" and "_prims_common" in frame.f_code.co_filename:
            seen.append(frame.f_back.f_code.co_name if frame.f_back else None)
        return None

    def f(t):
        return t * 0.5

    jacfwd(f)(torch.ones(2))                         # warm-up (torch's lazy imports): not traced
    sys.setprofile(tracer)
    try:
        jacfwd(f)(torch.ones(2))
    finally:
        sys.setprofile(None)
    if not seen:
        pytest.skip("this torch computes mixed dual/constant tangents natively (no slow path to guard)")
    assert "f" in seen


def test_face_arrays_are_built_once_and_shared():
    assert mk.loft_faces_np(4, 6, "pole", "pole") is mk.loft_faces_np(4, 6, "pole", "pole")
    a, b = mk.loft_faces(4, 6, "pole", "pole"), mk.loft_faces(4, 6, "pole", "pole")
    assert a.data_ptr() == b.data_ptr() and np.array_equal(a.numpy(), mk.loft_faces_np(4, 6, "pole", "pole"))
