"""The mesh-conversion table (issue #7, ``make table-convert``): six real meshes from ``../shared/data/real``
converted to perturbation functions and to a BSP, against marching cubes of a dense SDF grid with the
same number of parameters (one distance value per node).

Every result is meshed (``perturb``: marching cubes at 128³; ``bsp``: the exact polytope; grid: marching
cubes of the grid itself) and scored the same way, in the normalized frame the converters work in
(DESIGN.md's protocol v2: bounding-box center at the origin, farthest vertex at distance 1):

- ``parameters``: numbers in the representation (a grid: nodes);
- ``seconds``: the conversion (a grid: computing its exact signed distances);
- ``iou_3d``: winding-number occupancy on a 64³ grid (DESIGN.md);
- ``chamfer_l1``: mean of both directions' point-to-surface distances, 10,000 samples each way;
- ``vertex_dev_%``: mean and max distance of the input's vertices to the result's surface, percent of
  the bounding-box diagonal (the paper's quality measure, taken on the meshed result for every method);
- ``normal_deg``: mean angle between the input's face normal at 10,000 surface samples and the normal
  of the result's nearest triangle (inside-out or missing walls show here).

The paper's stopping rule looks at the input's vertices only; on a low-poly mesh (the LoD2 house has 16
triangles) it is met long before the surface is (compare ``vertex_dev`` with ``iou_3d``).

Usage: ``python -m benchmarks.table_convert OUT_DIR [--quick]`` (``--quick``: two meshes, small settings).
"""

from __future__ import annotations

import datetime as dt
import math
import platform
import sys
import time
from pathlib import Path

import numpy as np
import torch

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "real"
MESHES = (  # (name, path under DATA, up axis)
    ("ocrtoc mug (scan)", "vessels/ocrtoc_mug.ply", "z"),
    ("probcomp mug (scan)", "vessels/probcomp_mug.obj", "z"),  # stands on Z (experiments/table1.toml)
    ("ocrtoc bowl (scan)", "vessels/ocrtoc_bowl.ply", "z"),
    ("ocrtoc pitcher (scan)", "vessels/ocrtoc_pitcher.ply", "z"),
    ("fuze bottle (scan)", "vessels/trimesh_fuze_bottle.obj", "y"),
    ("hipped-roof house (LoD2)", "buildings/denhaag_B06DD5CD_lod2.obj", "z"),
)
PERTURB = {"tolerance": 0.01, "normal_tolerance": 20.0, "max_functions": 2000, "time_limit": 300.0}
BSP = {"planes": 32, "convexes": 8}


def dense_grid(target, parameters: int) -> tuple[object, float, int]:
    """Marching cubes of the exact signed distance sampled on ``n³ <= parameters`` nodes over the
    target's bounding box plus one cell; returns (mesh, seconds, nodes)."""
    from skimage.measure import marching_cubes

    from ipm.metrics import inside, point_to_surface
    from ipm.types import TriMesh

    n = max(4, int(math.floor(parameters ** (1 / 3) + 1e-9)))
    V, F = target.verts, target.faces
    t0 = time.perf_counter()
    lo, hi = V.min(0), V.max(0)
    h = (hi - lo) / (n - 3)
    axes = [np.linspace(lo[i] - h[i], hi[i] + h[i], n) for i in range(3)]
    pts = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    d = point_to_surface(pts, V, F)
    d[inside(pts, V, F)] *= -1
    seconds = time.perf_counter() - t0
    vol = d.reshape(n, n, n)
    if not (vol.min() < 0 < vol.max()):
        return TriMesh(torch.zeros(0, 3, dtype=torch.float64), torch.zeros(0, 3, dtype=torch.long)), seconds, n ** 3
    spacing = tuple(float(a[1] - a[0]) for a in axes)
    verts, faces, _, _ = marching_cubes(vol, 0.0, spacing=spacing)
    verts = verts + np.array([a[0] for a in axes])
    return (TriMesh(torch.as_tensor(verts, dtype=torch.float64), torch.as_tensor(faces.astype(np.int64))),
            seconds, n ** 3)


def scores(shape, target) -> dict:
    """The table's quality columns for a meshed result against the prepared target (same frame)."""
    import trimesh

    from ipm.metrics import iou_3d, shape_scores

    if shape.n_faces == 0:
        return {"iou_3d": 0.0, "chamfer_l1": float("nan"), "vertex_dev_mean_%": float("nan"),
                "vertex_dev_max_%": float("nan"), "normal_deg": float("nan")}
    import igl

    Vs, Fs = shape.verts.double().numpy(), shape.faces.numpy()
    d2, _, _ = igl.point_mesh_squared_distance(np.ascontiguousarray(target.verts), Vs, Fs)
    d = np.sqrt(np.maximum(d2, 0.0))
    # normals: the target's face normal at 10,000 area-weighted surface samples against the normal of
    # the result's nearest triangle (vertex normals would be averages across sharp edges)
    tm = trimesh.Trimesh(target.verts, target.faces, process=False)
    pts, tface = trimesh.sample.sample_surface(tm, 10_000, seed=0)
    _, face, _ = igl.point_mesh_squared_distance(np.ascontiguousarray(pts), Vs, Fs)
    fn = trimesh.Trimesh(Vs, Fs, process=False).face_normals[face]
    angle = np.degrees(np.arccos(np.clip((tm.face_normals[tface] * fn).sum(1), -1.0, 1.0)))
    s = shape_scores(shape, target.mesh(), normalize=False)
    return {"iou_3d": iou_3d(shape, target.mesh(), normalize=False), "chamfer_l1": s.chamfer_l1,
            "vertex_dev_mean_%": 100 * float(d.mean()) / target.diagonal,
            "vertex_dev_max_%": 100 * float(d.max()) / target.diagonal, "normal_deg": float(angle.mean())}


def run(out_dir: Path, quick: bool = False) -> list[dict]:
    from ipm.convert import get_converter
    from ipm.convert.common import prepare
    from ipm.io.meshes import load_mesh

    torch.set_num_threads(1)
    perturb = dict(PERTURB, max_functions=40, time_limit=30.0) if quick else PERTURB
    bsp = dict(BSP, steps=60) if quick else BSP
    rows = []
    for name, rel, up in MESHES[:2] if quick else MESHES:
        mesh = load_mesh(DATA / rel, up=up)
        target = prepare(mesh)
        label = f"{name}, {mesh.n_faces:,} triangles"
        for method, options in (("perturb", perturb), ("bsp", bsp)):
            t0 = time.perf_counter()
            res = get_converter(method)(mesh, seed=0, **options)
            seconds = time.perf_counter() - t0
            shape = res.generator.to_mesh(res.values, resolution=128)
            size = (f"{res.stats['functions']} functions" if method == "perturb"
                    else f"{res.stats['convexes']} convexes, {res.stats['planes']} planes")
            params = int(res.stats["parameters"])
            rows.append({"target": label, "method": method, "size": size, "parameters": params,
                         "seconds": seconds, **scores(shape, target)})
            grid, g_seconds, nodes = dense_grid(target, params)
            n = round(nodes ** (1 / 3))
            rows.append({"target": label, "method": f"SDF grid (as {method})", "size": f"{n}³ nodes",
                         "parameters": nodes, "seconds": g_seconds, **scores(grid, target)})
            print(f"{label}: {method} {size} in {seconds:.1f} s; IoU {rows[-2]['iou_3d']:.3f} vs grid "
                  f"{rows[-1]['iou_3d']:.3f}", file=sys.stderr, flush=True)
    write(out_dir, rows, perturb, bsp, quick)
    return rows


def write(out_dir: Path, rows: list[dict], perturb: dict, bsp: dict, quick: bool) -> None:
    import ipm
    from ipm.files import write_text

    cols = ["target", "method", "size", "parameters", "seconds", "iou_3d", "chamfer_l1", "vertex_dev_mean_%",
            "vertex_dev_max_%", "normal_deg"]

    def fmt(v):
        return f"{v:.4g}" if isinstance(v, float) else str(v)

    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    lines += ["| " + " | ".join(fmt(r[c]) for c in cols) + " |" for r in rows]
    csv = "\n".join([",".join(cols)] + [",".join(fmt(r[c]).replace(",", ";") for c in cols) for r in rows])
    doc = "\n".join([
        "# Mesh conversion table (issue #7)", "",
        f"Command: `make table-convert` (`python -m benchmarks.table_convert {out_dir}"
        f"{' --quick' if quick else ''}`)  ",
        f"Date: {dt.datetime.now(dt.UTC).isoformat(timespec='seconds')}  ",
        f"Machine: {platform.machine()}, {__import__('os').cpu_count()} cores, one torch thread  ",
        f"Versions: ipm {ipm.__version__}, torch {torch.__version__}, Python {platform.python_version()}", "",
        f"Settings: perturb {perturb}; bsp {bsp}. Each SDF grid has the largest n³ not above the parameter "
        "count of the representation beside it, over the bounding box plus one cell, exact signed distances "
        "(libigl distance, winding-number sign), marching cubes at level 0.", "",
        (__doc__ or "").split("\n\n")[1], "",
        *lines, ""])
    write_text(out_dir / "README.md", doc)
    write_text(out_dir / "table.csv", csv + "\n")


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    run(Path(args[0] if args else "results/table_convert"), quick="--quick" in sys.argv)
