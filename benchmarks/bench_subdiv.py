"""Loop subdivision speed (issue #14): a closed mesh of about 16k vertices subdivided two levels (about
262k vertices), float32 and float64, forward (S V) and forward + backward (S^T G), with 1 and 2 torch
threads; the building of the composed sparse operator (libigl's matrices, once per face array) apart.

The mesh: a torus from trimesh (a genus-1 closed surface, 16,384 vertices), so that the count is exact.
Then neural subdivision's inference, two levels, of the 502-vertex real bottle scan
(``../shared/data/real/vessels/trimesh_fuze_bottle.obj``, welded) with the shipped weights, float32.
Then one evaluation (loss and gradient) of the real-mug fit of ``experiments/subdiv_fit.toml`` (the
ocrtoc mug, the protocol's first view at 256 px, the dishes mug preset) for each way of making its mesh:
the medium and high levels of detail as they are, the low one as it is and subdivided once by Loop and
by neural subdivision; the configurations interleaved, best of 7 each, one thread."""

from __future__ import annotations

import itertools
import time
from pathlib import Path

import numpy as np
import torch

from benchmarks.common import timings, write_results

THREADS = (1, 2)
DTYPES = (torch.float32, torch.float64)


def _torus() -> tuple[np.ndarray, np.ndarray]:
    import trimesh

    m = trimesh.creation.torus(1.0, 0.35, major_sections=128, minor_sections=128)
    return np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64)


def _bottle() -> tuple[np.ndarray, np.ndarray]:
    from ipm.io.meshes import load_mesh

    path = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "real" / "vessels"
    path = path / "trimesh_fuze_bottle.obj"
    from ipm.subdiv import clean

    m = load_mesh(path, up="z", normalize=True)
    return clean(m.verts.numpy(), m.faces.numpy())


def _neural_rows() -> list[dict]:
    from ipm.subdiv import SCHEMES

    V, F = _bottle()
    scheme = SCHEMES.get("neural")
    rows = []
    for threads in THREADS:
        torch.set_num_threads(threads)
        x = torch.as_tensor(V, dtype=torch.float32)

        def infer():
            with torch.no_grad():
                scheme.subdivide(x, F, 2)

        m, b = timings(infer)
        out = scheme.subdivide(x, F, 2)[0].shape[0]
        rows.append({"vertices": f"{len(V)} -> {out} (neural)", "dtype": "float32", "threads": threads,
                     "forward ms (median)": round(1e3 * m, 2), "forward ms (best)": round(1e3 * b, 2),
                     "fwd+bwd ms (median)": "-", "fwd+bwd ms (best)": "-"})
    return rows


FIT_CONFIGS = {"medium": {}, "high": {"lod": "high"}, "low": {"lod": "low"},
               "low+loop": {"lod": "low", "subdivide": "loop"}, "low+neural": {"lod": "low", "subdivide": "neural"}}


def _fit_rows() -> list[dict]:
    from ipm.generators import get_generator
    from ipm.io.meshes import load_mesh
    from ipm.optim.fit import FitSettings, MaskTarget
    from ipm.optim.problem import Problem
    from ipm.render.camera import input_views
    from ipm.render.raster import rasterize_mesh

    path = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "real" / "vessels" / "ocrtoc_mug.ply"
    mug = load_mesh(path, up="z", normalize=True)
    cams = input_views(1, 256)
    target = MaskTarget(torch.stack([rasterize_mesh(mug, c).mask.float() for c in cams]),
                        [c.to(torch.float32) for c in cams])
    gen = get_generator("dishes")
    torch.set_num_threads(1)
    probs = {k: Problem(gen, target, FitSettings(budget=10, preset="mug", **kw)) for k, kw in FIT_CONFIGS.items()}
    times: dict[str, list[float]] = {k: [] for k in probs}
    for _ in range(8):   # interleaved, the first round a warm-up
        for k, p in probs.items():
            x = p.x0()
            t0 = time.perf_counter()
            p.objective(x, dict(p.d0), True)
            times[k].append(time.perf_counter() - t0)
    rows = []
    for k, p in probs.items():
        m = p.mesh_world(p.x0(), dict(p.d0))
        t = sorted(times[k][1:])
        rows.append({"vertices": f"real-mug fit, {k}: {m.n_verts} vertices, {m.n_faces} faces", "dtype": "float32",
                     "threads": 1, "forward ms (median)": "-", "forward ms (best)": "-",
                     "fwd+bwd ms (median)": round(1e3 * t[len(t) // 2], 2), "fwd+bwd ms (best)": round(1e3 * t[0], 2)})
    return rows


def run(out_dir: Path) -> list[dict]:
    from ipm.subdiv import SCHEMES

    V, F = _torus()
    scheme = SCHEMES.get("loop")
    t0 = time.perf_counter()
    op, NF = scheme.operator(F, len(V), 2)
    build_s = time.perf_counter() - t0
    before = torch.get_num_threads()
    rows = []
    for threads, dtype in itertools.product(THREADS, DTYPES):
        torch.set_num_threads(threads)
        x = torch.as_tensor(V, dtype=dtype)
        g = torch.randn(op.shape[0], 3, dtype=dtype)

        def forward():
            with torch.no_grad():
                op(x)

        def backward():
            xr = x.clone().requires_grad_()
            (op(xr) * g).sum().backward()

        fm, fb = timings(forward)
        bm, bb = timings(backward)
        rows.append({"vertices": f"{len(V)} -> {op.shape[0]}", "dtype": str(dtype).removeprefix("torch."),
                     "threads": threads, "forward ms (median)": round(1e3 * fm, 2), "forward ms (best)":
                     round(1e3 * fb, 2), "fwd+bwd ms (median)": round(1e3 * bm, 2),
                     "fwd+bwd ms (best)": round(1e3 * bb, 2)})
    rows += _neural_rows()
    rows += _fit_rows()
    torch.set_num_threads(before)
    notes = (f"Operator build (libigl loop_matrix twice, composed; cached per face array): {build_s:.2f} s, "
             f"{op.scipy.nnz} nonzeros, {len(NF)} faces. Medians and bests of 7 repeats after 1 warm-up; "
             "a shared machine only ever adds time, so the best is the stable number.")
    write_results(out_dir, "subdiv", "Loop subdivision (two levels, forward and backward) and neural "
                  "subdivision's inference", rows, notes)
    return rows
