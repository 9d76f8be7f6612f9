"""``ipm subdivide MESH --method loop|midpoint --levels L -o OUT``: a mesh file subdivided.

The file's vertices are welded first where they coincide exactly (STL stores every triangle on its own;
without the weld each triangle would be subdivided alone), and triangles that repeat a vertex after the
weld (zero area; scans have them) are dropped; the output reports both counts. Coordinates are kept as
they are in the file (no up-axis change, no normalization)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated

import typer

from ipm.cli.common import JsonOpt, UsageError, check_output, emit, resolve_subdivision

MESH_SUFFIXES = (".obj", ".ply", ".stl", ".glb")


def register(app: typer.Typer) -> None:
    @app.command()
    def subdivide(
        mesh: Annotated[Path, typer.Argument(help="mesh file (.ply, .obj, .stl, .glb, .off)")],
        output: Annotated[Path, typer.Option("-o", "--output", help="subdivided mesh (.obj, .ply, .stl or .glb)")],
        method: Annotated[str, typer.Option(help="loop (smooth, Loop 1987), midpoint (edges split at their "
                                                 "midpoints; the surface does not move) or neural (half-flap "
                                                 "MLPs, Liu et al. 2020; closed meshes)")] = "loop",
        levels: Annotated[int, typer.Option(help="how many times, 1 to 6 (each multiplies the triangles "
                                                 "by 4)")] = 1,
        weights: Annotated[Path | None, typer.Option(help="neural: a weights file (.npz, from ipm "
                                                          "train-subdivision); default: the shipped one")] = None,
        json_out: JsonOpt = False,
    ) -> None:
        """Subdivide a triangle mesh (Loop, midpoint or neural), differentiable in ipm.subdiv."""
        import torch

        from ipm.errors import InputError
        from ipm.io.export import export_mesh
        from ipm.io.meshes import load_mesh
        from ipm.subdiv import clean
        from ipm.types import TriMesh

        check_output(output, MESH_SUFFIXES)
        scheme = resolve_subdivision("--method", method, levels)
        if weights is not None:
            if method != "neural":
                raise UsageError(f"--weights applies to --method neural, not {method}")
            scheme = scheme.with_weights(weights)
        if method == "neural":
            scheme.network()  # a bad weights file is refused before the mesh is read
        src = load_mesh(mesh, up="y", normalize=False)
        # welded, zero-area triangles and the vertices left on no face dropped
        welded, F = clean(src.verts.numpy(), src.faces.numpy())
        if len(F) == 0:
            raise UsageError(f"mesh file {mesh}: every triangle repeats a vertex; nothing to subdivide")
        t0 = time.perf_counter()
        try:
            with torch.no_grad():
                nv, nf = scheme.subdivide(torch.as_tensor(welded), F, levels)
        except InputError as e:
            raise UsageError(f"{mesh}: {e}") from None
        seconds = time.perf_counter() - t0
        export_mesh(TriMesh(nv.detach(), torch.as_tensor(nf)), output, sidecar=False)
        emit({"output": str(output), "method": method, "levels": levels,
              "input": {"vertices": int(src.n_verts), "welded": int(len(welded)), "faces": int(len(F)),
                        "dropped_degenerate": int(src.n_faces - len(F))},
              "vertices": int(nv.shape[0]), "faces": int(len(nf)), "seconds": round(seconds, 3)}, json_out)
