"""``ipm render MESH|GEN ... -o DIR``: exact masks, cameras.json and shaded previews (a target maker).

With ``--masks DIR`` it renders in the cameras of an existing mask set instead and also writes
target-vs-render overlays with their IoU.

Sizes are checked before any work, per view (``MAX_SIDE`` pixels a side) and in total (``MAX_PIXELS``
over all views: the work and the files grow with it). Views are written one by one into a staged folder
(:func:`ipm.files.staged_directory`), so memory holds one view at a time, and the folder appears, or its
render files are replaced, only when every view is written. An output folder that is not empty is refused
unless ``--overwrite`` is given; then every render file in it (``view_*``, ``preview_*``, ``overlay_*``,
``depth_*``, ``normal_*``, ``part_*``, ``cameras.json``, ``parts.json``) is replaced as a whole, so that
no file of an earlier render survives to be read with the new one; other files are kept.
"""

from __future__ import annotations

import re
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
    emit,
    resolve_params,
)

NEAR = 1e-3
# --resolution (marching cubes) of generate and render; each grid is also checked against memory
MIN_RESOLUTION, MAX_RESOLUTION = 8, 2048


def check_resolution_option(resolution: int, *, upper: bool = True) -> int:
    """``--resolution`` in range, for every source (mesh generators and mesh files ignore it, but a value
    no generator could use is refused alike). Commands check the lower bound before any work and the upper
    one after an SDF generator's own memory check, whose message names the largest resolution that fits."""
    if resolution < MIN_RESOLUTION or (upper and resolution > MAX_RESOLUTION):
        raise UsageError(f"--resolution: expected {MIN_RESOLUTION}..{MAX_RESOLUTION} samples, got {resolution}")
    return resolution


def _source_mesh(source: str, up: str, normalize: bool, resolution: int, library, param_opts: dict):
    """The mesh to render: a mesh file, or a generator's output."""
    from ipm.io.meshes import MESH_SUFFIXES, load_mesh, normalize_mesh, surface_area

    path = Path(source)
    if path.suffix.lower() in MESH_SUFFIXES:
        if not path.is_file():
            raise UsageError(f"mesh file not found: {path}")
        used = [k for k, v in param_opts.items() if v]
        if used:
            raise UsageError(f"{', '.join(used)} apply to generators, not to a mesh file ({path})")
        check_resolution_option(resolution)
        return load_mesh(path, up=up, normalize=normalize), {"mesh": str(path)}
    if up != "y":
        raise UsageError("--up applies to mesh files; generators are Y-up")
    from ipm.generators import get_generator

    g = get_generator(source, library=[str(p) for p in library] if library else None)
    values = resolve_params(g, param_opts["--preset"], param_opts["--params"], param_opts["--set"],
                            param_opts["--random"], param_opts["seed"])
    g.check_meshing(values, resolution)
    check_resolution_option(resolution)
    mesh = g.to_mesh(values, resolution=resolution)
    if mesh.n_faces == 0 or surface_area(mesh) <= 0:
        raise UsageError(f"{source}: these parameters give an empty shape (no surface to render)")
    if normalize:
        mesh = normalize_mesh(mesh)
    return mesh, {"generator": g.name, "params": dict(values)}


def _cameras(views: int | None, cameras: Path | None, masks: Path | None, size: int | None):
    from ipm.render.camera import input_views, load_cameras

    given = [n for n, v in (("--views", views), ("--cameras", cameras), ("--masks", masks)) if v is not None]
    if len(given) > 1:
        raise UsageError(f"give one of --views, --cameras and --masks, got {' and '.join(given)}")
    if size is not None and (cameras is not None or masks is not None):
        raise UsageError("--size applies to --views; with --cameras or --masks each view's size comes "
                         "from cameras.json")
    if cameras is not None:
        if cameras.is_dir():
            cameras = cameras / "cameras.json"
        if not cameras.is_file():
            raise UsageError(f"cameras file not found: {cameras}")
        return _check_sizes(load_cameras(cameras), str(cameras)), None
    if masks is not None:
        from ipm.io.masks import load_mask_set

        ms = load_mask_set(masks)
        return _check_sizes(list(ms.cameras), str(masks)), ms
    k = 4 if views is None else views
    if not 1 <= k <= MAX_VIEWS:
        raise UsageError(f"--views: expected a number of views in 1..{MAX_VIEWS}, got {k}")
    s = 256 if size is None else size
    if not 8 <= s <= MAX_SIDE:
        raise UsageError(f"--size: expected an image size in 8..{MAX_SIDE} pixels, got {s}")
    if k * s * s > MAX_PIXELS:
        raise UsageError(f"--views {k} --size {s}: {k} views of {s}x{s} are {k * s * s:,} pixels; expected at "
                         f"most {MAX_PIXELS:,} pixels in all (the limit; at --size {s} at most "
                         f"{max(1, MAX_PIXELS // (s * s))} views)")
    return input_views(k, s), None


# One view at most MAX_SIDE a side (about 13 GB of work memory at 8192x8192, one view at a time) and at most
# MAX_PIXELS over all views (about 1 microsecond a pixel here: 4 to 5 minutes, and about 1 GB of depth maps).
MAX_SIDE, MAX_VIEWS = 8192, 256
MAX_PIXELS = 2**28


def _check_sizes(cams: list, where: str) -> list:
    """The same limits as --views and --size, for cameras read from a file."""
    if not 1 <= len(cams) <= MAX_VIEWS:
        raise UsageError(f"{where}: expected 1..{MAX_VIEWS} cameras, got {len(cams)}")
    for i, c in enumerate(cams):
        if not (1 <= c.width <= MAX_SIDE and 1 <= c.height <= MAX_SIDE):
            raise UsageError(f"{where}: camera {i} asks for {c.width}x{c.height} pixels; each side may be at "
                             f"most {MAX_SIDE}")
    total = sum(int(c.width) * int(c.height) for c in cams)
    if total > MAX_PIXELS:
        raise UsageError(f"{where}: {len(cams)} cameras ask for {total:,} pixels; expected at most "
                         f"{MAX_PIXELS:,} pixels in all (the limit)")
    return cams


# The files a render writes: with --overwrite, every one of them in the output folder is replaced.
RENDER_FILE = re.compile(r"^(?:(?:view|preview|overlay|depth|normal|part)_\d{3,}\.(?:png|npy)|cameras\.json|"
                         r"parts\.json)$")


def is_render_file(name: str) -> bool:
    return RENDER_FILE.match(name) is not None


def _check_output_folder(output: Path, overwrite: bool, masks: Path | None) -> None:
    """Before any work: a file in the way, a folder holding anything without --overwrite, the --masks
    folder itself, a place this process may not write."""
    from ipm.files import check_writable, same_file
    from ipm.io.masks import CAMERAS_FILE

    if output.exists() and not output.is_dir():
        raise UsageError(f"output {output}: expected a folder, got a file")
    if masks is not None and output.exists() and same_file(output, masks):
        raise UsageError(f"-o/--output {output}: expected a folder other than --masks, got the same folder")
    if output.is_dir() and not overwrite and any(output.iterdir()):
        raise UsageError(f"output {output}: expected a new or empty folder, got one that holds files; give "
                         "--overwrite to replace its render files")
    check_writable(output / CAMERAS_FILE)


def _check_outside(mesh, cameras) -> None:
    """Every vertex must be in front of every camera (a camera inside the object cannot see it whole)."""
    from ipm.render.camera import project

    for i, cam in enumerate(cameras):
        _, depth = project(mesh.verts.detach(), cam.to(dtype=mesh.verts.dtype))
        dmin = float(depth.min())
        if dmin <= NEAR:
            eye = ", ".join(f"{v:.3g}" for v in cam.eye.tolist())
            raise UsageError(f"camera {i} at ({eye}) is inside the object or too close to it: part of the "
                             f"mesh is behind the camera (nearest depth {dmin:.3g}); move the camera out")


def register(app: typer.Typer) -> None:
    @app.command()
    def render(
        source: Annotated[str, typer.Argument(metavar="MESH|GEN", help="mesh file (.ply, .obj, .stl, .glb, "
                                              ".off) or a generator name, tree preset or tree file (.json)")],
        output: Annotated[Path, typer.Option("-o", "--output", help=(
            "output folder: new or empty (created), or with --overwrite one holding an earlier render"))],
        preset: PresetOpt = None,
        params: ParamsOpt = None,
        set_: SetOpt = None,
        random: RandomOpt = False,
        seed: SeedOpt = 0,
        up: Annotated[str, typer.Option(help="up axis of a mesh file: y or z (converted to Y up)")] = "y",
        normalize: Annotated[bool, typer.Option("--normalize/--no-normalize",
                                                help="bounding-box center to the origin, farthest vertex at "
                                                     "distance 1 (the evaluation protocol's unit bounding "
                                                     "sphere)")] = True,
        views: Annotated[int | None, typer.Option(
            help=f"K protocol input views, 1 to {MAX_VIEWS}: FOV 40, distance 3.2, elevation 25, azimuths "
                 f"30 + k 360/K; views x size^2 at most {MAX_PIXELS:,} pixels [default: 4]")] = None,
        cameras: Annotated[Path | None, typer.Option(help="cameras.json (or a folder holding one) to render "
                                                          "instead of the protocol views")] = None,
        masks: Annotated[Path | None, typer.Option(
            help="a mask set folder: render in its cameras and also write overlays with the IoU against "
                 "its masks")] = None,
        size: Annotated[int | None, typer.Option(
            help=f"image size in pixels for --views, 8 to {MAX_SIDE}; cameras files are held to the same "
                 f"limits (each side, and {MAX_PIXELS:,} pixels over all views) [default: 256]")] = None,
        resolution: Annotated[int, typer.Option(help=f"marching-cubes samples along the longest side, "
                                                     f"{MIN_RESOLUTION} to {MAX_RESOLUTION} (SDF "
                                                     "generators)")] = 128,
        cues: Annotated[bool, typer.Option("--cues/--no-cues", help=(
            "also write depth_###.npy (view-axis depth, scene units), normal_###.png and, for meshes with "
            "parts, part_###.png with parts.json"))] = True,
        preview_views: Annotated[bool, typer.Option("--previews/--no-previews",
                                                    help="also write shaded previews")] = True,
        overwrite: Annotated[bool, typer.Option("--overwrite", help=(
            "render into a folder that is not empty: all of its render files (view_*, preview_*, overlay_*, "
            "depth_*, normal_*, part_*, cameras.json, parts.json) are replaced as a whole, once the new render "
            "is complete; other files stay"))] = False,
        library: LibraryOpt = None,
        json_out: JsonOpt = False,
    ) -> None:
        """Render exact masks (view_000.png ...), cameras.json and shaded previews (preview_000.png ...)."""
        import numpy as np

        from ipm.files import staged_directory
        from ipm.io.cues import depth_name, part_name
        from ipm.io.masks import CAMERAS_FILE, view_name
        from ipm.viz.render_set import write_render_set

        if up.lower() not in ("y", "z"):
            raise UsageError(f"--up: expected y or z, got {up!r}")
        _check_output_folder(output, overwrite, masks)
        check_resolution_option(resolution, upper=False)
        cams, target = _cameras(views, cameras, masks, size)
        param_opts = {"--preset": preset, "--params": params, "--set": set_, "--random": random, "seed": seed}
        mesh, about = _source_mesh(source, up.lower(), normalize, resolution, library, param_opts)
        _check_outside(mesh, cams)

        result = {"dir": str(output), "views": len(cams), "faces": mesh.n_faces, **about}
        compare = None if target is None else target.masks.numpy()
        with staged_directory(output, replace=is_render_file if overwrite else None) as tmp:
            done = write_render_set(tmp, mesh, cams, cues=cues, previews=preview_views, compare=compare, near=NEAR)
        ious, parts = done.ious, done.parts
        result["masks"] = [str(output / view_name(i)) for i in range(len(cams))]
        if cues:
            result["depth"] = [str(output / depth_name(i)) for i in range(len(cams))]
            if parts:
                result["parts"] = [str(output / part_name(i)) for i in range(len(cams))]
        result["cameras"] = str(output / CAMERAS_FILE)
        if preview_views:
            result["previews"] = [str(output / f"preview_{i:03d}.png") for i in range(len(cams))]
        if ious:
            result["iou"] = [round(v, 6) for v in ious]
            result["mean_iou"] = round(float(np.mean(ious)), 6)
        if json_out:
            emit(result, True)
        else:
            emit({k: v for k, v in result.items() if k not in ("params", "masks", "previews")}, False)
