"""``ipm mask PHOTO --box X0,Y0,X1,Y1 -o MASK.png``: a foreground mask from a photo and a box (GrabCut).

The box is four whole, finite pixel coordinates. The mask and the ``--overlay`` are written all or none
(:func:`ipm.files.all_or_nothing`), and an overlay path that is the mask's own file is refused before any
work."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from ipm.cli.common import JsonOpt, SeedOpt, UsageError, check_output, emit


def register(app: typer.Typer) -> None:
    @app.command()
    def mask(
        photo: Annotated[Path, typer.Argument(help="the photo (JPEG, PNG, ...)")],
        box: Annotated[str, typer.Option(help="X0,Y0,X1,Y1: a box around the object, in whole pixels "
                                              "(x right, y down; X1, Y1 exclusive)")],
        output: Annotated[Path, typer.Option("-o", "--output", help="mask PNG (255 on the object)")],
        iterations: Annotated[int, typer.Option(min=1, max=100, help="GrabCut iterations")] = 5,
        context: Annotated[float, typer.Option(min=0.0, max=10.0, help=(
            "band around the box that the background colour model learns from, in box sizes"))] = 0.5,
        overlay: Annotated[Path | None, typer.Option(help="also write the photo with the mask over it (PNG; "
                                                          "a file other than -o)")] = None,
        seed: SeedOpt = 0,
        json_out: JsonOpt = False,
    ) -> None:
        """Make a foreground mask from a photo and a box around the object (GrabCut, no learned weights)."""
        from ipm.files import all_or_nothing, check_distinct
        from ipm.io.masks import read_photo, write_mask
        from ipm.segment import box_mask, parse_box

        check_output(output, (".png",))
        if overlay is not None:
            check_output(overlay, (".png",))
        check_distinct({"-o/--output": output, "--overlay": overlay})
        corners = parse_box(box)
        image = read_photo(photo)
        m = box_mask(image, corners, iterations=iterations, context=context, seed=seed)
        if not m.any():
            raise UsageError(f"--box {box}: no foreground found in the box; draw the box around the object")
        with all_or_nothing(output, *([overlay] if overlay else [])):
            write_mask(output, m)
            if overlay is not None:
                _write_overlay(overlay, image, m)
        emit({"mask": str(output), "pixels": int(m.sum()), **({"overlay": str(overlay)} if overlay else {})},
             json_out)


def _write_overlay(path: Path, image, mask) -> None:
    import numpy as np

    from ipm.render.preview import save_png

    out = image.astype(np.float64)
    out[mask] = 0.55 * out[mask] + 0.45 * np.array([0.0, 255.0, 0.0])
    save_png(path, out.round().astype(np.uint8))
