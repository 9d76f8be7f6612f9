"""What the converter methods (``bsp``, ``perturb``) share: the visual hull of the task as their input.

Both are mesh converters (:mod:`ipm.convert`), not silhouette fitters, so from K masks they convert the
visual hull of those masks (:func:`ipm.bench.methods.visual_hull.hull_mesh`, ``resolution`` voxels a
side). They see exactly the masks the other methods see, so they can be no better than the visual hull
of the same views up to smoothing; what they add is a compact, editable representation (``info``
reports its size). No image is rendered: ``evaluations`` is 0 and the conversion's own work is in
``info``.
"""

from __future__ import annotations

from ipm.bench.methods import Task
from ipm.bench.methods.visual_hull import hull_mesh
from ipm.bench.views import check_task
from ipm.types import TriMesh


def hull_input(name: str, task: Task, budget: int, resolution: int) -> TriMesh:
    """The checked task's visual hull on ``resolution``³ voxels (the mesh a converter method converts)."""
    check_task(name, task.masks, task.cameras, budget)
    return hull_mesh(task, resolution)[0]
