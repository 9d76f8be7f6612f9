"""``ipm vectorize IMAGE -o OUT.svg``: a raster line drawing as curves (cubic Beziers), with junctions and
endpoints, fitted as the zero set of a piecewise bicubic implicit function (``ipm.curves``).

Writes the SVG, a JSON file with everything (curves as samples and Beziers, junctions, endpoints, the
half-width; default: beside the SVG with the suffix .json) and, with ``--preview``, a PNG of the curves
over the input, all or none (:func:`ipm.files.all_or_nothing`). ``--json`` prints the summary as JSON (the
file goes to ``--json-file``).

The drawing may have at most ``MAX_PIXELS`` pixels, checked from its header before it is decoded: the fit's
time and memory grow with the pixels (2048 x 2048 took 65 s and 4.5 GB at the default 300 steps here; a
6000 x 6000 drawing would take over 8 minutes and about 36 GB)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated

import typer

from ipm.cli.common import JsonOpt, UsageError, check_output, emit

# the most pixels a drawing may have (2048 x 2048)
MAX_PIXELS = 2048 * 2048

COLOURS = [(230, 25, 75), (60, 180, 75), (0, 130, 200), (245, 130, 48), (145, 30, 180), (70, 240, 240),
           (240, 50, 230), (128, 128, 0)]


def preview_png(ink, v, path: Path) -> None:
    """The curves (coloured polylines) over the input, junctions as red squares, endpoints as blue
    circles, drawn at up to 3 times the size (Pillow), written atomically."""
    import numpy as np
    from PIL import Image, ImageDraw

    from ipm.curves.bezier import sample_beziers
    from ipm.files import atomic_path

    H, W = v.size
    k = max(1, min(3, 1024 // max(H, W)))
    base = (255 - 160 * ink).clip(0, 255).astype(np.uint8)
    im = Image.fromarray(base).convert("RGB").resize((W * k, H * k), Image.NEAREST)
    draw = ImageDraw.Draw(im)
    for i, c in enumerate(v.curves):
        pts = sample_beziers(c.beziers, 0.5) * k
        if len(pts) > 1:
            draw.line([tuple(p) for p in pts], fill=COLOURS[i % len(COLOURS)], width=max(1, k))
    s = 2 * k
    for x, y in np.asarray(v.junctions).reshape(-1, 2) * k:
        draw.rectangle([x - s, y - s, x + s, y + s], outline=(255, 0, 0), width=max(1, k // 2))
    for x, y in np.asarray(v.endpoints).reshape(-1, 2) * k:
        draw.ellipse([x - s, y - s, x + s, y + s], outline=(0, 0, 255), width=max(1, k // 2))
    with atomic_path(path) as tmp:
        im.save(tmp, format="PNG")


def check_drawing_size(path: Path) -> None:
    """Refuse a drawing of more than ``MAX_PIXELS`` pixels from its header, before decoding it (a file that
    is not an image is left for :func:`ipm.io.drawings.read_drawing` to name)."""
    from PIL import Image

    limit = Image.MAX_IMAGE_PIXELS
    Image.MAX_IMAGE_PIXELS = None  # only the header is read here: no decompression bomb to fear
    try:
        with Image.open(path) as im:
            w, h = im.size
    except Exception:  # noqa: BLE001 - any unreadable file: read_drawing gives its one line
        return
    finally:
        Image.MAX_IMAGE_PIXELS = limit
    if w * h > MAX_PIXELS:
        beyond = (f"; more than {limit:,} pixels, Pillow's decompression-bomb limit, are not even read"
                  if limit and w * h > limit else "")
        raise UsageError(f"drawing {path}: {w}x{h} is {w * h:,} pixels; expected at most {MAX_PIXELS:,} "
                         f"pixels (the limit, 2048x2048{beyond}); scale the drawing down")


def register(app: typer.Typer) -> None:
    @app.command()
    def vectorize(
        image: Annotated[Path, typer.Argument(help="line drawing (PNG, JPEG): dark strokes on light paper, "
                                                   "or light on dark (detected), or a stroke mask; at most "
                                                   f"{MAX_PIXELS:,} pixels (2048x2048)")],
        output: Annotated[Path, typer.Option("-o", "--output", help="the curves as SVG (.svg)")],
        json_file: Annotated[Path | None, typer.Option("--json-file", help="everything as JSON (.json); "
                                                       "default: beside the SVG")] = None,
        preview: Annotated[Path | None, typer.Option(help="also write the curves over the input (.png)")] = None,
        cell: Annotated[int, typer.Option(help="cell size in pixels, 2 or more")] = 8,
        width: Annotated[float | None, typer.Option(help="stroke half-width in pixels; default: estimated")] = None,
        steps: Annotated[int, typer.Option(help="Adam steps")] = 300,
        seed: Annotated[int, typer.Option("--seed", min=0, help="random seed (0 or more)")] = 0,
        json_out: JsonOpt = False,
    ) -> None:
        """Vectorize a line drawing: curves, junctions and endpoints as SVG and JSON."""
        import json

        from ipm.curves import VectorizeSettings, to_json, to_svg
        from ipm.curves import vectorize as run
        from ipm.files import all_or_nothing, check_distinct, write_text
        from ipm.io.drawings import read_drawing

        check_output(output, (".svg",))
        json_path = json_file if json_file is not None else output.with_suffix(".json")
        check_output(json_path, (".json",))
        if preview is not None:
            check_output(preview, (".png",))
        paths = [output, json_path] + ([preview] if preview is not None else [])
        check_distinct({"-o/--output": output, "--json-file" if json_file is not None else
                        f"the JSON file beside -o ({json_path.name})": json_path, "--preview": preview})
        settings = VectorizeSettings(cell=cell, width=width, steps=steps, seed=seed).check()
        check_drawing_size(image)
        ink = read_drawing(image)
        t0 = time.perf_counter()
        v = run(ink, settings)
        seconds = time.perf_counter() - t0
        with all_or_nothing(*paths):
            write_text(output, to_svg(v))
            write_text(json_path, json.dumps(to_json(v)) + "\n")
            if preview is not None:
                preview_png(ink, v, preview)
        result = {"svg": str(output), "json": str(json_path)}
        if preview is not None:
            result["preview"] = str(preview)
        result.update({"curves": len(v.curves), "closed": sum(c.closed for c in v.curves),
                       "junctions": len(v.junctions), "endpoints": len(v.endpoints),
                       "width": round(v.width, 3), "loss": round(v.loss, 6), "seconds": round(seconds, 2)})
        emit(result, json_out)
