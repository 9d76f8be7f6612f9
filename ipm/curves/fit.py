"""Fitting the piecewise bicubic field to a drawing's ink by Adam (Kingma and Ba 2015).

The objective, summed over pixels so that the weights are per pixel of ink:

    E = sum_pixels (exp(-p^2 / w^2) - ink)^2 + continuity * C(data) + smooth * B(data)

C is :func:`ipm.curves.hermite.continuity` (soft, Charbonnier, eps = w / 4) and B the thin-plate energy
:func:`ipm.curves.hermite.bending`. The learning rate follows a cosine schedule to a tenth of its start.
"""

from __future__ import annotations

import logging
import math

import numpy as np
import torch

from ipm.curves.hermite import bending, continuity, gaussian_scale, render_field

log = logging.getLogger("ipm.curves")


def fit_field(data0: np.ndarray, ink: torch.Tensor, cell: int, half_width: float, steps: int, lr: float,
              w_continuity: float, w_smooth: float, seed: int = 0,
              active: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """Adam on the Hermite data (Ny, Nx, 2, 2, 4) from ``data0`` against ``ink`` (H, W) (its dtype and
    device are used): (fitted data as float64 numpy, final mean squared raster error per pixel)."""
    gen = torch.Generator().manual_seed(int(seed))
    jitter = 1e-3 * torch.randn(data0.shape, generator=gen, dtype=torch.float64) if seed else 0.0
    data = (torch.as_tensor(data0, dtype=torch.float64) + jitter).to(ink).requires_grad_(True)
    w = gaussian_scale(half_width)
    eps = w / 4.0
    opt = torch.optim.Adam([data], lr=lr)
    size = tuple(ink.shape)
    act = None if active is None else torch.as_tensor(active, device=ink.device)
    for k in range(steps):
        for g in opt.param_groups:
            g["lr"] = lr * (0.1 + 0.9 * 0.5 * (1.0 + math.cos(math.pi * k / max(steps, 1))))
        opt.zero_grad(set_to_none=True)
        img = torch.exp(-(render_field(data, cell, size) / w) ** 2)
        loss = ((img - ink) ** 2).sum()
        if w_continuity > 0:
            loss = loss + w_continuity * continuity(data, eps, act)
        if w_smooth > 0:
            loss = loss + w_smooth * bending(data, cell)
        loss.backward()
        opt.step()
    with torch.no_grad():
        img = torch.exp(-(render_field(data, cell, size) / w) ** 2)
        mse = float(((img - ink) ** 2).mean())
    log.debug("curves: fitted %d steps, raster mse %.5f", steps, mse)
    return data.detach().cpu().double().numpy(), mse
