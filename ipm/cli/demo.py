"""``make demo``: the main job on built-in data, end to end, printing where the results are.

Today it shows the universal generator: meshes of the shipped trees, their Jacobians checked against
float64 finite differences, and (when the renderer is installed) shaded previews.
Run: ``python -m ipm.cli.demo [OUT_DIR]`` (what ``make demo`` does).
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import torch


def run(out: Path) -> dict:
    from ipm.generators import get_generator
    from ipm.io.atomic import write_text
    from ipm.io.export import export_mesh
    from ipm.jacobian import check_sdf_jacobian, sdf_jacobian

    out.mkdir(parents=True, exist_ok=True)
    summary: dict = {"meshes": {}, "jacobians": {}}
    for name in ("csg", "chair", "mug", "vase", "wind_rose", "shelf"):
        g = get_generator(name)
        values = g.values()
        t0 = time.perf_counter()
        mesh = g.to_mesh(values, resolution=160)
        dt = time.perf_counter() - t0
        path = export_mesh(mesh, out / f"{name}.glb", g.metadata(values))
        tm = mesh.to_trimesh()
        summary["meshes"][name] = {"file": str(path), "faces": mesh.n_faces, "watertight": bool(tm.is_watertight),
                                   "volume": round(float(tm.volume), 5), "seconds": round(dt, 3)}
        try:
            from ipm.render.preview import write_preview
        except ImportError:
            write_preview = None
        if write_preview is not None:
            write_preview(mesh, out / f"{name}.png")
            summary["meshes"][name]["preview"] = str(out / f"{name}.png")
        tree = g.tree
        lo, hi = tree.bounds()
        pts = torch.rand(2000, 3, dtype=torch.float64) * torch.as_tensor(hi - lo + 0.2) + torch.as_tensor(lo - 0.1)
        t0 = time.perf_counter()
        J = sdf_jacobian(tree.sdf, tree.theta(), pts)
        dt = time.perf_counter() - t0
        chk = check_sdf_jacobian(tree.sdf, tree.theta(), pts, J=J)
        summary["jacobians"][name] = {"shape": list(J.shape), "seconds": round(dt, 4),
                                      "max_rel_error_vs_fd": chk.max_rel_error}
    write_text(out / "summary.json", json.dumps(summary, indent=2) + "\n")
    return summary


def main() -> None:
    out = Path(sys.argv[1] if len(sys.argv) > 1 else "results/demo")
    torch.manual_seed(0)
    summary = run(out)
    for name, m in summary["meshes"].items():
        j = summary["jacobians"][name]
        print(f"{name:10s} {m['faces']:7d} faces  watertight={m['watertight']}  "
              f"Jacobian {j['shape']} in {j['seconds']} s, max rel. error vs FD {j['max_rel_error_vs_fd']:.1e}")
    print(f"\nResults: {out.resolve()}  (meshes *.glb with .params.json, summary.json)")


if __name__ == "__main__":
    main()
