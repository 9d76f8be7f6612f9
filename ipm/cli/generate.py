"""``ipm generate GEN ... -o OUT.{obj,ply,stl,glb,usda,usdc}``, or ``-o OUT.{scad,py}`` for SDF trees: an
OpenSCAD or CadQuery program (:mod:`ipm.io.programs`). GEN may be a finished run folder of ``ipm fit``.

The mesh or program, its ``.params.json`` sidecar and the ``--preview`` are written all or none
(:func:`ipm.files.all_or_nothing`): an existing output is replaced only when every one of them is written, and
two outputs that are the same file are refused before any work."""

from __future__ import annotations

import logging
from functools import partial
from pathlib import Path
from typing import Annotated

import typer

from ipm.cli.common import (
    JsonOpt,
    LibraryOpt,
    ParamsOpt,
    PresetOpt,
    RandomOpt,
    SeedOpt,
    SetOpt,
    UsageError,
    check_output,
    command_line,
    emit,
    open_generator,
    resolve_params,
)
from ipm.cli.render import MAX_RESOLUTION, MIN_RESOLUTION, check_resolution_option

MESH_SUFFIXES = (".obj", ".ply", ".stl", ".glb", ".usda", ".usdc")
PROGRAM_SUFFIXES = (".scad", ".py")  # the formats of ipm.io.programs.PROGRAMS
log = logging.getLogger("ipm")
MIN_SEGMENTS, MAX_SEGMENTS = 3, 1024  # ipm.sdf.exact's (not imported here: it needs torch; ipm --help stays fast)


def _grid_mesh(g, values, *, resolution: int, lod, segments: int):
    """The generator's own mesh (SDF generators: marching cubes at ``resolution``)."""
    return g.to_mesh(values, resolution=resolution, lod=lod)


def _exact_mesh(g, values, *, resolution: int, lod, segments: int):
    """The exact CSG mesh of an SDF tree; one warning naming the nodes meshed by marching cubes instead."""
    exact = g.exact_mesh(values, segments=segments, resolution=resolution)
    if exact.grid_only:
        log.warning("exact mesh: manifold3d refused the marching-cubes mesh of %s; the whole tree is meshed by "
                    "marching cubes (resolution %d)", ", ".join(exact.fallback), resolution)
    elif exact.fallback:
        log.warning("exact mesh: no exact form for %s; meshed by marching cubes (resolution %d)",
                    ", ".join(exact.fallback), resolution)
    return exact.mesh


MESHERS = {"grid": _grid_mesh, "exact": _exact_mesh}


def register(app: typer.Typer) -> None:
    @app.command()
    def generate(
        gen: Annotated[str, typer.Argument(help="generator name (dishes, building, meshtree, sdftree), "
                                                "tree preset, tree file (.json), or the run folder of "
                                                "ipm fit")],
        output: Annotated[Path, typer.Option("-o", "--output", help="mesh file: .obj, .ply, .stl, .glb, .usda or "
                                             ".usdc; for SDF trees also a program: .scad (OpenSCAD), .py "
                                             "(CadQuery)")],
        preset: PresetOpt = None,
        params: ParamsOpt = None,
        set_: SetOpt = None,
        random: RandomOpt = False,
        seed: SeedOpt = 0,
        resolution: Annotated[int, typer.Option(help=(
            f"marching-cubes samples along the longest side, {MIN_RESOLUTION} to {MAX_RESOLUTION} (generators "
            "meshed from a field: SDF trees, bsp and perturb files; mesh generators such as dishes and building "
            "take --lod instead and accept any value in range)"))] = 128,
        lod: Annotated[str | None, typer.Option(help="level of detail of mesh generators (e.g. low, "
                                                     "medium, high)")] = None,
        mesher: Annotated[str, typer.Option(help="how an SDF tree becomes a mesh: grid (marching cubes at "
                                                 "--resolution) or exact (manifold3d CSG with sharp edges; nodes "
                                                 "without an exact form use the grid, with a warning)")] = "grid",
        segments: Annotated[int, typer.Option(help="--mesher exact and OpenSCAD programs ($fn): straight pieces "
                                                   "per full circle of curved primitives, "
                                                   f"{MIN_SEGMENTS} to {MAX_SEGMENTS}")] = 64,
        preview: Annotated[Path | None, typer.Option(help="also write a shaded preview PNG")] = None,
        library: LibraryOpt = None,
        json_out: JsonOpt = False,
    ) -> None:
        """Generate a mesh (or an SDF tree's program) from a generator and parameters; write it with a
        .params.json sidecar."""
        from ipm.files import check_distinct
        from ipm.io.export import export_mesh, sidecar_path

        check_output(output, MESH_SUFFIXES + PROGRAM_SUFFIXES)
        if preview is not None:
            check_output(preview, (".png",))
        check_distinct({"-o/--output": output, f"the parameter file beside -o ({sidecar_path(output).name})":
                        sidecar_path(output), "--preview": preview})
        check_resolution_option(resolution, upper=False)
        if mesher not in MESHERS:
            raise UsageError(f"--mesher: expected one of {', '.join(MESHERS)}, got {mesher!r}")
        if not MIN_SEGMENTS <= segments <= MAX_SEGMENTS:
            raise UsageError(f"--segments: expected {MIN_SEGMENTS} to {MAX_SEGMENTS} pieces per circle, got {segments}")
        g, fitted = open_generator(gen, library)
        values = resolve_params(g, preset, params, set_, random, seed, fitted)
        g.check_meshing(values, resolution)
        check_resolution_option(resolution)
        if output.suffix.lower() in PROGRAM_SUFFIXES:
            mesh_for_preview = partial(MESHERS[mesher], g, values, resolution=resolution, lod=lod, segments=segments)
            return _write_program(g, values, output, preview, mesh_for_preview, segments, json_out)
        mesh = MESHERS[mesher](g, values, resolution=resolution, lod=lod, segments=segments)
        if mesh.n_faces == 0:
            raise UsageError(f"{gen}: these parameters give an empty shape (no surface inside the bounds)")
        from ipm.files import all_or_nothing

        result = {"mesh": str(output), "params": str(sidecar_path(output)), "vertices": mesh.n_verts,
                  "faces": mesh.n_faces}
        with all_or_nothing(output, sidecar_path(output), *([preview] if preview else [])):
            export_mesh(mesh, output, g.metadata(values))
            if preview is not None:
                from ipm.render.preview import write_preview

                write_preview(mesh, preview)
                result["preview"] = str(preview)
        emit(result, json_out)


def _write_program(g, values: dict, output: Path, preview: Path | None, mesh_for_preview, segments: int,
                   json_out: bool) -> None:
    """The SDF tree's program (and its sidecar, and the ``preview`` of ``mesh_for_preview()``), all or none."""
    from ipm.files import all_or_nothing
    from ipm.io.export import sidecar_path
    from ipm.io.programs import export_program

    tree = g.sdf_tree(values)  # generators that are not SDF trees refuse here
    result = {"program": str(output), "params": str(sidecar_path(output))}
    with all_or_nothing(output, sidecar_path(output), *([preview] if preview else [])):
        export_program(tree, output, g.metadata(values), segments=segments, command=command_line())
        if preview is not None:
            from ipm.render.preview import write_preview

            write_preview(mesh_for_preview(), preview)
            result["preview"] = str(preview)
    emit(result, json_out)
