"""Sinkhorn divergence between masks read as mass on the pixel grid, optionally with a dustbin (partial
transport).

Entropic optimal transport with the squared Euclidean cost, solved in the log domain (Peyré and Cuturi,
"Computational Optimal Transport", 2019, section 4.4) with eps-scaling (the blur annealed from the image's
diagonal down to ``blur``), and debiased into the Sinkhorn divergence S(a, b) = OT(a, b) - OT(a, a) / 2 -
OT(b, b) / 2 of Feydy et al. ("Interpolating between optimal transport and MMD using Sinkhorn divergences",
AISTATS 2019), which is 0 when the masks agree and keeps its minimum there (plain OT_eps would pull the fit
towards a shrunken, blurred copy of the target). On a pixel grid the Gibbs kernel exp(-|x - y|^2 / eps)
factors into one kernel over rows and one over columns, so each log-domain kernel product costs
O(H W (H + W)) instead of O((H W)^2) (the separable, "convolutional" form of Solomon et al., SIGGRAPH 2015).

Gradients: the potentials are computed without a graph and the loss is their dual value <a, f> + <b, g>,
whose gradient in the masses is the potential itself at convergence (the envelope theorem; GeomLoss makes
the same choice), so the backward pass costs one product and no unrolled iterations.

Where two masks do not overlap the soft IoU has no gradient; this loss still moves every boundary pixel's mass
towards the other mask. With ``dustbin`` (a distance d, share of the image), each mask gets one extra bin at
cost d^2 / 2 from every pixel and 0 from the other bin, holding the other mask's total mass: mass with no
partner within d goes to the bin instead of moving (partial transport as balanced transport with dummy
points; Chapel et al., NeurIPS 2020), for a target the generator cannot explain whole (an occluder, a
stand). Masses are taken relative to the target's total, so a fit that is too small or too large pays for
the mass it lacks or adds."""

from __future__ import annotations

import math

import torch

from ipm.losses.masks import LOSSES
from ipm.losses.masks._transport import TransportSettings, axes, normalized, pooled

_D = TransportSettings()
TINY = 1e-30  # mass added before the log: an empty mask stays finite (float32 holds 1e-30)


def _kernel_lse(h: torch.Tensor, cy: torch.Tensor, cx: torch.Tensor) -> torch.Tensor:
    """``log sum_{k,l} exp(h[k, l] - cy[i, k] - cx[j, l])`` for ``h (..., H, W)``, ``cy (H, H)``, ``cx (W, W)``
    (costs already divided by eps): ``(..., H, W)``, one axis at a time."""
    rows = torch.logsumexp(h[..., :, None, :] - cx, dim=-1)              # (..., H_k, W_j)
    return torch.logsumexp(rows[..., None, :, :] - cy[:, :, None], dim=-2)  # (..., H_i, W_j)


def _softmin(lb, g, lbd, gd, cy, cx, cd, eps):
    """One half-step of Sinkhorn: the potential ``(f (..., H, W), f_bin (...))`` of one side from the other
    side's log masses ``lb`` / ``lbd`` and potential ``g`` / ``gd`` (``lbd`` None: no dustbin)."""
    inner = _kernel_lse(lb + g / eps, cy / eps, cx / eps)
    if lbd is None:
        return -eps * inner, None
    to_bin = (lbd + (gd - cd) / eps)[..., None, None]
    f = -eps * torch.logaddexp(inner, to_bin)
    from_pixels = torch.logsumexp((lb + (g - cd) / eps).flatten(-2), dim=-1)
    fd = -eps * torch.logaddexp(from_pixels, lbd + gd / eps)
    return f, fd


def _ot(a, b, ad, bd, cy, cx, cd, schedule, symmetric: bool) -> torch.Tensor:
    """Entropic OT between masses ``a``, ``b (..., H, W)`` (with dustbin masses ``ad``, ``bd (...)`` or None;
    each side's total 1), as the dual value ``<a, f> + <b, g>`` of potentials solved without a graph."""
    with torch.no_grad():
        la, lb = torch.log(a.detach() + TINY), torch.log(b.detach() + TINY)
        lad = None if ad is None else torch.log(ad.detach() + TINY)
        lbd = None if bd is None else torch.log(bd.detach() + TINY)
        f = torch.zeros_like(la)
        g = torch.zeros_like(lb)
        fd = gd = None if ad is None else torch.zeros_like(lad)
        for eps in schedule:
            if symmetric:  # OT(a, a): one potential, averaged updates (Feydy et al., eq. 25)
                f2, fd2 = _softmin(la, f, lad, fd, cy, cx, cd, eps)
                f = 0.5 * (f + f2)
                fd = None if fd is None else 0.5 * (fd + fd2)
                g, gd = f, fd
            else:
                f, fd = _softmin(lb, g, lbd, gd, cy, cx, cd, eps)
                g, gd = _softmin(la, f, lad, fd, cy, cx, cd, eps)
    value = (a * f).sum((-2, -1)) + (b * g).sum((-2, -1))
    if ad is not None:
        value = value + ad * fd + bd * gd
    return value


def eps_schedule(diameter: float, blur: float, iterations: int) -> list[float]:
    """Blurs of the eps-scaling: geometric from ``diameter`` down to ``blur`` over the first half of the
    ``iterations``, then ``blur``; returned as eps = blur^2."""
    n = max(iterations // 2, 1)
    ratio = max(diameter / blur, 1.0)
    return [(blur * ratio ** max(1.0 - k / n, 0.0)) ** 2 for k in range(iterations)]


@LOSSES.register("sinkhorn")
def sinkhorn_loss(pred: torch.Tensor, target: torch.Tensor, *, blur: float = _D.blur,
                  iterations: int = _D.iterations, dustbin: float | None = _D.dustbin, size: int = _D.size
                  ) -> torch.Tensor:
    """Sinkhorn divergence of masks ``pred, target (..., H, W)`` in [0, 1] (pooled to at most ``size`` pixels
    a side), in squared shares of the image's longer side, averaged over leading axes; 0-dim. ``blur``: the
    entropic blur (share of the image); ``dustbin``: see the module; ``iterations``: Sinkhorn iterations."""
    p, t = pooled(pred, size), pooled(target, size)
    h, w = p.shape[-2:]
    y, x = axes(h, w, p)
    cy = (y[:, None] - y[None, :]) ** 2
    cx = (x[:, None] - x[None, :]) ** 2
    schedule = eps_schedule(math.hypot(h, w) / max(h, w), blur, iterations)
    if dustbin is None:
        a, _ = normalized(p)
        b, _ = normalized(t)
        ad = bd = None
        cd = 0.0
    else:  # masses relative to the target's total; each side's bin holds the other side's total
        tt = t.sum((-2, -1))[..., None, None] + 1e-12
        a, b = p / tt, t / tt
        ma, mb = a.sum((-2, -1)), b.sum((-2, -1))
        total = ma + mb
        a, b = a / total[..., None, None], b / total[..., None, None]
        ad, bd = mb / total, ma / total
        cd = 0.5 * dustbin ** 2
    ab = _ot(a, b, ad, bd, cy, cx, cd, schedule, symmetric=False)
    aa = _ot(a, a, ad, ad, cy, cx, cd, schedule, symmetric=True)
    bb = _ot(b, b, bd, bd, cy, cx, cd, schedule, symmetric=True)
    return (ab - 0.5 * aa - 0.5 * bb).mean()
