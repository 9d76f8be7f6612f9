"""A render set written view by view: what ``ipm render`` leaves in its folder (:mod:`ipm.io.masks`' mask set,
:mod:`ipm.io.cues`' depth, normal and part-label maps, shaded previews, overlays against an earlier mask set).

One view at a time is rendered (the exact rasterizer), written and dropped, so memory holds one view; the caller
gives a staged folder (:func:`ipm.files.staged_directory`) that appears, or replaces an earlier render, only
when every view is written.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ipm.types import Camera, TriMesh

log = logging.getLogger(__name__)


@dataclass
class RenderSet:
    """What a render set holds: its views' count, the views whose masks are empty or touch the border, the IoU
    of each view against the masks it was compared with (empty without them), and whether it has part labels."""

    views: int
    empty: list[int] = field(default_factory=list)
    clipped: list[int] = field(default_factory=list)
    ious: list[float] = field(default_factory=list)
    parts: bool = False


def write_render_set(folder: Path, mesh: TriMesh, cameras: list[Camera], *, cues: bool = True,
                     previews: bool = True, compare: np.ndarray | None = None, near: float = 1e-3) -> RenderSet:
    """Render ``mesh`` in ``cameras`` into ``folder``: ``view_###.png`` exact masks and ``cameras.json``; with
    ``cues``, ``depth_###.npy``, ``normal_###.png`` and, for a mesh with groups, ``part_###.png`` and
    ``parts.json``; with ``previews``, shaded ``preview_###.png``; with ``compare`` (masks (K, H, W) of an earlier
    set in the same cameras), ``overlay_###.png`` and their IoU. Views whose mask is empty or touches the image
    border are logged as warnings and returned."""
    from ipm.files import write_text
    from ipm.io.cues import (
        depth_name,
        normal_name,
        part_name,
        write_depth,
        write_normals,
        write_part_names,
        write_parts,
    )
    from ipm.io.masks import CAMERAS_FILE, view_name, write_mask
    from ipm.metrics import mask_iou, touches_border
    from ipm.render.camera import cameras_to_json
    from ipm.render.preview import save_png, shade_fragments
    from ipm.render.raster import rasterize, view_maps

    out = RenderSet(len(cameras), parts=cues and mesh.groups is not None and bool(mesh.group_names))
    for i, cam in enumerate(cameras):
        fr = rasterize(mesh.verts, mesh.faces, cam, near=near)
        m = fr.mask.cpu().numpy()
        if not m.any():
            out.empty.append(i)
        elif touches_border(m):
            out.clipped.append(i)
        write_mask(folder / view_name(i), m)
        if cues:
            maps = view_maps(fr, mesh)
            write_depth(folder / depth_name(i), maps["depth"])
            write_normals(folder / normal_name(i), maps["normal"], maps["mask"])
            if maps["groups"] is not None:
                write_parts(folder / part_name(i), maps["groups"])
        if previews:
            save_png(folder / f"preview_{i:03d}.png", shade_fragments(fr, cam, mesh))
        if compare is not None:
            from ipm.viz import overlay

            t = compare[i, : cam.height, : cam.width]
            out.ious.append(mask_iou(t, m))
            overlay(t, m, f"view {i}").save(folder / f"overlay_{i:03d}.png", format="PNG")
        del fr, m
    write_text(folder / CAMERAS_FILE, cameras_to_json(cameras))
    if out.parts:
        write_part_names(folder, mesh.group_names)
    if out.empty:
        log.warning("the object is outside views %s: their masks are empty", ", ".join(map(str, out.empty)))
    if out.clipped:
        log.warning("the object touches the image border in views %s: a fit cannot see where it ends (use "
                    "--normalize or move the cameras out)", ", ".join(map(str, out.clipped)))
    return out
