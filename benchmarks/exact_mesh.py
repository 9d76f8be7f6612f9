"""Exact CSG meshes against marching cubes (issue #31, ``make exact-mesh``): do the truth's sharp edges survive?

Targets: the ``csg`` preset and the ten random 3-part trees of the structure table ("random 3 parts #0-9",
drawn by :func:`benchmarks.table_structure.make_random`: boxes, cylinders and spheres joined by union and cut by
subtraction). Each is meshed by ``ipm.sdf.exact`` at 64 segments per circle and by marching cubes at
resolution 128 (``ipm generate``'s two meshers).

The edge measure: the truth's sharp edges are those of a fine reference, the exact mesh at 256 segments, whose
faces meet at more than :data:`SHARP` degrees. Points are sampled along each of them (at most :data:`STEP`
apart), and a point counts as present when the mesh under test has an edge near it whose dihedral angle matches
the reference's there within :data:`ANGLE_TOL` degrees. Near: within :data:`TOL` plus the mesh's own distance
from the surface (``eps``, the largest ``|sdf|`` at its face centers: a 64-gon's sag is 0.0012 r, a 64-segment
geodesic sphere's 0.0032 r) divided by ``cos(angle / 2)``, because where two faceted surfaces meet at a shallow
angle their crossing moves by that much more (at most 10 ``eps``). Marching cubes cuts each sharp edge into a
chamfer about one cell wide (0.01 here), so its edges are neither where nor as sharp as the truth's and the
measure fails for it, as it should.

Usage: ``python -m benchmarks.exact_mesh OUT_DIR``.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np
import torch

from benchmarks.common import commit, machine, timings

SEGMENTS = 64        # the exact mesher's pieces per circle (ipm generate's default)
REFERENCE = 256      # the reference's
RESOLUTION = 128     # marching cubes' samples along the longest side (ipm generate's default)
SHARP = 30.0         # degrees between face normals: a sharp edge of the reference
ANGLE_TOL = 10.0     # degrees: a reference edge's dihedral angle kept by the mesh under test
TOL = 1e-3           # distance from a reference edge point to the mesh's matching edge, beyond the mesh's own error
STEP = 0.01          # the largest spacing of the points sampled along a reference edge
SEEDS = range(10)    # random 3 parts #0 .. #9


def targets() -> list[tuple[str, object]]:
    """``(name, SdfTreeGenerator)`` of every target."""
    from benchmarks.table_structure import make_random
    from ipm.generators import get_generator
    from ipm.generators.sdftree import SdfTreeGenerator
    from ipm.sdf.tree import tree_from_json

    out = [("csg preset", get_generator("csg"))]
    for seed in SEEDS:
        out.append((f"random 3 parts #{seed}", SdfTreeGenerator(tree_from_json({"tree": make_random(3, seed)}))))
    return out


def sharp_edges(mesh, min_angle: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The edges whose two faces meet at more than ``min_angle`` degrees: ``(a (E, 3), b (E, 3), angle (E,))``."""
    tm = mesh.to_trimesh()
    angle = np.degrees(tm.face_adjacency_angles)
    keep = angle > min_angle
    edges = tm.face_adjacency_edges[keep]
    return tm.vertices[edges[:, 0]], tm.vertices[edges[:, 1]], angle[keep]


def edge_samples(a: np.ndarray, b: np.ndarray, angle: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points ``(P, 3)`` along edges ``a -> b``, at most :data:`STEP` apart, with their edge's angle ``(P,)``."""
    pts, ang = [], []
    for p, q, w in zip(a, b, angle):
        m = max(1, math.ceil(np.linalg.norm(q - p) / STEP))
        t = (np.arange(m) + 0.5) / m
        pts.append(p + t[:, None] * (q - p))
        ang.append(np.full(m, w))
    return np.concatenate(pts), np.concatenate(ang)


def surface_error(tree, mesh) -> float:
    """``eps``: the largest ``|sdf|`` of ``tree`` at the face centers of ``mesh`` (its distance from the surface)."""
    centers = mesh.verts[mesh.faces].mean(1)
    return float(tree.sdf(None, centers).abs().max()) if mesh.n_faces else 0.0


def present(mesh, pts: np.ndarray, ref_angle: np.ndarray, eps: float) -> np.ndarray:
    """Per reference point ``(P,)``: does ``mesh`` have an edge near it (the module docstring) whose dihedral angle
    is within :data:`ANGLE_TOL` of the reference's?"""
    a, b, angle = sharp_edges(mesh, SHARP - ANGLE_TOL)
    found = np.zeros(len(pts), dtype=bool)
    if len(a) == 0:
        return found
    tol = TOL + eps / np.maximum(np.cos(np.radians(ref_angle) / 2), 0.1)
    ab = b - a
    ab2 = np.maximum(np.einsum("ei,ei->e", ab, ab), 1e-30)
    for i in range(0, len(pts), 32):
        p = pts[i:i + 32, None, :]
        s = np.clip(np.einsum("pei,ei->pe", p - a[None], ab) / ab2, 0.0, 1.0)
        dist = np.linalg.norm(p - (a[None] + s[..., None] * ab[None]), axis=-1)
        ok = (dist < tol[i:i + 32, None]) & (np.abs(angle[None] - ref_angle[i:i + 32, None]) < ANGLE_TOL)
        found[i:i + 32] = ok.any(1)
    return found


def mesh_row(name: str, mesher: str, make, tree, pts: np.ndarray, ref_angle: np.ndarray) -> dict:
    """One row: a mesher's median seconds of 3, its size, closedness and the edge measure."""
    median, _ = timings(make, repeat=3, warmup=0)
    mesh = make()
    tm = mesh.to_trimesh()
    eps = surface_error(tree, mesh)
    hit = present(mesh, pts, ref_angle, eps)
    return {"target": name, "mesher": mesher, "seconds": median, "vertices": mesh.n_verts, "faces": mesh.n_faces,
            "watertight": bool(tm.is_watertight and tm.is_winding_consistent and tm.volume > 0),
            "surface_error": eps, "edge_points": len(pts), "edge_points_present": int(hit.sum()),
            "every_edge": bool(hit.all())}


def run(out_dir: Path) -> list[dict]:
    """Every target under both meshers; writes ``rows.json`` and ``README.md`` into ``out_dir``."""
    torch.set_num_threads(1)
    rows = []
    for name, gen in targets():
        values = gen.values()
        ref = gen.exact_mesh(values, segments=REFERENCE).mesh
        pts, ref_angle = edge_samples(*sharp_edges(ref, SHARP))
        rows.append(mesh_row(name, f"exact, {SEGMENTS} segments", lambda: gen.exact_mesh(
            values, segments=SEGMENTS).mesh, gen.tree, pts, ref_angle))
        rows.append(mesh_row(name, f"marching cubes, {RESOLUTION}", lambda: gen.to_mesh(
            values, resolution=RESOLUTION), gen.tree, pts, ref_angle))
        print(f"{name}: " + "; ".join(f"{r['mesher']} {r['seconds']:.3f} s, edges {r['edge_points_present']}/"
                                      f"{r['edge_points']}" for r in rows[-2:]), file=sys.stderr, flush=True)
    write(out_dir, rows)
    return rows


def write(out_dir: Path, rows: list[dict]) -> None:
    """``rows.json`` and the README's table."""
    from ipm.files import write_text

    out_dir.mkdir(parents=True, exist_ok=True)
    write_text(out_dir / "rows.json", json.dumps(rows, indent=1) + "\n")
    yes = {True: "yes", False: "no"}
    lines = [
        "# Exact CSG meshes against marching cubes (issue #31: `make exact-mesh`)", "",
        f"Command: `python -m benchmarks.exact_mesh {out_dir}`  ",
        f"Commit: {commit()}  ",
        f"Machine: {machine()}", "",
        f"- Targets: the `csg` preset and the structure table's random 3-part trees #{SEEDS[0]}-{SEEDS[-1]} "
        "(`benchmarks.table_structure.make_random`).",
        f"- exact: `ipm generate TREE --mesher exact` ({SEGMENTS} segments per circle); marching cubes: `ipm generate "
        f"TREE` (resolution {RESOLUTION}). Seconds: the median of 3 runs, one torch thread.",
        "- watertight: closed, consistently wound, positive volume (trimesh).",
        f"- edges present: points every {STEP} or less along the sharp edges (faces meeting at more than {SHARP:g}°) "
        f"of a reference, the exact mesh at {REFERENCE} segments; a point is present when the mesh has an edge "
        f"within {TOL} + eps / cos(angle / 2) whose dihedral angle is the reference's within {ANGLE_TOL:g}°; eps: the "
        "mesh's largest |sdf| at its face centers (its own distance from the surface; see the module docstring). "
        "Every edge: all of them.", "",
        "| target | mesher | s | vertices | faces | watertight | eps | edge points present | every edge |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(f"| {r['target']} | {r['mesher']} | {r['seconds']:.3f} | {r['vertices']} | {r['faces']} | "
                     f"{yes[r['watertight']]} | {r['surface_error']:.1e} | "
                     f"{r['edge_points_present']}/{r['edge_points']} | {yes[r['every_edge']]} |")
    exact = [r for r in rows if r["mesher"].startswith("exact")]
    lines += ["", f"Exact: {sum(r['watertight'] for r in exact)}/{len(exact)} watertight, "
              f"{sum(r['every_edge'] for r in exact)}/{len(exact)} with every edge, slowest "
              f"{max(r['seconds'] for r in exact):.3f} s."]
    write_text(out_dir / "README.md", "\n".join(lines) + "\n")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: python -m benchmarks.exact_mesh OUT_DIR")
    run(Path(sys.argv[1]))
