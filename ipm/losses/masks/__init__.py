"""Mask losses, one module each, registered by name in :data:`LOSSES` (``FitSettings.loss``,
``ipm fit --loss``).

A mask loss is a pure function ``(pred, target, **options) -> loss`` of soft masks ``(..., H, W)`` in [0, 1]
(any float dtype, differentiable in ``pred``) returning a 0-dim tensor, registered with
``@LOSSES.register("name")``. Its keyword-only options take their values from the fit's settings of the same
name (``FitSettings.transport``: :class:`TransportSettings`). Adding one is one new module in this package.

A fit's loss is one of them or a weighted sum, written ``iou+0.5*sinkhorn`` (:func:`parse_loss`,
:func:`mask_loss`).
"""

from __future__ import annotations

import inspect
import re
from collections.abc import Callable

import torch

from ipm.errors import InputError
from ipm.registry import Registry

LOSSES = Registry("mask loss", packages=["ipm.losses.masks"])

_TERM = re.compile(r"^(?:(\d+(?:\.\d*)?|\.\d+)\s*\*\s*)?([a-z_][a-z0-9_]*)$")


def parse_loss(spec: str) -> list[tuple[float, str]]:
    """``"iou+0.5*sinkhorn"`` -> ``[(1.0, "iou"), (0.5, "sinkhorn")]``: registered names, each at most
    once, weights positive and finite. Raises :class:`InputError` with one line otherwise."""
    names = LOSSES.names()
    allowed = f"a mask loss ({', '.join(names)}) or a weighted sum of them such as iou+0.5*sinkhorn"
    if not isinstance(spec, str):
        raise InputError(f"loss: expected {allowed}, got {spec!r}")
    terms: list[tuple[float, str]] = []
    for part in spec.split("+"):
        m = _TERM.match(part.strip())
        if m is None:
            raise InputError(f"loss: expected {allowed}, got {spec!r}")
        w = float(m.group(1)) if m.group(1) else 1.0
        name = m.group(2)
        if name not in names:
            raise InputError(f"loss: expected {allowed}, got {spec!r}")
        if not 0.0 < w < float("inf"):
            raise InputError(f"loss: expected positive finite weights, got {spec!r}")
        if any(n == name for _, n in terms):
            raise InputError(f"loss: expected each mask loss at most once, got {spec!r}")
        terms.append((w, name))
    return terms


def loss_options(name: str) -> set[str]:
    """The keyword-only options the mask loss ``name`` takes."""
    params = inspect.signature(LOSSES[name]).parameters.values()
    return {p.name for p in params if p.kind is inspect.Parameter.KEYWORD_ONLY}


def mask_loss(spec: str, **options) -> Callable[[torch.Tensor, torch.Tensor], torch.Tensor]:
    """The loss ``spec`` (see :func:`parse_loss`) as one function ``(pred, target) -> 0-dim``; each term is
    given the ``options`` it takes (:func:`loss_options`), the others are ignored."""
    terms = [(w, LOSSES[n], {k: v for k, v in options.items() if k in loss_options(n)}) for w, n in parse_loss(spec)]

    def loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        total = None
        for w, fn, opts in terms:
            v = fn(pred, target, **opts)
            total = w * v if total is None else total + w * v
        return total

    return loss
