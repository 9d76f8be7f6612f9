"""Deferred renderer speed: all outputs (depth, flat and smooth normals, part labels, antialiased shaded
image and mask) forward and forward+backward for a ~10k-face mesh at 256^2 (and 1k / 50k faces, 128^2 /
512^2 around it), float32, with 1 and 2 torch threads; median and best of repeats, and the share of each
op in one forward+backward.

Meshes and view are those of :mod:`benchmarks.bench_render` (the scanned mug, decimated; the protocol's
first input view, where the object fills most of the image).
"""

from __future__ import annotations

import itertools
import time
from pathlib import Path

import torch

from benchmarks.bench_render import _cache, _loadavg
from benchmarks.common import timings as timeit
from benchmarks.common import write_results

GRID = ((10_000, 256), (1_000, 256), (50_000, 256), (10_000, 128), (10_000, 512))
THREADS = (1, 2)
TARGET_S = 0.080  # 10k faces, 256^2, forward + backward


def _loss(out) -> torch.Tensor:
    return out.image.sum() + out.mask.sum() + out.depth.sum() + out.normal.sum()


def run(out_dir: Path) -> list[dict]:
    from ipm.render.camera import input_views
    from ipm.render.deferred import DeferredSettings, render_deferred
    from ipm.types import TriMesh

    threads_before = torch.get_num_threads()
    settings = DeferredSettings(smooth=True)
    load_before = _loadavg()
    rows = []
    for (n, size), threads in itertools.product(GRID, THREADS):
        if (n, size) != GRID[0] and threads != 2:
            continue  # the 1-thread column only for the target point
        torch.set_num_threads(threads)
        verts, faces, source = _cache[n]
        cam = input_views(1, size)[0]
        groups = torch.arange(faces.shape[0]) % 4

        def fwd_bwd():
            v = verts.clone().requires_grad_(True)
            _loss(render_deferred(TriMesh(v, faces, groups), cam, settings)).backward()

        def fwd():
            with torch.no_grad():
                render_deferred(TriMesh(verts, faces, groups), cam, settings)

        t_fb, b_fb = timeit(fwd_bwd)
        t_f, b_f = timeit(fwd)
        row = {"measure": f"deferred {size}^2, {faces.shape[0]} faces ({source})", "threads": threads,
               "fwd+bwd ms": 1e3 * t_fb, "best fwd+bwd ms": 1e3 * b_fb, "fwd ms": 1e3 * t_f,
               "best fwd ms": 1e3 * b_f, "target": "-", "ok": "-"}
        if (n, size) == GRID[0]:
            row["target"] = f"fwd+bwd <= {1e3 * TARGET_S:.0f} ms"
            row["ok"] = f"median {t_fb <= TARGET_S}, best {b_fb <= TARGET_S}"
        rows.append(row)

    torch.set_num_threads(2)
    split = _op_split(*_cache[GRID[0][0]][:2], input_views(1, GRID[0][1])[0])
    torch.set_num_threads(threads_before)
    notes = ("All outputs: depth, smooth normals, part labels, Lambert image and coverage, both antialiased; "
             "loss = sum of image + mask + depth + normals; float32 vertices; times include building the "
             "silhouette-edge topology every call. Op split (best of 7, 2 threads, 10k faces, 256^2, "
             f"forward ms): {split}. Load average (1 min) before / after: {load_before} / {_loadavg()} (2 "
             "shared cores: other jobs slow the 2-thread runs down). This file alone: "
             "`python -m benchmarks.run results/perf deferred`; the threads column is torch's intra-op "
             "thread count for that row.")
    write_results(out_dir, "deferred", "Deferred renderer (rasterize, interpolate, antialias, shade): "
                  "all outputs, forward and forward+backward", rows, notes)
    return rows


def _op_split(verts, faces, cam) -> str:
    from ipm.render import deferred as D
    from ipm.render import raster

    def best(fn, k=7):
        fn()
        ts = []
        for _ in range(k):
            t0 = time.perf_counter()
            fn()
            ts.append(time.perf_counter() - t0)
        return 1e3 * min(ts)

    with torch.no_grad():
        r = D.rasterize(verts, faces, cam)
        n = D.vertex_normal_image(verts, faces, r)
        img = D.shade(n, r.mask)
        sil = D.silhouette_edges(verts, faces, cam)
        parts = {
            "exact raster": best(lambda: raster.rasterize(verts, faces, cam)),
            "rasterize (incl. exact)": best(lambda: D.rasterize(verts, faces, cam)),
            "depth": best(lambda: D.depth(verts, faces, cam, r)),
            "smooth normals": best(lambda: D.vertex_normal_image(verts, faces, r)),
            "shade": best(lambda: D.shade(n, r.mask)),
            "silhouette edges": best(lambda: D.silhouette_edges(verts, faces, cam)),
            "antialias (2 channels)": best(lambda: D.antialias(torch.stack([img, img], -1), r, verts, faces,
                                                                cam, sil)),
        }
    return ", ".join(f"{k} {v:.1f}" for k, v in parts.items())
