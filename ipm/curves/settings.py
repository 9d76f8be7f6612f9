"""Settings of :func:`ipm.curves.vectorize` and the values it hands back."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ipm.errors import InputError


def _number(name: str, value, lo: float, hi: float, integer: bool = False) -> None:
    kind = "an integer" if integer else "a number"
    ok = (isinstance(value, (int, np.integer)) and not isinstance(value, bool)) if integer else (
        isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
        and math.isfinite(float(value)))
    if not ok or not lo <= value <= hi:
        raise InputError(f"vectorize {name}: expected {kind} in [{lo:g}, {hi:g}], got {value!r}")


@dataclass(frozen=True)
class VectorizeSettings:
    """How a drawing is vectorized. Checked by :meth:`check` (one-line :class:`InputError`).

    cell: cell size in pixels (2 to 64); width: the stroke half-width r in pixels (ink > 1/2 within r of
    the centreline; the field renders exp(-p^2 / w^2) with w = r / sqrt(ln 2)), None: estimated from the
    image and calibrated on the result; steps, lr: Adam; continuity: weight of the soft continuity of
    shared corners (Charbonnier, per corner quantity, against the raster loss summed over pixels);
    smooth: weight of the thin-plate energy; bezier_tol: max distance in pixels of the Bezier fit from the
    extracted polyline; samples: samples per pixel of the zero-set extraction; seed: the seed (the fit
    itself is deterministic; the seed jitters the start by 1e-3 pixel so that runs can be repeated
    with other starts)."""

    cell: int = 8
    width: float | None = None
    steps: int = 300
    lr: float = 0.05
    continuity: float = 0.5
    smooth: float = 0.5
    bezier_tol: float = 0.2
    samples: int = 4
    seed: int = 0

    def check(self) -> VectorizeSettings:
        _number("cell", self.cell, 2, 64, integer=True)
        if self.width is not None:
            _number("width", self.width, 0.25, 100.0)
        _number("steps", self.steps, 0, 100000, integer=True)
        _number("lr", self.lr, 1e-6, 10.0)
        _number("continuity", self.continuity, 0.0, 1e6)
        _number("smooth", self.smooth, 0.0, 1e6)
        _number("bezier_tol", self.bezier_tol, 0.01, 100.0)
        _number("samples", self.samples, 1, 16, integer=True)
        _number("seed", self.seed, 0, 2**63 - 1, integer=True)
        return self


@dataclass(frozen=True)
class Curve:
    """One curve: ``points`` (n, 2) float64 samples in pixel coordinates (x right, y down, pixel centres
    at +0.5); ``closed``; ``beziers`` (m, 4, 2) float64 cubic Bezier control points."""

    points: np.ndarray
    closed: bool
    beziers: np.ndarray


@dataclass(frozen=True)
class Vectorized:
    """A vectorized drawing: curves, ``junctions`` (j, 2) and ``endpoints`` (e, 2) in pixel coordinates,
    the stroke half-width ``width`` (pixels), the image ``size`` (H, W) and the final raster ``loss``
    (mean squared difference of rendered and given ink per pixel)."""

    curves: tuple[Curve, ...]
    junctions: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    endpoints: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    width: float = 1.0
    size: tuple[int, int] = (0, 0)
    loss: float = 0.0
