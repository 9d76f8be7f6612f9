"""``ipm generate GEN ... -o OUT.{obj,ply,stl,glb,usda,usdc}``, or ``-o OUT.{scad,py}`` for SDF trees: an
OpenSCAD or CadQuery program (:mod:`ipm.io.programs`). GEN may be a finished run folder of ``ipm fit``.

The mesh or program, its ``.params.json`` sidecar and the ``--preview`` are written all or none
(:func:`ipm.files.all_or_nothing`): an existing output is replaced only when every one of them is written, and
two outputs that are the same file are refused before any work."""

from __future__ import annotations

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
        g, fitted = open_generator(gen, library)
        values = resolve_params(g, preset, params, set_, random, seed, fitted)
        if output.suffix.lower() in PROGRAM_SUFFIXES:
            return _write_program(g, values, output, preview, resolution, json_out)
        g.check_meshing(values, resolution)
        check_resolution_option(resolution)
        mesh = g.to_mesh(values, resolution=resolution, lod=lod)
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


def _write_program(g, values: dict, output: Path, preview: Path | None, resolution: int, json_out: bool) -> None:
    """The SDF tree's program (and its sidecar, and the preview of its mesh), all or none."""
    from ipm.files import all_or_nothing
    from ipm.io.export import sidecar_path
    from ipm.io.programs import export_program

    tree = g.sdf_tree(values)  # generators that are not SDF trees refuse here
    result = {"program": str(output), "params": str(sidecar_path(output))}
    with all_or_nothing(output, sidecar_path(output), *([preview] if preview else [])):
        export_program(tree, output, g.metadata(values), command=command_line())
        if preview is not None:
            from ipm.render.preview import write_preview

            g.check_meshing(values, resolution)
            write_preview(g.to_mesh(values, resolution=resolution), preview)
            result["preview"] = str(preview)
    emit(result, json_out)
