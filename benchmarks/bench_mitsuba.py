"""The soft silhouette against Mitsuba 3, side by side in one process: forward + backward w.r.t. the
vertex positions of the scanned mug decimated to 10k faces (the mesh of :mod:`benchmarks.bench_render`),
seen from the protocol's first input view, at 128^2 and 256^2, with 1 and 2 threads each.

ipm: :func:`ipm.render.soft.soft_silhouette` (sigma 1 px^2, float32; the default backend "native",
and "eager" for comparison), loss = sum of the image times fixed random weights, ``backward()``.
Mitsuba 3 (variant ``llvm_ad_rgb``): the mesh as an area emitter (radiance 1) on a black background,
integrator ``direct_projective`` with ``sppi = 0`` (no indirect discontinuities: only the silhouette
term and the continuous part), 4 samples per pixel, box pixel filter, a perspective sensor with the same
eye, target, up, vertical fov (``fov_axis = 'y'``) and size; per repetition the vertex positions are set
and marked for gradients (``params.update()``, which is what every step of a fit pays: Mitsuba rebuilds
its BVH), then render, the same weighted loss, ``dr.backward`` and the gradient read back as a NumPy
array.

Repetitions alternate between ipm (native, eager) and Mitsuba so that other jobs on a shared machine
slow all down alike. Each timed step is a step in its steady state, as in a fit's loop: a pause of
``SETTLE`` seconds first (the previous step's idle threads stop spinning: Dr.Jit's workers spin for several
milliseconds of CPU after a job, libgomp's up to about 3 ms, and would compete for the cores with the next
measurement), then an untimed step of the same renderer (its own thread pool awake, its caches warm),
then the timed one. Threads: ``torch.set_num_threads`` for ipm, ``drjit.set_thread_count`` for Dr.Jit's pool.
The sanity check compares Mitsuba's primal image (64 spp, coverage > 0.5) with ipm's exact hard mask
(IoU). Mitsuba is an optional extra (``pip install mitsuba``): where it does not import, one row says so.

A depth render too (issue #30), forward + backward w.r.t. the vertex positions of a fixed random weighting
of the image, as a depth term of a fit pays it: ipm's deferred renderer's rasterizer and depth op
(:func:`ipm.render.deferred.rasterize` and :func:`~ipm.render.deferred.depth`: the visible face per pixel
centre and the perspective-correct interpolated view-axis depth; the default backend and the native one),
and Mitsuba's differentiable ray casting of one ray per pixel centre (``sensor.sample_ray``,
``scene.ray_intersect``, the hit's distance from the eye along the view axis: the same view-axis depth, 0
where no surface), with ``params.update()`` as above. Both differentiate the depth inside the triangles only
(neither has an edge term for depth); their depth images are compared (largest difference where both see
the mesh).
"""

from __future__ import annotations

import itertools
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from benchmarks.bench_render import _cache, _loadavg
from benchmarks.common import write_results

FACES = 10_000
SIZES = (128, 256)
THREADS = (1, 2)
SIGMA = 1.0  # squared pixels
SPP = 4
REPEAT = 9
WARMUP = 2
SETTLE = 0.05  # seconds of pause before each measured pair of steps (see the module docstring)
TARGET = 10.0  # Mitsuba / ipm at 128^2


def _mitsuba_scene(verts: np.ndarray, faces: np.ndarray, cam, ply: Path):
    """(scene, params, key) for the mesh as an area emitter seen by ``cam`` (see the module docstring)."""
    import mitsuba as mi
    import trimesh

    trimesh.Trimesh(verts, faces, process=False).export(ply)
    eye, target, up = (cam.eye.tolist(), cam.target.tolist(), cam.up.tolist())
    scene = mi.load_dict({
        "type": "scene",
        "integrator": {"type": "direct_projective", "sppi": 0},
        "sensor": {
            "type": "perspective", "fov": float(cam.fov_deg), "fov_axis": "y",
            "to_world": mi.ScalarTransform4f().look_at(origin=eye, target=target, up=up),
            "film": {"type": "hdrfilm", "width": cam.width, "height": cam.height, "rfilter": {"type": "box"},
                     "pixel_format": "rgb", "sample_border": True},
            "sampler": {"type": "independent", "sample_count": SPP},
        },
        "mug": {"type": "ply", "filename": str(ply), "face_normals": True,
                "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.0}},
                "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 1.0}}},
    })
    params = mi.traverse(scene)
    # the loader may reorder or merge vertices: set ours, so both renderers see the same mesh
    params["mug.vertex_positions"] = mi.Float(verts.astype(np.float32).ravel())
    params["mug.faces"] = mi.UInt32(faces.astype(np.uint32).ravel())
    params.update()
    return scene, params, "mug.vertex_positions"


def _mitsuba_step(scene, params, key, flat: np.ndarray, weight, seed: int) -> np.ndarray:
    """One forward + backward of Mitsuba; returns the gradient w.r.t. the vertex positions (V * 3,)."""
    import drjit as dr
    import mitsuba as mi

    params[key] = mi.Float(flat)
    dr.enable_grad(params[key])
    params.update()
    img = mi.render(scene, params, spp=SPP, seed=seed)
    dr.backward(dr.sum(img * weight, axis=None))
    return dr.grad(params[key]).numpy()


def _mitsuba_depth_step(scene, params, key, flat: np.ndarray, weight) -> tuple:
    """One forward + backward of Mitsuba's depth image (module docstring): (depth (H, W), gradient (V * 3,))."""
    import drjit as dr
    import mitsuba as mi

    params[key] = mi.Float(flat)
    dr.enable_grad(params[key])
    params.update()
    sensor = scene.sensors()[0]
    w, h = sensor.film().size()
    idx = dr.arange(mi.UInt32, w * h)
    centre = mi.Point2f((mi.Float(idx % w) + 0.5) / w, (mi.Float(idx // w) + 0.5) / h)
    ray, _ = sensor.sample_ray(0.0, 0.0, centre, mi.Point2f(0.5, 0.5))
    si = scene.ray_intersect(ray)
    to_world = sensor.world_transform()
    forward = to_world @ mi.Vector3f(0.0, 0.0, 1.0)
    eye = to_world @ mi.Point3f(0.0, 0.0, 0.0)
    # the hit's distance from the eye along the view axis (the rays start on the near plane: si.t is from there)
    z = dr.select(si.is_valid(), dr.dot(si.p - eye, forward), 0.0)
    dr.backward(dr.sum(z * weight, axis=None))
    return z.numpy().reshape(h, w), dr.grad(params[key]).numpy()


def _depth_rows(scene, params, key, verts: torch.Tensor, faces: torch.Tensor, cam, gen: torch.Generator,
                source: str) -> list[dict]:
    """The depth render side by side (module docstring), for each thread count."""
    import drjit as dr
    import mitsuba as mi

    from ipm.render.deferred import depth, rasterize

    size = cam.width
    weight_t = torch.rand(size, size, generator=gen)
    weight_m = mi.Float(weight_t.numpy().ravel())
    flat = verts.numpy().astype(np.float32).ravel()

    def ipm_step(backend=None):
        v = verts.clone().requires_grad_(True)
        d = depth(v, faces, cam, rasterize(v, faces, cam, backend=backend))
        (d * weight_t).sum().backward()
        return d.detach()

    seen = ipm_step().numpy()
    z, _ = _mitsuba_depth_step(scene, params, key, flat, weight_m)
    both = (seen > 0) & (z > 0)
    diff = np.abs(seen[both] - z[both]) if both.any() else np.full(1, np.nan)
    rows = []
    for threads in THREADS:
        torch.set_num_threads(threads)
        dr.set_thread_count(threads)
        for _ in range(WARMUP):
            ipm_step(), ipm_step("native"), _mitsuba_depth_step(scene, params, key, flat, weight_m)
        t_ipm, t_native, t_mi = [], [], []
        for _ in range(REPEAT):
            t_ipm.append(_steady(ipm_step))
            t_native.append(_steady(lambda: ipm_step("native")))
            t_mi.append(_steady(lambda: _mitsuba_depth_step(scene, params, key, flat, weight_m)))
        m_ipm, m_nat, m_mi = (statistics.median(t) for t in (t_ipm, t_native, t_mi))
        rows.append({"measure": f"depth {size}^2, {faces.shape[0]} faces ({source})", "threads": threads,
                     "ipm ms": 1e3 * m_ipm, "best ipm ms": 1e3 * min(t_ipm),
                     "Mitsuba ms": 1e3 * m_mi, "best Mitsuba ms": 1e3 * min(t_mi),
                     "Mitsuba / ipm": m_mi / m_ipm, "best / best": min(t_mi) / min(t_ipm),
                     "ipm native ms": 1e3 * m_nat, "Mitsuba / ipm native": m_mi / m_nat,
                     "depth difference, max / median": f"{diff.max():.1e} / {np.median(diff):.1e}",
                     "pixels": f"{int((seen > 0).sum())} / {int((z > 0).sum())}",
                     "load": _loadavg()})
    return rows


def _steady(step) -> float:
    """Seconds of one call of ``step`` in its steady state: after a pause and an untimed call."""
    time.sleep(SETTLE)
    step()
    t0 = time.perf_counter()
    step()
    return time.perf_counter() - t0


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max((a | b).sum(), 1))


def run(out_dir: Path) -> list[dict]:
    from ipm.render.camera import input_views
    from ipm.render.raster import hard_mask
    from ipm.render.soft import native_available, soft_silhouette

    verts, faces, source = _cache[FACES]
    backend = "native" if native_available() else "eager (no C compiler)"
    threads_before = torch.get_num_threads()
    load_before = _loadavg()
    try:
        import drjit as dr
        import mitsuba as mi

        mi.set_variant("llvm_ad_rgb")
        mi.set_log_level(mi.LogLevel.Error)  # the scan has non-manifold vertices: a long warning per load
        versions = f"mitsuba {mi.__version__}, drjit {dr.__version__}"
    except Exception as e:  # not installed, or no LLVM for the CPU backend
        reason = f"{type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}"
        rows = [{"measure": "Mitsuba 3 comparison skipped", "reason": reason}]
        for name, what in (("mitsuba", "Soft silhouette"), ("mitsuba_depth", "Depth render")):
            write_results(out_dir, name, f"{what} vs Mitsuba 3 (skipped)", rows,
                          "Mitsuba 3 is an optional extra (`pip install mitsuba`); it did not import here.")
        return rows

    rows, depth_rows = [], []
    gen = torch.Generator().manual_seed(0)
    tmp = tempfile.TemporaryDirectory()
    try:
        for size in SIZES:
            cam = input_views(1, size)[0]
            weight_t = torch.rand(size, size, generator=gen)
            weight_m = mi.TensorXf(np.repeat(weight_t.numpy()[:, :, None], 3, axis=2) / 3.0)
            scene, params, key = _mitsuba_scene(verts.double().numpy(), faces.numpy(), cam,
                                                Path(tmp.name) / f"mug{size}.ply")
            flat = verts.numpy().astype(np.float32).ravel()
            check = mi.render(scene, spp=64, seed=1).numpy()[..., 0] > 0.5
            iou = _iou(check, hard_mask(verts, faces, cam).numpy())

            def ipm_step(backend=None):
                v = verts.clone().requires_grad_(True)
                (soft_silhouette(v, faces, cam, sigma=SIGMA, backend=backend) * weight_t).sum().backward()
                return v.grad

            for threads in THREADS:
                torch.set_num_threads(threads)
                dr.set_thread_count(threads)
                seed = itertools.count()
                for _ in range(WARMUP):
                    ipm_step()
                    ipm_step("eager")
                    _mitsuba_step(scene, params, key, flat, weight_m, next(seed))
                t_ipm, t_eager, t_mi = [], [], []
                for _ in range(REPEAT):  # alternate, so that load hits all alike
                    t_ipm.append(_steady(ipm_step))
                    t_eager.append(_steady(lambda: ipm_step("eager")))
                    t_mi.append(_steady(lambda: _mitsuba_step(scene, params, key, flat, weight_m, next(seed))))
                m_ipm, m_mi = statistics.median(t_ipm), statistics.median(t_mi)
                ratio = m_mi / m_ipm
                row = {"measure": f"{size}^2, {faces.shape[0]} faces ({source})", "threads": threads,
                       "ipm ms": 1e3 * m_ipm, "best ipm ms": 1e3 * min(t_ipm),
                       "Mitsuba ms": 1e3 * m_mi, "best Mitsuba ms": 1e3 * min(t_mi),
                       "Mitsuba / ipm": ratio, "best / best": min(t_mi) / min(t_ipm),
                       "ipm eager ms": 1e3 * statistics.median(t_eager), "best ipm eager ms": 1e3 * min(t_eager),
                       "Mitsuba / ipm eager": m_mi / statistics.median(t_eager),
                       "mask IoU": iou, "load": _loadavg(), "target": "-", "ok": "-"}
                if size == 128:
                    row["target"], row["ok"] = f">= {TARGET:.0f}x", str(ratio >= TARGET)
                rows.append(row)
            if size == max(SIZES):
                depth_rows.extend(_depth_rows(scene, params, key, verts, faces, cam, gen, source))
    finally:
        tmp.cleanup()
        torch.set_num_threads(threads_before)
    notes = (f"ipm: soft_silhouette, sigma = {SIGMA} px^2, float32, default backend ({backend}; 'ipm eager': "
             "backend='eager', the pure-torch kernels, as before the native kernel); "
             f"Mitsuba: {versions}, "
             f"llvm_ad_rgb, direct_projective (sppi = 0), {SPP} spp, box filter, the mesh as an area emitter; "
             "both: forward + backward of sum(image * fixed random weights) w.r.t. the vertex positions "
             f"(Mitsuba's includes params.update(), its BVH rebuild). Median and best of {REPEAT} repetitions "
             f"after {WARMUP} warm-ups, ipm, ipm eager and Mitsuba alternating, each timed step in its steady "
             f"state: a {1e3 * SETTLE:.0f} ms pause (the previous renderer's idle threads stop spinning) and an "
             "untimed step of the same renderer first. Threads: torch.set_num_threads and "
             "drjit.set_thread_count. mask IoU: Mitsuba's primal image at 64 spp (> 0.5) against ipm's exact "
             f"hard mask. Load average (1 min) before: {load_before}; 'load' is after each row.")
    write_results(out_dir, "mitsuba", "Soft silhouette (ipm) vs Mitsuba 3 (llvm_ad_rgb), forward + backward",
                  rows, notes)
    write_results(out_dir, "mitsuba_depth", "Depth render (ipm) vs Mitsuba 3 ray casting (llvm_ad_rgb), forward + "
                  "backward", depth_rows,
                  f"ipm: ipm.render.deferred.rasterize + depth (view-axis depth at pixel centres, perspective-correct, "
                  f"float32), default backend ('ipm') and backend='native' ('ipm native'); Mitsuba: {versions}, one "
                  "ray per pixel centre through sensor.sample_ray and scene.ray_intersect, the hit's distance from "
                  "the eye along the view axis, params.update() included; both: forward + backward of sum(depth * "
                  "fixed random weights) w.r.t. the vertex positions, no edge term. depth difference: the largest "
                  "and the median difference of the two depth images where both see the mesh (scene units; the "
                  "camera stands 3.2 from the centre); pixels: covered pixels, ipm / "
                  f"Mitsuba. Timing as in mitsuba.md (median and best of {REPEAT}, alternating, steady state). "
                  f"Load average (1 min) before: {load_before}; 'load' is after each row.")
    return rows
