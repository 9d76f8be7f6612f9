"""Mask losses, one module each, registered by name in :data:`LOSSES` (``FitSettings.loss``,
``ipm fit --loss``).

A mask loss is a pure function ``(pred, target) -> loss`` of soft masks ``(..., H, W)`` in [0, 1] (any float
dtype, differentiable in ``pred``) returning a 0-dim tensor, registered with ``@LOSSES.register("name")``.
Adding one is one new module in this package.
"""

from __future__ import annotations

from ipm.registry import Registry

LOSSES = Registry("mask loss", packages=["ipm.losses.masks"])
