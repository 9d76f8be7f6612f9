"""Deferred renderer (nvdiffrast's ops): agreement with the exact rasterizer, barycentrics on the pixel
ray, float64 gradients of interpolated depth, normals and shading against finite differences, and of the
antialiased image at silhouette and occlusion edges (finite differences of the same image, and the
derivative of the exact projected area), each under both backends; and the native backend (the C kernel)
against the eager one: same outputs and gradients, the same bits for any thread count and instruction set,
and the fallback to eager where it cannot be built."""

from __future__ import annotations

import inspect

import pytest
import torch
import trimesh
from conftest import real_path

from ipm.errors import InputError
from ipm.io.meshes import load_mesh
from ipm.render import deferred as D
from ipm.render import deferred_native
from ipm.render.camera import input_views, orbit_camera, pixel_rays, project
from ipm.render.raster import rasterize as exact_rasterize
from ipm.types import TriMesh


def box(extents=(1.0, 1.2, 0.8)):
    m = trimesh.creation.box(extents=extents)
    return torch.tensor(m.vertices, dtype=torch.float64), torch.tensor(m.faces, dtype=torch.int64)


CAM = orbit_camera(30.0, 20.0, 3.0, width=40, height=32)
needs_native = pytest.mark.skipif(not deferred_native.available(), reason="no C compiler for the native kernel")


@pytest.fixture(params=["eager", pytest.param("native", marks=needs_native)])
def backend(request, monkeypatch):
    """The test under each backend: rasterize reads ``$IPM_DEFERRED_BACKEND``, the other ops follow the raster."""
    monkeypatch.setenv("IPM_DEFERRED_BACKEND", request.param)
    return request.param


# -- rasterize / interpolate ----------------------------------------------------------------------------

@pytest.mark.parametrize("name, up", [("vessels/probcomp_mug.obj", "y"),
                                      ("buildings/denhaag_84A7976B_lod2.obj", "z")])
def test_mask_face_and_depth_match_the_exact_rasterizer(name, up, backend):
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


def test_interpolated_positions_lie_on_the_pixel_rays(backend):
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


def test_part_labels_and_normals(backend):
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

def _interior(v, f, fn, cam=CAM):
    """fn(verts) on the pixels whose face id survives small perturbations."""
    r = D.rasterize(v, f, cam)
    keep = r.mask.clone()
    keep[1:] &= r.face[1:] == r.face[:-1]
    keep[:-1] &= r.face[:-1] == r.face[1:]
    keep[:, 1:] &= r.face[:, 1:] == r.face[:, :-1]
    keep[:, :-1] &= r.face[:, :-1] == r.face[:, 1:]
    return lambda x: fn(x)[keep]


@pytest.mark.parametrize("what", ["depth", "position", "flat normal", "smooth normal", "shade"])
def test_gradcheck_interior(what, backend):
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


def test_gradcheck_camera(backend):
    v, f = box()
    eye = CAM.eye.clone().requires_grad_(True)
    fov = CAM.fov_deg.clone().requires_grad_(True)

    def fn(e, fv):
        cam = type(CAM)(e, CAM.target, CAM.up, fv, CAM.width, CAM.height, cx=19.0, cy=17.5)
        r = D.rasterize(v, f, cam)
        return torch.stack([D.depth(v, f, cam, r), D.vertex_normal_image(v, f, r)[..., 0]], -1)

    off = type(CAM)(CAM.eye, CAM.target, CAM.up, CAM.fov_deg, CAM.width, CAM.height, cx=19.0, cy=17.5)
    assert torch.autograd.gradcheck(_interior(v, f, lambda e: fn(e, fov), off), (eye,))
    assert torch.autograd.gradcheck(_interior(v, f, lambda fv: fn(CAM.eye, fv), off), (fov,))


# -- antialiasing ---------------------------------------------------------------------------------------

def _scene():
    """A box with a triangle floating in front of it: silhouette edges against the background and an
    occlusion edge against the box."""
    v, f = box()
    tri = torch.tensor([[-0.1, -0.3, 0.9], [0.5, 0.1, 0.8], [0.0, 0.45, 0.85]], dtype=torch.float64)
    return torch.cat([v, tri]), torch.cat([f, torch.tensor([[8, 9, 10]])])


@pytest.mark.parametrize("image", ["mask", "shade"])
def test_antialias_gradient_matches_finite_differences(image, backend):
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


def test_antialiased_coverage_follows_the_exact_area(backend):
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


def test_antialias_leaves_interiors_and_open_mesh_seams_alone(backend):
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


def test_render_deferred_outputs(backend):
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


def test_settings_and_empty_views(backend):
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


# -- the native backend against the eager one ---------------------------------------------------------------

def _outputs_and_grads(mesh, cam, backend, dtype=torch.float64):
    """Every output of render_deferred (smooth normals, antialiased), an interpolated attribute, and the
    gradients of a weighted sum of them w.r.t. the vertices, the attribute and the camera's eye and fov."""
    v = mesh.verts.to(dtype).clone().requires_grad_(True)
    attr = torch.linspace(-1.0, 2.0, 2 * v.shape[0], dtype=dtype).view(-1, 2).requires_grad_(True)
    eye = cam.eye.to(dtype).clone().requires_grad_(True)
    fov = cam.fov_deg.to(dtype).clone().requires_grad_(True)
    view = type(cam)(eye, cam.target.to(dtype), cam.up.to(dtype), fov, cam.width, cam.height, cx=cam.cx,
                     cy=cam.cy)
    out = D.render_deferred(TriMesh(v, mesh.faces, mesh.groups), view, D.DeferredSettings(smooth=True,
                                                                                          backend=backend))
    extra = D.interpolate(attr, out.raster, mesh.faces, background=0.5)
    images = {"depth": out.depth, "normal": out.normal, "image": out.image, "mask": out.mask, "attr": extra,
              "bary": out.raster.bary}
    g = torch.Generator().manual_seed(3)
    loss = sum((x * torch.rand(x.shape, generator=g, dtype=dtype)).sum() for x in images.values())
    loss.backward()
    grads = {"verts": v.grad, "attr": attr.grad, "eye": eye.grad, "fov": fov.grad}
    return {k: x.detach() for k, x in images.items()}, grads, out


def _scenes():
    """The box with a triangle in front of it (occlusion edges), the mug scan (a closed mesh with thin walls)
    from a view with an off-center principal point, each with part labels."""
    v, f = _scene()
    mug = load_mesh(real_path("vessels/probcomp_mug.obj"), up="y")
    cam = orbit_camera(200.0, -15.0, 3.2, width=64, height=48)
    cam = type(cam)(cam.eye, cam.target, cam.up, cam.fov_deg, 64, 48, cx=30.5, cy=25.0)
    return [(TriMesh(v, f, torch.arange(f.shape[0]) % 3), CAM),
            (TriMesh(mug.verts.double(), mug.faces, torch.arange(mug.faces.shape[0]) % 2), cam)]


@needs_native
@pytest.mark.parametrize("scene", [0, 1])
def test_native_matches_eager_in_float64(scene):
    mesh, cam = _scenes()[scene]
    (img0, g0, out0), (img1, g1, out1) = (_outputs_and_grads(mesh, cam, b) for b in ("eager", "native"))
    assert out1.raster.backend == "native" and out0.raster.backend == "eager"
    for dtype in (torch.float64, torch.float32):
        sil = [D.silhouette_edges(mesh.verts.to(dtype), mesh.faces, cam, backend=b) for b in ("eager", "native")]
        assert torch.equal(*sil) and sil[0].any()
    assert torch.equal(out0.raster.face, out1.raster.face) and torch.equal(out0.parts, out1.parts)
    assert torch.allclose(out0.raster.zbuf, out1.raster.zbuf, rtol=1e-13, atol=0)  # inf where empty in both
    for k in img0:
        assert (img0[k] - img1[k]).abs().max() <= 1e-12, k
    for k in g0:
        assert (g0[k] - g1[k]).norm() <= 1e-11 * g0[k].norm() + 1e-13, k


@needs_native
@pytest.mark.parametrize("scene", [0, 1])
def test_native_in_float32_is_as_close_to_float64_as_eager(scene):
    """Barycentrics are triple products that cancel: both backends lose digits in float32 (the native one
    computes them in double from the float32 vertices), neither more than a few times the other."""
    mesh, cam = _scenes()[scene]
    ref, gref, _ = _outputs_and_grads(mesh, cam, "eager")
    (img0, g0, out0), (img1, g1, out1) = (_outputs_and_grads(mesh, cam, b, torch.float32)
                                          for b in ("eager", "native"))
    assert torch.equal(out0.raster.face, out1.raster.face)
    assert img1["image"].dtype == torch.float32 and g1["verts"].dtype == torch.float32
    for k in ref:
        err0, err1 = ((x[k].double() - ref[k]).abs().max() for x in (img0, img1))
        assert err1 <= 2 * err0 + 1e-6, (k, err0, err1)
    for k in ("verts", "attr"):
        err0, err1 = ((x[k].double() - gref[k]).norm() / gref[k].norm() for x in (g0, g1))
        assert err1 <= 2 * err0 + 1e-6, (k, err0, err1)


@needs_native
def test_native_coverage_and_faces_are_the_exact_rasterizers():
    mesh = load_mesh(real_path("buildings/denhaag_84A7976B_lod2.obj"), up="z")
    for cam in (input_views(1, 96)[0], orbit_camera(120.0, 35.0, 3.0, width=80, height=72)):
        fr = exact_rasterize(mesh.verts.double(), mesh.faces, cam)
        r = D.rasterize(mesh.verts, mesh.faces, cam, backend="native")
        assert torch.equal(r.mask, fr.mask) and torch.equal(r.face, fr.face)
        assert torch.allclose(r.zbuf, fr.depth, rtol=1e-13, atol=0)


@needs_native
def test_native_bits_do_not_depend_on_the_thread_count():
    mesh, cam = _scenes()[1]
    before = torch.get_num_threads()
    try:
        runs = []
        for n in (1, 2):
            torch.set_num_threads(n)
            runs.append(_outputs_and_grads(mesh, cam, "native", torch.float32)[:2])
    finally:
        torch.set_num_threads(before)
    (img1, g1), (img2, g2) = runs
    assert all(torch.equal(img1[k], img2[k]) for k in img1) and all(torch.equal(g1[k], g2[k]) for k in g1)


@needs_native
def test_native_bits_do_not_depend_on_the_instruction_set(tmp_path, monkeypatch):
    """As the soft kernel (issue #28): built for this CPU, for AVX2 (x86-64-v3) and for plain x86-64, the
    kernel gives the same outputs and gradients bit for bit."""
    import platform

    from ipm import native

    if platform.machine() not in ("x86_64", "AMD64"):
        pytest.skip("compares x86-64 instruction sets")
    mesh, cam = _scenes()[1]
    runs = {}
    try:
        for march in ("-march=native", "-march=x86-64-v3", "-march=x86-64"):
            built = tuple(([f if not f.startswith("-march=") else march for f in cflags], libs)
                          for cflags, libs in native.FLAGS)
            monkeypatch.setattr(native, "FLAGS", built)
            monkeypatch.setenv("IPM_CACHE_DIR", str(tmp_path / march))
            native.forget("deferred")
            for dtype in (torch.float32, torch.float64):
                runs[march, dtype] = _outputs_and_grads(mesh, cam, "native", dtype)[:2]
    finally:
        native.forget("deferred")
    for (march, dtype), (img, g) in runs.items():
        img0, g0 = runs["-march=native", dtype]
        assert all(torch.equal(img0[k], img[k]) for k in img0), (march, dtype)
        assert all(torch.equal(g0[k], g[k]) for k in g0), (march, dtype)


def test_native_falls_back_to_eager_without_the_kernel(monkeypatch):
    mesh, cam = _scenes()[0]
    expected = _outputs_and_grads(mesh, cam, "eager")
    monkeypatch.setattr(deferred_native, "_kernel", lambda: None)
    for backend in ("native", None):
        img, g, out = _outputs_and_grads(mesh, cam, backend)
        assert out.raster.backend == "eager"
        assert all(torch.equal(expected[0][k], img[k]) for k in img)
        assert all(torch.equal(expected[1][k], g[k]) for k in g)
    with pytest.raises(InputError):
        D.DeferredSettings(backend="cuda")
    with pytest.raises(InputError):
        D.rasterize(mesh.verts, mesh.faces, cam, backend="fast")


@needs_native
def test_native_checks_indices_and_stays_finite_with_non_finite_vertices():
    v, f = _scene()
    r = D.rasterize(v, f, CAM, backend="native")
    with pytest.raises(InputError):
        D.interpolate(v, r, f[:5])  # not the faces that were rasterized
    with pytest.raises(InputError):
        D.interpolate(v[:4], r, f)
    with pytest.raises(InputError):
        D.antialias(r.mask.double(), r, v, f, CAM, torch.ones(5, 3, dtype=torch.bool))
    bad = v.clone()
    bad[9] = float("nan")  # a vertex of the floating triangle: the box is drawn alone
    for backend in ("eager", "native"):
        out = D.render_deferred(TriMesh(bad, f), CAM, D.DeferredSettings(backend=backend))
        assert torch.equal(out.raster.face, D.rasterize(v, f[:12], CAM, backend="eager").face)
        assert torch.isfinite(out.image).all() and torch.isfinite(out.depth).all()


@needs_native
def test_the_kernels_header_declares_what_its_source_defines():
    from ipm import native

    decl = native.declarations("deferred")
    names = ["dr_zbuf"] + [f"dr_{op}_{way}_{t}" for op in ("bary", "interp", "aa") for way in ("fwd", "bwd")
                           for t in "fd"] + ["dr_silhouette_f", "dr_silhouette_d"]
    for name in names:
        assert f"{name}(" in decl and callable(getattr(native.load("deferred").lib, name))
    assert '#include "deferred.h"' in (native.HERE / "deferred.c").read_text()
