"""``vectorize``: a raster line drawing to a curve network (the steps of the package docstring)."""

from __future__ import annotations

import logging

import numpy as np
import torch

from ipm.curves.bezier import fit_beziers
from ipm.curves.clean import clean_ink
from ipm.curves.extract import bridge_gaps, chain, join_corners, network, resample, zero_pieces
from ipm.curves.fit import fit_field
from ipm.curves.hermite import gaussian_scale
from ipm.curves.init import estimate_half_width, initial_data, skeleton
from ipm.curves.settings import Curve, Vectorized, VectorizeSettings
from ipm.curves.strokes import calibrate_width
from ipm.errors import InputError
from ipm.threads import one_by_default

log = logging.getLogger("ipm.curves")


def check_ink(ink, cell: int) -> None:
    """Refuse what cannot be vectorized: not (H, W), non-finite or outside [0, 1], smaller than one
    cell, or without ink (all paper) or all ink."""
    shape = tuple(getattr(ink, "shape", ()))
    if len(shape) != 2:
        raise InputError(f"expected an ink image (H, W), got shape {shape}")
    if min(shape) == 0:
        raise InputError(f"expected an ink image with pixels, got size {shape[0]} x {shape[1]}")
    if min(shape) < cell:
        raise InputError(f"expected an image at least one cell ({cell} pixels) on each side, "
                         f"got {shape[0]} x {shape[1]}")
    arr = ink.detach().cpu().numpy() if isinstance(ink, torch.Tensor) else np.asarray(ink)
    if not np.all(np.isfinite(arr)) or arr.min() < 0 or arr.max() > 1:
        raise InputError("expected ink values in [0, 1], got values outside or not finite")
    strokes = arr > 0.5
    if not strokes.any():
        raise InputError("nothing to vectorize: the image has no strokes (all paper)")
    if strokes.all():
        raise InputError("nothing to vectorize: the image is all ink (no paper)")


@one_by_default
def vectorize(ink, settings: VectorizeSettings = VectorizeSettings()) -> Vectorized:
    """Vectorize ``ink`` (H, W) float in [0, 1], 1 = stroke (numpy or torch; the fit runs on a torch
    input's device, numpy on the CPU). Deterministic for the same input, settings and seed."""
    settings.check()
    check_ink(ink, settings.cell)
    device = ink.device if isinstance(ink, torch.Tensor) else torch.device("cpu")
    arr = (ink.detach().cpu().numpy() if isinstance(ink, torch.Tensor) else np.asarray(ink)).astype(np.float64)
    cleaned = clean_ink(arr)
    arr, mask = cleaned.ink, cleaned.mask
    skel = skeleton(mask)
    r = float(settings.width) if settings.width is not None else estimate_half_width(arr, skel)
    data0, inked = initial_data(arr, skel, settings.cell, r)
    target = torch.as_tensor(arr, dtype=torch.float32, device=device)
    data, loss = fit_field(data0, target, settings.cell, r, settings.steps, settings.lr, settings.continuity,
                           settings.smooth, settings.seed, inked)
    pieces = zero_pieces(data, settings.cell, settings.samples, arr, torn=0.25 * gaussian_scale(r))
    chained = chain(pieces, join=max(1.0, 0.5 * r))
    bridged = bridge_gaps(chained, max(2.0 * settings.cell, 4.0 * r), arr)
    bridged = join_corners(bridged, max(2.0 * settings.cell, 4.0 * r), r, arr)
    paths, junctions, endpoints = network(bridged, r, arr.shape, ink=arr)
    curves = []
    for pts, closed in paths:
        pts = resample(pts, 1.0, closed)
        if len(pts) < 2:
            continue
        curves.append(Curve(points=pts, closed=closed,
                            beziers=fit_beziers(pts, settings.bezier_tol, closed)))
    curves = tuple(curves)
    if settings.width is None and curves:
        r = calibrate_width(curves, cleaned.strokes, r)
    log.debug("curves: %d curves, %d junctions, %d endpoints, r %.3f", len(curves), len(junctions),
              len(endpoints), r)
    return Vectorized(curves=curves, junctions=junctions, endpoints=endpoints, width=float(r),
                      size=(int(arr.shape[0]), int(arr.shape[1])), loss=float(loss))
