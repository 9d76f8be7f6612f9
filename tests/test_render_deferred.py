"""Deferred renderer (nvdiffrast's ops): agreement with the exact rasterizer, barycentrics on the pixel
ray, float64 gradients of interpolated depth, normals and shading against finite differences, and of the
antialiased image at silhouette and occlusion edges (finite differences of the same image, and the
derivative of the exact projected area)."""

from __future__ import annotations

import inspect

import pytest
import torch
import trimesh
from conftest import real_path

from ipm.errors import InputError
from ipm.io.meshes import load_mesh
from ipm.render import deferred as D
from ipm.render.camera import input_views, orbit_camera, pixel_rays, project
from ipm.render.raster import rasterize as exact_rasterize
from ipm.types import TriMesh


def box(extents=(1.0, 1.2, 0.8)):
    m = trimesh.creation.box(extents=extents)
    return torch.tensor(m.vertices, dtype=torch.float64), torch.tensor(m.faces, dtype=torch.int64)


CAM = orbit_camera(30.0, 20.0, 3.0, width=40, height=32)


# -- rasterize / interpolate ----------------------------------------------------------------------------

@pytest.mark.parametrize("name, up", [("vessels/probcomp_mug.obj", "y"),
                                      ("buildings/denhaag_84A7976B_lod2.obj", "z")])
def test_mask_face_and_depth_match_the_exact_rasterizer(name, up):
    mesh = load_mesh(real_path(name), up=up)
    v = mesh.verts.double()
    for cam in (input_views(1, 64)[0], orbit_camera(200.0, -15.0, 3.2, width=64, height=48)):
        fr = exact_rasterize(v, mesh.faces, cam)
        r = D.rasterize(v, mesh.faces, cam)
        assert torch.equal(r.mask, fr.mask) and torch.equal(r.face, fr.face)
        d = D.depth(v, mesh.faces, cam, r)
        rel = ((d - fr.depth).abs() / fr.depth.abs())[fr.mask]
        assert float(rel.max()) < 1e-9
        assert torch.all(d[~r.mask] == 0)
        b = r.bary[r.mask]
        assert torch.allclose(b.sum(-1), torch.ones_like(b[:, 0]), atol=1e-12)
        assert float(b.min()) > -1e-9  # pixel centers are inside their face


def test_interpolated_positions_lie_on_the_pixel_rays():
    v, f = box()
    r = D.rasterize(v, f, CAM)
    pts = D.interpolate(v, r, f)[r.mask]  # (N, 3)
    o, d = pixel_rays(CAM)
    d = d[r.mask]
    along = ((pts - o) * d).sum(-1, keepdim=True)
    off = (pts - o) - along * d
    assert float(off.abs().max()) < 1e-12 and bool((along > 0).all())
    # and on the plane of the visible face
    n = D.face_normals(v, f)[r.face[r.mask]]
    assert float(((pts - v[f[r.face[r.mask], 0]]) * n).sum(-1).abs().max()) < 1e-12
    # and their projection is the pixel center
    xy, _ = project(pts, CAM)
    ys, xs = torch.nonzero(r.mask, as_tuple=True)
    assert torch.allclose(xy, torch.stack([xs + 0.5, ys + 0.5], -1).double(), atol=1e-9)


def test_interpolate_checks_and_background():
    v, f = box()
    r = D.rasterize(v, f, CAM)
    out = D.interpolate(torch.ones(v.shape[0], 2, dtype=torch.float64), r, f, background=-1.0)
    assert torch.allclose(out[r.mask], torch.ones_like(out[r.mask])) and torch.all(out[~r.mask] == -1.0)
    with pytest.raises(InputError):
        D.interpolate(torch.ones(v.shape[0]), r, f)
    with pytest.raises(InputError):
        D.rasterize(v.float()[:, :2], f, CAM)


def test_part_labels_and_normals():
    a, fa = box((1.0, 1.0, 1.0))
    b, fb = box((0.4, 0.4, 0.4))
    mesh = TriMesh.concat([TriMesh(a, fa), TriMesh(b + torch.tensor([0.0, 0.8, 0.0], dtype=torch.float64),
                                                   fb)], names=["body", "lid"])
    out = D.render_deferred(mesh, CAM)  # headlight
    r = out.raster
    assert torch.equal(out.parts[~r.mask], torch.full_like(out.parts[~r.mask], -1))
    assert set(out.parts[r.mask].unique().tolist()) == {0, 1}
    assert torch.equal(out.parts[r.mask], mesh.groups[r.face[r.mask]])
    fr = exact_rasterize(mesh.verts, mesh.faces, CAM)
    assert torch.allclose(out.normal, fr.normal, atol=1e-12)
    # a box's smooth normals (area-weighted corners) are unit and point outwards
    ns = D.vertex_normal_image(mesh.verts, mesh.faces, r)[r.mask]
    assert torch.allclose(ns.norm(dim=-1), torch.ones(len(ns), dtype=torch.float64))
    assert D.part_labels(None, r)[r.mask].eq(0).all()


# -- shading ------------------------------------------------------------------------------------------

def test_a_face_facing_the_light_gets_ambient_plus_intensity():
    n = torch.zeros(2, 3, 3, dtype=torch.float64)
    n[..., 2] = 1.0
    n[1, 2] = torch.tensor([0.0, 0.0, -1.0])
    mask = torch.ones(2, 3, dtype=torch.bool)
    mask[0, 0] = False
    img = D.shade(n, mask, torch.tensor([0.0, 0.0, 2.0]), 0.7, 0.1)
    assert img[0, 0] == 0.0 and torch.allclose(img[0, 1:], torch.full((2,), 0.8, dtype=torch.float64))
    assert img[1, 2] == pytest.approx(0.1)  # facing away: ambient only
    with pytest.raises(InputError):
        D.shade(n[0], mask)


def test_shading_parameters_are_differentiable():
    n = torch.nn.functional.normalize(torch.randn(4, 5, 3, dtype=torch.float64, generator=torch.Generator()
                                                  .manual_seed(0)), dim=-1)
    mask = torch.ones(4, 5, dtype=torch.bool)
    args = (torch.tensor([0.3, 0.2, 1.0], dtype=torch.float64, requires_grad=True),
            torch.tensor(0.7, dtype=torch.float64, requires_grad=True),
            torch.tensor(0.2, dtype=torch.float64, requires_grad=True))
    assert torch.autograd.gradcheck(lambda lv, i, a: D.shade(n, mask, lv, i, a), args)


# -- gradients w.r.t. vertex positions (interior pixels: face ids fixed) --------------------------------

def _interior(v, f, fn):
    """fn(verts) on the pixels whose face id survives small perturbations."""
    r = D.rasterize(v, f, CAM)
    keep = r.mask.clone()
    keep[1:] &= r.face[1:] == r.face[:-1]
    keep[:-1] &= r.face[:-1] == r.face[1:]
    keep[:, 1:] &= r.face[:, 1:] == r.face[:, :-1]
    keep[:, :-1] &= r.face[:, :-1] == r.face[:, 1:]
    return lambda x: fn(x)[keep]


@pytest.mark.parametrize("what", ["depth", "position", "flat normal", "smooth normal", "shade"])
def test_gradcheck_interior(what):
    v, f = box()
    light = torch.tensor([0.4, 0.7, 0.6], dtype=torch.float64)

    def fn(x):
        r = D.rasterize(x, f, CAM)
        if what == "depth":
            return D.depth(x, f, CAM, r)
        if what == "position":
            return D.interpolate(x, r, f)
        if what == "flat normal":
            return D.face_normal_image(x, f, r)
        if what == "smooth normal":
            return D.vertex_normal_image(x, f, r)
        return D.shade(D.vertex_normal_image(x, f, r), r.mask, light)

    x = v.clone().requires_grad_(True)
    assert torch.autograd.gradcheck(_interior(v, f, fn), (x,))


def test_gradcheck_camera():
    v, f = box()
    eye = CAM.eye.clone().requires_grad_(True)
    fov = CAM.fov_deg.clone().requires_grad_(True)

    def fn(e, fv):
        cam = orbit_camera(30.0, 20.0, 3.0, width=40, height=32)
        cam = type(cam)(e, cam.target, cam.up, fv, cam.width, cam.height)
        return D.depth(v, f, cam, D.rasterize(v, f, cam))

    assert torch.autograd.gradcheck(_interior(v, f, lambda e: fn(e, fov)), (eye,))


# -- antialiasing ---------------------------------------------------------------------------------------

def _scene():
    """A box with a triangle floating in front of it: silhouette edges against the background and an
    occlusion edge against the box."""
    v, f = box()
    tri = torch.tensor([[-0.1, -0.3, 0.9], [0.5, 0.1, 0.8], [0.0, 0.45, 0.85]], dtype=torch.float64)
    return torch.cat([v, tri]), torch.cat([f, torch.tensor([[8, 9, 10]])])


@pytest.mark.parametrize("image", ["mask", "shade"])
def test_antialias_gradient_matches_finite_differences(image):
    """gradcheck (central differences, eps 1e-6) of the whole antialiased image: at eps = 1e-6 no pixel
    changes face id in this generic view, so the antialiased image is smooth there and its finite
    difference is the gradient we want to be exact."""
    v, f = _scene()
    light = torch.tensor([0.4, 0.7, 0.6], dtype=torch.float64)

    def fn(x):
        r = D.rasterize(x, f, CAM)
        col = r.mask.double() if image == "mask" else D.shade(D.face_normal_image(x, f, r), r.mask, light)
        return D.antialias(col, r, x, f, CAM)

    x = v.clone().requires_grad_(True)
    out = fn(x)
    x.grad = None
    out.sum().backward()
    assert float(x.grad[:8].abs().sum()) > 0 and float(x.grad[8:].abs().sum()) > 0
    assert torch.autograd.gradcheck(fn, (x,))


def test_antialiased_coverage_follows_the_exact_area():
    """The sum of an antialiased mask is (up to the corners) the projected area, and its gradient w.r.t.
    the vertices is the derivative of the exact area (shoelace formula on the projected vertices): this
    compares with the coverage the hard mask cannot differentiate, not with the approximation itself."""
    cam = orbit_camera(10.0, 5.0, 3.0, width=48, height=48)
    v = torch.tensor([[-0.6, -0.5, 0.0], [0.7, -0.35, 0.1], [0.1, 0.65, -0.1]], dtype=torch.float64,
                     requires_grad=True)
    f = torch.tensor([[0, 1, 2]])
    r = D.rasterize(v, f, cam)
    s = D.antialias(r.mask.double(), r, v, f, cam).sum()
    (g_aa,) = torch.autograd.grad(s, v)
    xy, _ = project(v, cam)
    area = 0.5 * torch.abs((xy[1, 0] - xy[0, 0]) * (xy[2, 1] - xy[0, 1]) -
                           (xy[2, 0] - xy[0, 0]) * (xy[1, 1] - xy[0, 1]))
    (g_area,) = torch.autograd.grad(area, v)
    assert float(s.detach()) == pytest.approx(float(area.detach()), rel=0.01)
    assert float((g_aa - g_area).norm() / g_area.norm()) < 0.05  # measured 0.025
    assert int(r.mask.sum()) != pytest.approx(float(area.detach()), abs=0.5)  # the plain mask is off


def test_antialias_leaves_interiors_and_open_mesh_seams_alone():
    # two coplanar triangles sharing an edge: the shared edge is no silhouette, nothing blends there
    v = torch.tensor([[-0.5, -0.5, 0.0], [0.5, -0.5, 0.0], [0.5, 0.5, 0.0], [-0.5, 0.5, 0.0]],
                     dtype=torch.float64)
    f = torch.tensor([[0, 1, 2], [0, 2, 3]])
    sil = D.silhouette_edges(v, f, CAM)
    assert sil.sum() == 4 and not sil[0, 2] and not sil[1, 0]
    r = D.rasterize(v, f, CAM)
    col = torch.where(r.face[..., None] == 0, torch.tensor([1.0, 0.0]).double(),
                      torch.tensor([0.0, 1.0]).double()) * r.mask[..., None]
    out = D.antialias(col, r, v, f, CAM)
    inner = r.mask.clone()
    inner[1:] &= r.mask[:-1]
    inner[:-1] &= r.mask[1:]
    inner[:, 1:] &= r.mask[:, :-1]
    inner[:, :-1] &= r.mask[:, 1:]
    assert torch.equal(out[inner], col[inner])
    assert not torch.equal(out, col)


def test_render_deferred_outputs():
    v, f = box()
    x = v.clone().requires_grad_(True)
    out = D.render_deferred(TriMesh(x, f), CAM, D.DeferredSettings(smooth=True))
    H, W = CAM.height, CAM.width
    assert out.depth.shape == (H, W) and out.normal.shape == (H, W, 3) and out.parts.shape == (H, W)
    assert out.image.shape == (H, W) and out.mask.shape == (H, W)
    assert float(out.image.detach().min()) >= 0.0 and float(out.mask.detach().max()) <= 1.0 + 1e-12
    (out.image.sum() + out.depth.sum() + out.mask.sum()).backward()
    assert torch.isfinite(x.grad).all() and float(x.grad.abs().sum()) > 0
    out32 = D.render_deferred(TriMesh(v.float(), f), CAM)
    assert out32.image.dtype == torch.float32 and out32.depth.dtype == torch.float32


def test_ops_are_device_agnostic():
    src = inspect.getsource(D)
    assert ".cpu()" not in src and ".numpy()" not in src and ".item()" not in src


def test_settings_and_empty_views():
    with pytest.raises(InputError):
        D.DeferredSettings(near=0.0)
    with pytest.raises(InputError):
        D.DeferredSettings(light_dir=torch.zeros(2))
    v, f = box()
    away = orbit_camera(30.0, 20.0, 3.0, target=(0.0, 0.0, 10.0), width=16, height=12)
    for mesh in (TriMesh(v, f[:0]), TriMesh(v + torch.tensor([0.0, 0.0, 50.0], dtype=torch.float64), f)):
        out = D.render_deferred(mesh, away if mesh.n_faces else CAM)
        assert not out.raster.mask.any() and float(out.image.abs().sum()) == 0.0
        assert bool((out.parts == -1).all())
    lit = D.render_deferred(TriMesh(v, f), CAM, D.DeferredSettings(
        light_dir=torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64), antialias=False, ambient=0.0,
        intensity=1.0))
    top = lit.normal[..., 1] > 0.999
    assert top.any() and torch.allclose(lit.image[top], torch.ones_like(lit.image[top]))
