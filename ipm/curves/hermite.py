"""The piecewise bicubic Hermite field p(x, y) on a grid of square cells, and its raster loss.

Each cell holds its own copy of the data at its four corners: the value p and the derivatives p_u, p_v,
p_uv, with (u, v) in [0, 1]^2 the cell's local coordinates (u = (x - x0) / h, so p_u = h p_x and
p_uv = h^2 p_xy: every quantity is in the units of p, pixels). Inside the cell p is the tensor-product
cubic Hermite interpolant (the bicubic Hermite patch; e.g. de Boor, "A Practical Guide to Splines", or
"Bicubic interpolation" on Wikipedia):

    p(u, v) = sum_{a, b} b_a(v) C[a, b] b_b(u),   b(t) = [h00, h01, h10, h11](t)

with h00 = 2t^3 - 3t^2 + 1, h01 = -2t^3 + 3t^2 (values at t = 0, 1) and h10 = t^3 - 2t^2 + t,
h11 = t^3 - t^2 (slopes at t = 0, 1); C holds the corner values (top-left block), p_u (top-right),
p_v (bottom-left) and p_uv (bottom-right). Two cells holding the same data at a shared corner pair agree
in value and in both first derivatives all along the shared edge (each depends only on the edge's two
corners), so the field is C1 there.

Layout of the data: ``(Ny, Nx, 2, 2, 4)`` float, cell row, cell column, corner row (0 top, 1 bottom),
corner column (0 left, 1 right), quantity (p, p_u, p_v, p_uv). Tensors follow their inputs' device.
"""

from __future__ import annotations

import math

import numpy as np
import torch

P, PU, PV, PUV = range(4)


def basis(t: torch.Tensor, order: int = 0) -> torch.Tensor:
    """The four cubic Hermite basis functions [h00, h01, h10, h11] (or their ``order``-th derivative) at
    ``t``: (n,) -> (n, 4)."""
    t2, t3 = t * t, t * t * t
    one = torch.ones_like(t)
    if order == 0:
        cols = (2 * t3 - 3 * t2 + 1, -2 * t3 + 3 * t2, t3 - 2 * t2 + t, t3 - t2)
    elif order == 1:
        cols = (6 * t2 - 6 * t, -6 * t2 + 6 * t, 3 * t2 - 4 * t + one, 3 * t2 - 2 * t)
    elif order == 2:
        cols = (12 * t - 6, -12 * t + 6, 6 * t - 4, 6 * t - 2)
    else:
        raise ValueError(f"expected a derivative order of 0, 1 or 2, got {order}")
    return torch.stack(cols, dim=-1)


def coefficients(data: torch.Tensor) -> torch.Tensor:
    """The 4 x 4 coefficient matrix C of every cell: (..., 2, 2, 4) -> (..., 4, 4); rows index the basis
    in v, columns the basis in u (module docstring)."""
    top = torch.cat([data[..., P], data[..., PU]], dim=-1)      # (..., 2 [j], 4): p[j, :], p_u[j, :]
    bottom = torch.cat([data[..., PV], data[..., PUV]], dim=-1)  # p_v[j, :], p_uv[j, :]
    return torch.cat([top, bottom], dim=-2)


def sample_cells(data: torch.Tensor, t: torch.Tensor, du: int = 0, dv: int = 0) -> torch.Tensor:
    """Every cell's field (or its derivative d^du/du d^dv/dv) on the local grid ``t`` x ``t``:
    data (Ny, Nx, 2, 2, 4), t (n,) -> (Ny, Nx, n [v], n [u])."""
    C = coefficients(data)
    bu = basis(t.to(data), du)
    bv = basis(t.to(data), dv)
    return torch.einsum("ka,yxab,lb->yxkl", bv, C, bu)


def render_field(data: torch.Tensor, cell: int, size: tuple[int, int]) -> torch.Tensor:
    """p at the pixel centres of a ``size`` = (H, W) image: (H, W). Cell (cy, cx) covers the pixels
    [cy h, (cy + 1) h) x [cx h, (cx + 1) h); pixel centres sit at local t = (k + 0.5) / h."""
    ny, nx = data.shape[:2]
    t = (torch.arange(cell, dtype=data.dtype, device=data.device) + 0.5) / cell
    p = sample_cells(data, t)  # (Ny, Nx, h, h)
    return p.permute(0, 2, 1, 3).reshape(ny * cell, nx * cell)[: size[0], : size[1]]


def gaussian_scale(half_width: float) -> float:
    """The w of exp(-p^2 / w^2) that crosses 1/2 at |p| = ``half_width``: w = r / sqrt(ln 2)."""
    return half_width / math.sqrt(math.log(2.0))


def intensity(p: torch.Tensor, half_width: float) -> torch.Tensor:
    """Rendered ink I = exp(-p^2 / w^2), w = :func:`gaussian_scale` (``half_width``)."""
    w = gaussian_scale(half_width)
    return torch.exp(-(p / w) ** 2)


def raster_loss(data: torch.Tensor, ink: torch.Tensor, cell: int, half_width: float) -> torch.Tensor:
    """Mean squared difference between the rendered ink and ``ink`` (H, W): a scalar."""
    img = intensity(render_field(data, cell, tuple(ink.shape)), half_width)
    return ((img - ink) ** 2).mean()


def continuity(data: torch.Tensor, eps: float, active: torch.Tensor | None = None) -> torch.Tensor:
    """Soft continuity between the copies of shared corners held by edge-adjacent cells: the sum of the
    Charbonnier penalty sqrt(d^2 + eps^2) - eps (Charbonnier et al. 1994) over every quantity of every
    shared corner. Its slope is bounded, so the data can break continuity where a single smooth function
    cannot follow it (endpoints, T-junctions). ``active`` (Ny, Nx) bool: only pairs of active cells count
    (default all)."""
    dx = data[:, :-1, :, 1, :] - data[:, 1:, :, 0, :]
    dy = data[:-1, :, 1, :, :] - data[1:, :, 0, :, :]
    ex = torch.sqrt(dx * dx + eps * eps) - eps
    ey = torch.sqrt(dy * dy + eps * eps) - eps
    if active is not None:
        ex = ex * (active[:, :-1] & active[:, 1:])[:, :, None, None].to(ex)
        ey = ey * (active[:-1, :] & active[1:, :])[:, :, None, None].to(ey)
    return ex.sum() + ey.sum()


def bending(data: torch.Tensor, cell: int) -> torch.Tensor:
    """Thin-plate energy sum over cells of the integral of p_xx^2 + 2 p_xy^2 + p_yy^2 dx dy in pixel units,
    by Simpson's rule on 3 x 3 points per cell."""
    t = torch.tensor([0.0, 0.5, 1.0], dtype=data.dtype, device=data.device)
    wts = torch.tensor([1.0, 4.0, 1.0], dtype=data.dtype, device=data.device) / 6.0
    wgt = wts[:, None] * wts[None, :]
    puu = sample_cells(data, t, du=2)
    pvv = sample_cells(data, t, dv=2)
    puv = sample_cells(data, t, du=1, dv=1)
    e = (puu ** 2 + 2 * puv ** 2 + pvv ** 2) * wgt
    return e.sum() / cell ** 2  # (1/h^2)^2 per squared second derivative, h^2 of area


def sample_cells_np(data: np.ndarray, n: int) -> np.ndarray:
    """Every cell's field on an n x n grid of local coordinates from 0 to 1 inclusive (borders shared
    with the neighbours): (Ny, Nx, 2, 2, 4) float64 -> (Ny, Nx, n, n)."""
    with torch.no_grad():
        t = torch.linspace(0.0, 1.0, n, dtype=torch.float64)
        return sample_cells(torch.as_tensor(data, dtype=torch.float64), t).numpy()


def from_polynomial(coeffs: np.ndarray, cell: int, origin: np.ndarray, center: np.ndarray,
                    scale: float) -> np.ndarray:
    """Corner data (2, 2, 4) of one cell (top-left corner ``origin`` (x, y) in pixels) for the quadratic
    f = c0 s^2 + c1 s t + c2 t^2 + c3 s + c4 t + c5 of the local coordinates s = (x - cx) / scale,
    t = (y - cy) / scale. A bicubic Hermite patch reproduces every polynomial of degree <= 3 in each
    variable, so the patch equals f exactly."""
    a, b, c, d, e, f = coeffs
    out = np.zeros((2, 2, 4))
    for j in range(2):
        for i in range(2):
            s = (origin[0] + i * cell - center[0]) / scale
            t = (origin[1] + j * cell - center[1]) / scale
            k = cell / scale
            out[j, i, P] = a * s * s + b * s * t + c * t * t + d * s + e * t + f
            out[j, i, PU] = k * (2 * a * s + b * t + d)
            out[j, i, PV] = k * (b * s + 2 * c * t + e)
            out[j, i, PUV] = k * k * b
    return out
