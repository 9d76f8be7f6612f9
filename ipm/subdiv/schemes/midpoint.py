"""Midpoint subdivision: every edge split at its midpoint, old vertices kept (the surface does not move;
only the triangles get smaller). libigl's ``upsample_matrix``."""

from __future__ import annotations

import numpy as np

from ipm.subdiv import SCHEMES, LinearScheme


def _matrix(faces: np.ndarray, n: int):
    import igl

    return igl.upsample_matrix(np.ascontiguousarray(faces, dtype=np.int64), n)


SCHEMES.add("midpoint", LinearScheme("midpoint", _matrix, boundary=True))
