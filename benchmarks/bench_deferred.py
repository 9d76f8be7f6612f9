"""Deferred renderer speed, the native backend (the C kernel) and the eager one side by side: all outputs
(depth, smooth normals, part labels, antialiased shaded image and mask) forward and forward+backward for a
~10k-face mesh at 128^2 and 256^2 (and 1k / 50k faces, 512^2 around it), float32, one torch thread (and the
native backend on two at the target point); median and best of repeats, the backends called in turn so that
the machine's load falls on both alike; and the share of each op in one forward pass.

Meshes and view are those of :mod:`benchmarks.bench_render` (the scanned mug, decimated; the protocol's
first input view, where the object fills most of the image).
"""

from __future__ import annotations

import time
from pathlib import Path

import torch

from benchmarks.bench_render import _cache, _loadavg
from benchmarks.common import paired_timings, write_results

GRID = ((10_000, 256), (10_000, 128), (1_000, 256), (50_000, 256), (10_000, 512))
BACKENDS = ("native", "eager")
TARGET_S = 0.060  # native, 10k faces, 256^2, forward + backward, one thread (issue #30)
REPEAT = 9


def _loss(out) -> torch.Tensor:
    return out.image.sum() + out.mask.sum() + out.depth.sum() + out.normal.sum()


def _calls(n: int, size: int, backend: str) -> dict:
    """The forward+backward and forward-only calls of one grid point and backend."""
    from ipm.render.camera import input_views
    from ipm.render.deferred import DeferredSettings, render_deferred
    from ipm.types import TriMesh

    verts, faces, _ = _cache[n]
    cam = input_views(1, size)[0]
    groups = torch.arange(faces.shape[0]) % 4
    settings = DeferredSettings(smooth=True, backend=backend)

    def fwd_bwd():
        v = verts.clone().requires_grad_(True)
        _loss(render_deferred(TriMesh(v, faces, groups), cam, settings)).backward()

    def fwd():
        with torch.no_grad():
            render_deferred(TriMesh(verts, faces, groups), cam, settings)

    return {f"{backend} fb": fwd_bwd, f"{backend} f": fwd}


def _row(n: int, size: int, backend: str, threads: int, t: dict, load: str) -> dict:
    faces = _cache[n][1].shape[0]
    (m_fb, b_fb), (m_f, b_f) = t[f"{backend} fb"], t[f"{backend} f"]
    row = {"measure": f"deferred {size}^2, {faces} faces ({_cache[n][2]})", "backend": backend,
           "threads": threads, "fwd+bwd ms": 1e3 * m_fb, "best fwd+bwd ms": 1e3 * b_fb, "fwd ms": 1e3 * m_f,
           "best fwd ms": 1e3 * b_f, "load": load, "target": "-", "ok": "-"}
    if (n, size) == GRID[0] and backend == "native" and threads == 1:
        row["target"] = f"fwd+bwd <= {1e3 * TARGET_S:.0f} ms"
        row["ok"] = f"median {m_fb <= TARGET_S}, best {b_fb <= TARGET_S}"
    return row


def run(out_dir: Path) -> list[dict]:
    from ipm.render.camera import input_views

    threads_before = torch.get_num_threads()
    load_before = _loadavg()
    rows, speedup = [], {}
    try:
        torch.set_num_threads(1)
        for n, size in GRID:
            fns = {k: f for b in BACKENDS for k, f in _calls(n, size, b).items()}
            t = paired_timings(fns, REPEAT)
            rows += [_row(n, size, b, 1, t, _loadavg()) for b in BACKENDS]
            speedup[f"{_cache[n][1].shape[0]} faces {size}^2"] = t["eager fb"][0] / t["native fb"][0]
        torch.set_num_threads(2)
        t = paired_timings(_calls(*GRID[0], "native"), REPEAT)
        rows.append(_row(*GRID[0], "native", 2, t, _loadavg()))
        torch.set_num_threads(1)
        cam = input_views(1, GRID[0][1])[0]
        split = {b: _op_split(*_cache[GRID[0][0]][:2], cam, b) for b in BACKENDS}
        notes = ("All outputs: depth, smooth normals, part labels, Lambert image and coverage, both antialiased; "
                 "loss = sum of image + mask + depth + normals; float32 vertices; times include building the "
                 "silhouette-edge topology every call. The two backends' calls alternate within each repeat "
                 f"(median and best of {REPEAT}); eager / native forward+backward (medians): "
                 + ", ".join(f"{k} {r:.1f}x" for k, r in speedup.items()) + ". Op split (best of 7, one "
                 "thread, 10k faces, 256^2, forward ms): "
                 + "; ".join(f"{b}: {v}" for b, v in split.items()) + ". Load average (1 min) before / after: "
                 f"{load_before} / {_loadavg()} (2 shared cores), and per row in the load column; with a load "
                 "above 2 the 2-thread row measures threads waiting for busy cores (issue #28: ipm.threads only "
                 "gives a second thread where a core is idle). This file alone: `python -m benchmarks.run "
                 "results/perf deferred`; the threads column is torch's intra-op thread count for that row (the "
                 "native kernel's z-buffer uses them).")
        write_results(out_dir, "deferred", "Deferred renderer (rasterize, interpolate, antialias, shade): "
                      "native and eager backends, all outputs, forward and forward+backward", rows, notes)
    finally:
        torch.set_num_threads(threads_before)
    return rows


def _op_split(verts, faces, cam, backend: str) -> str:
    from ipm.render import deferred as D

    def best(fn, k=7):
        fn()
        ts = []
        for _ in range(k):
            t0 = time.perf_counter()
            fn()
            ts.append(time.perf_counter() - t0)
        return 1e3 * min(ts)

    with torch.no_grad():
        r = D.rasterize(verts, faces, cam, backend=backend)
        n = D.vertex_normal_image(verts, faces, r)
        img = D.shade(n, r.mask)
        sil = D.silhouette_edges(verts, faces, cam)
        parts = {
            "rasterize": best(lambda: D.rasterize(verts, faces, cam, backend=backend)),
            "depth": best(lambda: D.depth(verts, faces, cam, r)),
            "smooth normals": best(lambda: D.vertex_normal_image(verts, faces, r)),
            "shade": best(lambda: D.shade(n, r.mask)),
            "silhouette edges": best(lambda: D.silhouette_edges(verts, faces, cam)),
            "antialias (2 channels)": best(lambda: D.antialias(torch.stack([img, img], -1), r, verts, faces,
                                                                cam, sil)),
        }
    return ", ".join(f"{k} {v:.1f}" for k, v in parts.items())
