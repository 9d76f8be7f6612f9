"""What the silhouette-fitting methods (``sdf-grid``, ``mesh-deform``) share around their Adam loop: the
checked and reduced input views, and the per-step record and log of the loss terms."""

from __future__ import annotations

import logging
import math
from collections.abc import Callable

import torch

from ipm.bench.methods import Task
from ipm.bench.views import check_task, fit_views
from ipm.types import Camera

log = logging.getLogger("ipm.bench.methods")


def fit_input(name: str, task: Task, budget: int, max_size: int) -> tuple[torch.Tensor, list[Camera]]:
    """The task checked (:func:`~ipm.bench.views.check_task`), then its masks as soft float32 targets
    (K, h, w) and their cameras, reduced to at most ``max_size`` pixels a side
    (:func:`~ipm.bench.views.fit_views`)."""
    check_task(name, task.masks, task.cameras, budget)
    return fit_views(task.masks, task.cameras, max_size)


def loss_terms(name: str, budget: int) -> tuple[dict, Callable[[int, torch.Tensor], None]]:
    """A dict for a loss function to store its detached terms in (``silhouette`` first), and the
    ``after_step`` for :func:`ipm.optim.adam.minimize` that keeps the last silhouette loss as a float
    (``terms["silhouette"]``, NaN before the first step) and logs every term every 25 steps."""
    terms: dict[str, float | torch.Tensor] = {"silhouette": math.nan}

    def after_step(step: int, loss: torch.Tensor) -> None:
        terms["silhouette"] = float(terms["silhouette"])
        if step % 25 == 0 or step == budget - 1:
            log.debug("%s step %d: %s", name, step, " ".join(f"{k} {float(v):.4f}" for k, v in terms.items()))

    return terms, after_step
