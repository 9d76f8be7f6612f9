"""Level of detail of a mesh tree's round primitives."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields

import numpy as np

from ipm.errors import InputError
from ipm.params import dataclass_from


@dataclass(frozen=True)
class MeshLod:
    """Level of detail of round primitives: ``segments`` around their axis, ``rings`` from pole to
    pole of a sphere."""

    segments: int = 32
    rings: int = 16

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or v < 3:
                raise InputError(f"lod {f.name}: expected an integer >= 3, got {v!r}")


LODS = {"low": MeshLod(16, 8), "medium": MeshLod(), "high": MeshLod(64, 32)}


def resolve_lod(lod) -> MeshLod:
    """A :class:`MeshLod` from None (medium), a name (low, medium, high), a dict or a MeshLod."""
    if lod is None:
        return LODS["medium"]
    if isinstance(lod, MeshLod):
        return lod
    if isinstance(lod, str) and lod in LODS:
        return LODS[lod]
    if isinstance(lod, Mapping):
        return dataclass_from(MeshLod, lod, "lod")
    raise InputError(f"lod: expected None, one of {', '.join(LODS)}, a dict or a MeshLod, got {lod!r}")
