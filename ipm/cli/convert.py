"""``ipm convert MESH --to bsp|perturb|sdftree ... -o OUT.json``: a mesh into a universal representation.

The result file loads back with ``ipm generate OUT.json`` (and ``get_generator``). The mesh is
normalized first (DESIGN.md: up axis, bounding-box center at the origin, farthest vertex at 1); the file's
``frame`` says how to undo it.

The result, the ``--mesh`` and its ``.params.json`` sidecar are written all or none
(:func:`ipm.files.all_or_nothing`); two of them that are the same file are refused before any work.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path
from typing import Annotated

import typer

from ipm.cli.common import JsonOpt, SeedOpt, UsageError, check_output, emit

MESH_SUFFIXES = (".obj", ".ply", ".stl", ".glb")

# option -> the targets it applies to (an option given for another target is a usage error)
ONLY_FOR = {
    "--max-functions": ("perturb",), "--tolerance": ("perturb",), "--normal-tolerance": ("perturb",),
    "--time-limit": ("perturb",), "--planes": ("bsp", "sdftree"), "--convexes": ("bsp", "sdftree"),
    "--steps": ("bsp", "sdftree"),
}


def _check_options(to: str, given: dict) -> dict:
    """Validate the target-specific options; returns the converter's keyword arguments."""
    from ipm.convert import CONVERTERS

    if to not in CONVERTERS:
        raise UsageError(f"--to: expected one of {', '.join(CONVERTERS)}, got {to!r}")
    for opt, value in given.items():
        if value is not None and to not in ONLY_FOR[opt]:
            raise UsageError(f"{opt} applies to --to {' or '.join(ONLY_FOR[opt])}, not {to}")
    kw: dict = {}
    if given["--max-functions"] is not None:
        if given["--max-functions"] < 1:
            raise UsageError(f"--max-functions: expected at least 1, got {given['--max-functions']}")
        kw["max_functions"] = given["--max-functions"]
    for opt, key in (("--tolerance", "tolerance"), ("--normal-tolerance", "normal_tolerance"),
                     ("--time-limit", "time_limit")):
        v = given[opt]
        if v is not None:
            if not (math.isfinite(v) and v > 0):
                raise UsageError(f"{opt}: expected a positive number, got {v:g}")
            kw[key] = v
    for opt, key in (("--planes", "planes"), ("--convexes", "convexes"), ("--steps", "steps")):
        v = given[opt]
        if v is not None:
            if v < 1:
                raise UsageError(f"{opt}: expected at least 1, got {v}")
            kw[key] = v
    return kw


MeshArg = Annotated[Path, typer.Argument(help="mesh file (.ply, .obj, .stl, .glb, .off)")]
ToOpt = Annotated[str, typer.Option("--to", help="bsp (convex polytopes), perturb (quadric + perturbation "
                                                 "functions) or sdftree (the BSP as an SDF node tree)")]
OutputOpt = Annotated[Path, typer.Option("-o", "--output", help="result file (.json); loads back with ipm "
                                                                 "generate. With --mesh, both are written or neither")]
UpOpt = Annotated[str, typer.Option(help="up axis of the mesh file: y or z")]
MaxFunctionsOpt = Annotated[int | None, typer.Option("--max-functions", help="perturb: at most this many "
                                                     "perturbation functions [2000]")]
ToleranceOpt = Annotated[float | None, typer.Option(help="perturb: stop at this mean vertex deviation, as a "
                                                   "share of the bounding-box diagonal [0.01]")]
NormalToleranceOpt = Annotated[float | None, typer.Option("--normal-tolerance", help="perturb: and at this mean "
                                                          "normal deviation in degrees [20]")]
TimeLimitOpt = Annotated[float | None, typer.Option("--time-limit", help="perturb: stop after this many seconds")]
PlanesOpt = Annotated[int | None, typer.Option(help="bsp, sdftree: planes [16]")]
ConvexesOpt = Annotated[int | None, typer.Option(help="bsp, sdftree: convexes [4]")]
StepsOpt = Annotated[int | None, typer.Option(help="bsp, sdftree: Adam steps per stage [300]")]
MeshOutOpt = Annotated[Path | None, typer.Option("--mesh", help="also write the converted shape as a mesh "
                                                 "(.obj, .ply, .stl or .glb)")]
ResolutionOpt = Annotated[int, typer.Option(help="marching-cubes resolution of --mesh (perturb); its float32 "
                                                 "grid must fit in 2 GiB (at most 808)")]


def register(app: typer.Typer) -> None:
    @app.command()
    def convert(
        mesh: MeshArg,
        to: ToOpt,
        output: OutputOpt,
        up: UpOpt = "y",
        max_functions: MaxFunctionsOpt = None,
        tolerance: ToleranceOpt = None,
        normal_tolerance: NormalToleranceOpt = None,
        time_limit: TimeLimitOpt = None,
        planes: PlanesOpt = None,
        convexes: ConvexesOpt = None,
        steps: StepsOpt = None,
        mesh_out: MeshOutOpt = None,
        resolution: ResolutionOpt = 128,
        seed: SeedOpt = 0,
        json_out: JsonOpt = False,
    ) -> None:
        """Convert a mesh to a universal representation (BSP convexes, perturbation functions, SDF tree)."""
        kw = _check_options(to, {"--max-functions": max_functions, "--tolerance": tolerance,
                                 "--normal-tolerance": normal_tolerance, "--time-limit": time_limit,
                                 "--planes": planes, "--convexes": convexes, "--steps": steps})
        check_output(output, (".json",))
        if mesh_out is not None:
            check_output(mesh_out, MESH_SUFFIXES)
        from ipm.files import check_distinct
        from ipm.io.export import sidecar_path

        sidecar = sidecar_path(mesh_out) if mesh_out is not None else None
        check_distinct({"-o/--output": output, "--mesh": mesh_out,
                        f"the parameter file beside --mesh ({sidecar.name if sidecar else ''})": sidecar})
        if up not in ("y", "z"):
            raise UsageError(f"--up: expected y or z, got {up!r}")
        if not mesh.is_file():
            raise UsageError(f"mesh file not found: {mesh}")
        from ipm.convert import check_mesh_resolution

        check_mesh_resolution(resolution)  # up front: a grid too large for memory fails before any work

        result = _convert(mesh, to, up, output, mesh_out, sidecar, resolution, seed, kw)
        out = {"output": str(output), "to": to, **{k: v for k, v in result.stats.items()
                                                      if isinstance(v, (int, float, str, bool))}}
        if mesh_out is not None:
            out["mesh"] = str(mesh_out)
        emit(out, json_out)
        sys.stdout.flush()


def _convert(mesh: Path, to: str, up: str, output: Path, mesh_out: Path | None, sidecar: Path | None,
             resolution: int, seed: int, kw: dict):
    """Run converter ``to`` on the normalized mesh with a progress bar; write its file (and ``--mesh`` with its
    sidecar) all or none. Returns the converter's result."""
    from rich.console import Console
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from ipm.convert import get_converter
    from ipm.files import all_or_nothing, write_text
    from ipm.io.meshes import load_mesh

    target = load_mesh(mesh, up=up, normalize=True)
    fn = get_converter(to)
    bar = Progress(TextColumn(f"{to:<8}"), BarColumn(), TextColumn("{task.completed}/{task.total}"),
                   TextColumn("{task.fields[info]}"), TimeElapsedColumn(), transient=True,
                   console=Console(stderr=True))
    task = bar.add_task(to, total=1, info="")

    def progress(done: int, total: int, info: dict) -> None:
        text = "  ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in info.items())
        bar.update(task, completed=done, total=total, info=text)

    with bar:
        result = fn(target, progress=progress, seed=seed, **kw)
    data = {**result.data, "source": {"mesh": str(mesh), "up": up}}
    with all_or_nothing(output, mesh_out, sidecar):
        if mesh_out is not None:
            from ipm.io.export import export_mesh

            shape = result.generator.to_mesh(result.values, resolution=resolution)
            if shape.n_faces == 0:
                raise UsageError(f"{to}: the converted shape is empty; nothing to write to {mesh_out}")
            export_mesh(shape, mesh_out, result.generator.metadata(result.values))
        write_text(output, json.dumps(data, indent=1) + "\n")
    return result
