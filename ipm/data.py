"""Where the real data made by others lives, in one place: ``../shared/data/real`` beside the project (its README
gives each file's up axis, units and licence), or the folder ``$IPM_DATA`` names. Nothing of it is copied into the
project; the demo, the benchmarks and the tests read it from here."""

from __future__ import annotations

import os
from pathlib import Path

from ipm.errors import InputError

ENV = "IPM_DATA"


def root() -> Path:
    """The folder of the real data: ``$IPM_DATA``, else ``../shared/data/real`` beside the project."""
    given = os.environ.get(ENV)
    return Path(given) if given else (Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "real").resolve()


def path(rel: str) -> Path:
    """A file of the real data (``vessels/ocrtoc_mug.ply``); :class:`InputError` naming where it was looked for
    when it is not there."""
    p = root() / rel
    if not p.exists():
        raise InputError(f"real data: expected {rel} under {root()} (../shared/data/real beside the project, or "
                         f"${ENV}), got nothing there")
    return p


# the files the demo and the benchmarks use, with their up axes where the data README's is wrong
MUG = "vessels/ocrtoc_mug.ply"                   # Z up
TEAPOT = "vessels/trimesh_teapot.stl"             # Z up (table1.toml's tune split)
SUGAR_BOWL = "vessels/polyhaven_teaset_sugar_bowl.obj"   # Y up (table1.toml's tune split)
BOTTLE = "vessels/trimesh_fuze_bottle.obj"       # Z up (the README says Y: its long axis is Z, base at z = 0)
ARMCHAIR = "furniture/kaolin_armchair.obj"       # Y up
DUTCH_HOUSE = "buildings/3dbag_0503100000031927_lod22.obj"   # Z up, LoD2.2 (table_coverage's building_5)
PHOTOS = "photos/cleargrasp_cups"
PHOTO = f"{PHOTOS}/000000130-opaque-rgb-img.jpg"
PHOTO_DEPTH = f"{PHOTOS}/000000130-opaque-depth-mm.png"
PHOTO_INTRINSICS = f"{PHOTOS}/camera_intrinsics.yaml"
PHOTO_BOX = (380, 255, 600, 495)                  # the teal mug (the data README's box)
