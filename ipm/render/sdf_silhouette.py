"""Soft silhouettes, depth and normals of signed distance functions, by rays through pixel centers.

The reference for silhouettes: fits use the faster :mod:`ipm.render.sdf_mesh_silhouette` by default
(``FitSettings.sdf_silhouette``), tested against this one.

Silhouette: for each pixel ray, ``m = min_t f(o + t d)`` over the ray's stretch inside the box
``[lo, hi]`` (padded by the blur's reach), and ``silhouette = sigmoid(-m / sigma)``: about 1 where the ray
enters the solid, 0 where it passes far from it. The minimum is found without gradients:

1. sphere tracing from the box entry with steps ``max(step_scale |f|, min_step)``, which cannot jump over
   the surface when ``f`` is a distance or a bound (every node in :mod:`ipm.sdf` is), keeping the best
   sample and its neighbours; a ray stops once it is ``stop`` blur widths inside the solid or leaves
   the box;
2. a few golden-section steps between the best sample's neighbours, only for rays whose best value
   is within reach of the blur (elsewhere the silhouette is saturated at 0 or 1).

Then ``f`` is evaluated once more, with gradients, at the found points ``o + t* d`` (the envelope
theorem: d m / d q = partial f / partial q at the minimizer), so the silhouette is differentiable in
whatever ``f`` closes over (tree parameters) and in the camera (through the ray origin and direction).

Depth and normals (:func:`sdf_depth_normals`) come from plain sphere tracing, without gradients.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from ipm.errors import InputError
from ipm.render.camera import detach_camera, pixel_rays
from ipm.types import Camera

SDF = Callable[[torch.Tensor], torch.Tensor]
GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0


def _box(lo, hi, dtype, device) -> tuple[torch.Tensor, torch.Tensor]:
    lo_t = torch.as_tensor(np.asarray(lo, dtype=np.float64), dtype=dtype, device=device)
    hi_t = torch.as_tensor(np.asarray(hi, dtype=np.float64), dtype=dtype, device=device)
    if lo_t.shape != (3,) or hi_t.shape != (3,):
        raise InputError(f"box: expected lo and hi of shape (3,), got {tuple(lo_t.shape)} and "
                         f"{tuple(hi_t.shape)}")
    if not bool((hi_t > lo_t).all()):
        raise InputError(f"box: expected lo < hi on every axis, got lo={lo_t.tolist()}, hi={hi_t.tolist()}")
    return lo_t, hi_t


def ray_box(origin: torch.Tensor, dirs: torch.Tensor, lo: torch.Tensor, hi: torch.Tensor):
    """Slab test. origin (3,), dirs (N, 3) -> (t_enter (N,), t_exit (N,), hit (N,) bool), t_enter >= 0."""
    safe = torch.where(dirs.abs() < 1e-12, torch.full_like(dirs, 1e-12), dirs)
    inv = 1.0 / safe
    ta = (lo - origin) * inv
    tb = (hi - origin) * inv
    t0 = torch.minimum(ta, tb).amax(-1).clamp_min(0.0)
    t1 = torch.maximum(ta, tb).amin(-1)
    return t0, t1, t1 > t0


def default_sigma(camera: Camera, lo, hi) -> float:
    """Half a pixel's footprint at the box center's distance from the camera (world units)."""
    center = torch.as_tensor((np.asarray(lo, float) + np.asarray(hi, float)) / 2)
    dist = float(torch.linalg.vector_norm(camera.eye.detach().double().cpu() - center))
    fov = math.radians(float(camera.fov_deg.detach()))
    return 0.5 * 2.0 * dist * math.tan(fov / 2) / camera.height


@torch.no_grad()
def _trace_min(f: SDF, origin, dirs, t0, t1, sigma, *, step_scale, min_step, max_steps, stop, chunk):
    """Best sample per ray: (t_best, f_best, t_lo, t_hi) with [t_lo, t_hi] its neighbours."""
    n = dirs.shape[0]
    t = t0.clone()
    t_best = t0.clone()
    f_best = torch.full_like(t0, float("inf"))
    t_lo, t_hi = t0.clone(), t1.clone()
    t_prev = t0.clone()
    active = torch.arange(n, device=dirs.device)
    for _ in range(max_steps):
        if active.numel() == 0:
            break
        ta = t[active]
        fv = _eval(f, origin + ta[:, None] * dirs[active], chunk)
        step = torch.clamp(fv.abs() * step_scale, min=min_step)
        better = fv < f_best[active]
        idx_b = active[better]
        f_best[idx_b] = fv[better]
        t_best[idx_b] = ta[better]
        t_lo[idx_b] = t_prev[active][better]
        t_hi[idx_b] = torch.minimum(ta[better] + step[better], t1[idx_b])
        t_prev[active] = ta
        t_new = ta + step
        t[active] = t_new
        go = (t_new <= t1[active]) & (f_best[active] > -stop * sigma)
        active = active[go]
    return t_best, f_best, t_lo, t_hi


@torch.no_grad()
def _golden(f: SDF, origin, dirs, a, b, iters: int, chunk: int):
    """Golden-section search for the minimum of f along each ray within [a, b]; returns t (N,)."""
    c = b - GOLDEN * (b - a)
    d = a + GOLDEN * (b - a)
    fc = _eval(f, origin + c[:, None] * dirs, chunk)
    fd = _eval(f, origin + d[:, None] * dirs, chunk)
    for _ in range(iters):
        left = fc < fd  # the minimum is in [a, d]: the old c becomes the new d; else old d becomes new c
        b = torch.where(left, d, b)
        a = torch.where(left, a, c)
        c = b - GOLDEN * (b - a)
        d = a + GOLDEN * (b - a)
        probe = torch.where(left, c, d)
        fp = _eval(f, origin + probe[:, None] * dirs, chunk)
        fc, fd = torch.where(left, fp, fd), torch.where(left, fc, fp)
    return torch.where(fc < fd, c, d)


def _eval(f: SDF, pts: torch.Tensor, chunk: int) -> torch.Tensor:
    if pts.shape[0] <= chunk:
        return f(pts)
    return torch.cat([f(pts[i:i + chunk]) for i in range(0, pts.shape[0], chunk)])


def sdf_silhouette(f: SDF, camera: Camera, lo, hi, sigma: float | None = None, *,
                   dtype: torch.dtype = torch.float32, step_scale: float = 0.9, min_step: float | None = None,
                   max_steps: int = 256, refine: int = 12, stop: float = 12.0,
                   chunk: int = 1 << 18) -> torch.Tensor:
    """Soft silhouette (H, W) in [0, 1] of the solid ``{f < 0}`` (see the module docstring).

    f: points (N, 3) -> signed distances (N,), negative inside; gradients flow into whatever it closes
    over. camera: the view (its tensors may require grad). lo, hi: (3,) a box that bounds the solid.
    sigma: blur in world units (default: half a pixel's footprint at the box center, see
    :func:`default_sigma`). dtype: of the rays and points given to ``f``. min_step: smallest marching
    step (default 2 sigma: features thinner than about a pixel may be missed); max_steps:
    sphere-tracing steps per ray; refine: golden-section steps; stop: a ray stops this many sigmas
    inside the solid. Returns (H, W) in ``dtype``.
    """
    if sigma is None:
        sigma = default_sigma(camera, lo, hi)
    if not sigma > 0:
        raise InputError(f"sigma: expected a positive blur (world units), got {sigma}")
    dev = camera.eye.device
    cam = camera.to(dtype=dtype)
    lo_t, hi_t = _box(lo, hi, dtype, dev)
    pad = stop * sigma
    lo_t, hi_t = lo_t - pad, hi_t + pad
    origin, dirs = pixel_rays(cam)  # differentiable in the camera
    H, W = dirs.shape[:2]
    dirs = dirs.reshape(-1, 3)
    o_d, d_d = origin.detach(), dirs.detach()
    t0, t1, hit = ray_box(o_d, d_d, lo_t, hi_t)
    out = torch.zeros(H * W, dtype=dtype, device=dev)
    idx = torch.nonzero(hit).squeeze(1)
    if idx.numel() == 0:
        return out.view(H, W) + 0.0 * origin.sum()
    ms = min_step if min_step is not None else 2.0 * sigma
    tb, fb, ta, tc = _trace_min(f, o_d, d_d[idx], t0[idx], t1[idx], sigma, step_scale=step_scale, min_step=ms,
                                max_steps=max_steps, stop=stop, chunk=chunk)
    near = (fb.abs() < stop * sigma).nonzero().squeeze(1)
    if near.numel() and refine > 0:
        with torch.no_grad():
            tr = _golden(f, o_d, d_d[idx[near]], ta[near], tc[near], refine, chunk)
            fr = _eval(f, o_d + tr[:, None] * d_d[idx[near]], chunk)
            tb[near] = torch.where(fr < fb[near], tr, tb[near])
    pts = origin + tb[:, None] * dirs[idx]  # differentiable in the camera
    m = _eval(f, pts, chunk)
    return out.index_put((idx,), torch.sigmoid(-m / sigma)).view(H, W)


@dataclass(frozen=True)
class SdfPicture:
    """Sphere-traced hits: mask (H, W) bool, depth (H, W) along the view axis (inf where missed),
    normal (H, W, 3) unit world-space gradient of f (zero where missed), t (H, W) ray distance."""

    mask: torch.Tensor
    depth: torch.Tensor
    normal: torch.Tensor
    t: torch.Tensor


@torch.no_grad()
def sdf_depth_normals(f: SDF, camera: Camera, lo, hi, *, dtype: torch.dtype = torch.float32,
                      hit_eps: float | None = None, max_steps: int = 256, step_scale: float = 0.9,
                      chunk: int = 1 << 18) -> SdfPicture:
    """Depth and normals of ``{f < 0}`` by sphere tracing (no gradients), for pictures.

    hit_eps: a ray hits when ``f < hit_eps`` (default: a tenth of a pixel footprint). Normals are central
    differences of ``f``.
    """
    dev = camera.eye.device
    cam = detach_camera(camera).to(dtype=dtype)
    lo_t, hi_t = _box(lo, hi, dtype, dev)
    eps = hit_eps if hit_eps is not None else 0.2 * default_sigma(camera, lo, hi)
    origin, dirs = pixel_rays(cam)
    origin, dirs = origin.detach(), dirs.detach()
    H, W = dirs.shape[:2]
    d = dirs.reshape(-1, 3)
    t0, t1, boxhit = ray_box(origin, d, lo_t, hi_t)
    t = t0.clone()
    hit = torch.zeros_like(boxhit)
    active = torch.nonzero(boxhit).squeeze(1)
    for _ in range(max_steps):
        if active.numel() == 0:
            break
        fv = _eval(f, origin + t[active][:, None] * d[active], chunk)
        done = fv < eps
        hit[active[done]] = True
        t[active] = t[active] + torch.clamp(fv * step_scale, min=0.25 * eps)
        go = ~done & (t[active] <= t1[active])
        active = active[go]
    hit &= boxhit
    idx = torch.nonzero(hit).squeeze(1)
    normal = torch.zeros(H * W, 3, dtype=dtype, device=dev)
    if idx.numel():
        p = origin + t[idx][:, None] * d[idx]
        h = eps
        offs = torch.eye(3, dtype=dtype, device=dev) * h
        grad = torch.stack([_eval(f, p + offs[k], chunk) - _eval(f, p - offs[k], chunk)
                            for k in range(3)], -1)
        normal[idx] = grad / torch.linalg.vector_norm(grad, dim=-1, keepdim=True).clamp_min(1e-12)
    fwd = (cam.target - cam.eye)
    fwd = fwd / torch.linalg.vector_norm(fwd)
    depth = torch.where(hit, t * (d @ fwd), torch.full_like(t, float("inf")))
    tt = torch.where(hit, t, torch.full_like(t, float("inf")))
    return SdfPicture(hit.view(H, W), depth.view(H, W), normal.view(H, W, 3), tt.view(H, W))
