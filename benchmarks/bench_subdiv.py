"""Loop subdivision speed (issue #14): a closed mesh of about 16k vertices subdivided two levels (about
262k vertices), float32 and float64, forward (S V) and forward + backward (S^T G), with 1 and 2 torch
threads; the building of the composed sparse operator (libigl's matrices, once per face array) apart.

The mesh: a torus from trimesh (a genus-1 closed surface, 16,384 vertices), so that the count is exact.
Then neural subdivision's inference, two levels, of the 502-vertex real bottle scan
(``../shared/data/real/vessels/trimesh_fuze_bottle.obj``, welded) with the shipped weights, float32."""

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
    m = load_mesh(path, up="z", normalize=True)
    W, inv = np.unique(m.verts.numpy(), axis=0, return_inverse=True)
    return W, inv.reshape(-1)[m.faces.numpy()]


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
    torch.set_num_threads(before)
    notes = (f"Operator build (libigl loop_matrix twice, composed; cached per face array): {build_s:.2f} s, "
             f"{op.scipy.nnz} nonzeros, {len(NF)} faces. Medians and bests of 7 repeats after 1 warm-up; "
             "a shared machine only ever adds time, so the best is the stable number.")
    write_results(out_dir, "subdiv", "Loop subdivision (two levels, forward and backward) and neural "
                  "subdivision's inference", rows, notes)
    return rows
