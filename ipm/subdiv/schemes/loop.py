"""Loop subdivision (Loop 1987): new edge vertices 3/8, 3/8, 1/8, 1/8; old vertices re-weighted with
Warren's beta; on boundaries the cubic B-spline rules (1/2, 1/2 and 3/4, 1/8, 1/8). libigl's matrix."""

from __future__ import annotations

import numpy as np

from ipm.subdiv import SCHEMES, LinearScheme


def _matrix(faces: np.ndarray, n: int):
    import igl

    return igl.loop_matrix(np.ascontiguousarray(faces, dtype=np.int64), n)


SCHEMES.add("loop", LinearScheme("loop", _matrix, boundary=True))
