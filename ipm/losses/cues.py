"""Losses of the cues beyond silhouettes: depth, part labels and a shaded photo (torch only).

Each takes what the deferred renderer gives for one view (:func:`ipm.render.render_deferred`) and the
view's target, and returns a 0-dim loss on a scale comparable with a soft-IoU loss (about 0.1 for a
fair fit, 1 for none), so that the weights of ``FitSettings`` start at 1.

- :func:`depth_loss`: smooth L1 of the depth difference on the target's object pixels, in units of a
  tenth of the median target depth (an error of 1 % of the distance everywhere costs 0.05, one of 10 %
  about 1); object pixels the shape does not cover cost as much as an error of a tenth of the distance,
  so leaving hard pixels uncovered does not pay;
- :func:`parts_loss`: the disagreement of the blurred labels per named part, averaged over the parts;
- :func:`shading_loss`: the photo's grey levels on the object against Lambert shading
  ``ambient + intensity * max(0, n . l)`` with the light solved in closed form for the current normals
  (:func:`fit_light`), as a share of the photo's variance there (0: explained, 1: no better than a
  constant).
"""

from __future__ import annotations

import math

import torch

# smooth-L1 knee and unit of the depth loss, as shares of the median target depth
DEPTH_KNEE = 0.01
DEPTH_UNIT = 0.1
# closed-form light: re-solves with the lit set of the previous solution
LIGHT_ITERATIONS = 3
# blur (pixels) under which part labels are compared
PARTS_BLUR = 1.5


def depth_scale(target: torch.Tensor) -> float:
    """The median of the finite values of a target depth map (its typical distance)."""
    return float(target[torch.isfinite(target)].median())


def depth_loss(pred: torch.Tensor, covered: torch.Tensor, target: torch.Tensor, object_mask: torch.Tensor,
               scale: float) -> torch.Tensor:
    """pred: (H, W) rendered view-axis depth; covered: (H, W) bool, where the shape is seen; target: (H, W)
    depth, NaN where there is no reading; object_mask: (H, W) bool, the target's object pixels; scale: the
    target's typical depth (:func:`depth_scale`). 0-dim, see the module docstring."""
    valid = torch.isfinite(target) & object_mask
    n = int(valid.sum())
    if n == 0:
        return pred.sum() * 0.0
    both = valid & covered
    diff = (pred - torch.nan_to_num(target, nan=0.0))[both]
    knee = DEPTH_KNEE * scale
    err = torch.nn.functional.smooth_l1_loss(diff, torch.zeros_like(diff), reduction="sum", beta=knee)
    missed = float(n - int(both.sum())) * DEPTH_UNIT * scale
    return (err + missed) / (n * DEPTH_UNIT * scale)


def depth_agreement(pred: torch.Tensor, covered: torch.Tensor, target: torch.Tensor, object_mask: torch.Tensor,
                    scale: float) -> int:
    """Object pixels whose rendered depth is within the loss's knee of the target (for the tie rule)."""
    valid = torch.isfinite(target) & object_mask & covered
    return int(((pred - torch.nan_to_num(target, nan=0.0)).abs() <= DEPTH_KNEE * scale)[valid].sum())


def blur(x: torch.Tensor, sigma: float) -> torch.Tensor:
    """A separable Gaussian blur of images ``(..., H, W)`` (standard deviation ``sigma`` pixels, kernel
    radius 3 sigma, zero outside the image); the identity for ``sigma`` 0."""
    if sigma <= 0:
        return x
    r = max(1, int(math.ceil(3 * sigma)))
    k = torch.exp(-0.5 * (torch.arange(-r, r + 1, dtype=x.dtype, device=x.device) / sigma) ** 2)
    k = k / k.sum()
    shape = x.shape
    y = x.reshape(-1, 1, *shape[-2:])
    y = torch.nn.functional.conv2d(y, k.view(1, 1, 1, -1), padding=(0, r))
    y = torch.nn.functional.conv2d(y, k.view(1, 1, -1, 1), padding=(r, 0))
    return y.reshape(shape)


def parts_loss(pred: torch.Tensor, target: torch.Tensor, sigma: float = PARTS_BLUR) -> torch.Tensor:
    """pred: (P, H, W) soft coverage of each named part; target: (P, H, W) in [0, 1]. 0-dim: the mean over
    parts of ``1 - 2 <p, t> / (|p|^2 + |t|^2)`` for the two blurred by ``sigma`` pixels (:func:`blur`):
    0 where they agree, 1 where they do not overlap.

    Parts are small (a window of a building seen whole is a few pixels): unblurred, one pixel of
    misalignment leaves almost no overlap and every wrong count looks as bad as the right one; blurred,
    the overlap falls off smoothly with the offset. (A soft IoU of blurred masks is not 0 for equal
    ones, hence this form.)"""
    p, t = blur(pred, sigma), blur(target, sigma)
    inner = (p * t).sum((-2, -1))
    norm = (p * p + t * t).sum((-2, -1))
    return (1.0 - 2.0 * inner / norm.clamp_min(1e-12)).mean()


def fit_light(normal: torch.Tensor, grey: torch.Tensor, ridge: float = 1e-6
              ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The directional light and ambient that best explain ``grey (N,)`` from unit ``normal (N, 3)`` under
    ``ambient + intensity * max(0, n . l)``, in closed form.

    With ``L = intensity * l`` the unclamped model is linear in ``(ambient, L)``; it is solved by least
    squares (normal equations, a small ridge), then re-solved :data:`LIGHT_ITERATIONS` times with the
    normals facing away from the last ``L`` zeroed (the clamp). Differentiable in ``normal`` and ``grey``
    (the lit set is not). Returns (prediction (N,), ambient 0-dim, L (3,)).
    """
    ones = torch.ones_like(grey)[:, None]
    lit = torch.ones_like(grey, dtype=torch.bool)
    eye = torch.eye(4, dtype=grey.dtype, device=grey.device) * ridge
    for _ in range(LIGHT_ITERATIONS + 1):
        A = torch.cat([ones, normal * lit[:, None]], 1)
        c = torch.linalg.solve(A.T @ A + eye, A.T @ grey)
        lit = ((normal.detach() @ c[1:].detach()) > 0)
    return A @ c, c[0], c[1:]


def shading_loss(normal: torch.Tensor, grey: torch.Tensor, pixels: torch.Tensor
                 ) -> tuple[torch.Tensor, dict]:
    """normal: (H, W, 3) rendered unit normals; grey: (H, W) photo in [0, 1]; pixels: (H, W) bool, the
    object pixels seen in both. Returns (0-dim loss, ``{"ambient", "intensity", "light_dir"}`` of the
    solved light); loss 1 with fewer than 8 pixels."""
    n, g = normal[pixels], grey[pixels]
    if g.numel() < 8:
        return normal.sum() * 0.0 + 1.0, {}
    pred, ambient, L = fit_light(n, g)
    var = ((g - g.mean()) ** 2).mean().clamp_min(1e-8)
    loss = ((pred - g) ** 2).mean() / var
    k = float(torch.linalg.vector_norm(L.detach()))
    light = {"ambient": round(float(ambient.detach()), 5), "intensity": round(k, 5),
             "light_dir": [round(float(v) / max(k, 1e-12), 5) for v in L.detach()]}
    return loss, light
