"""First guesses from a trained network: the most probable combinations of the discrete values, each with the
continuous values the network expects and the yaw it finds most likely, turned into the world by the camera."""

from __future__ import annotations

import copy
import heapq
import itertools
from dataclasses import dataclass, field

import torch

from ipm.proposals.encode import TRAIN_AZIMUTH, camera_azimuth, encode_mask
from ipm.proposals.net import YAW_BINS, ProposalNet
from ipm.types import Camera

MAX_PROPOSALS = 4
MASS = 0.9   # proposals are taken, most probable first, until they hold this share of the probability


@dataclass(frozen=True)
class Proposal:
    """A guess: the generator's ``values``, its probability under the discrete heads, the world yaw (degrees;
    the fit's pose convention) and the continuous parameters' predicted standard deviations (normalized units)."""

    values: dict
    probability: float
    yaw_deg: float
    std: dict = field(default_factory=dict)


class Proposer:
    """A trained :class:`~ipm.proposals.net.ProposalNet` for generator ``gen``.

    Inference runs in float64 and its outputs are rounded to float32: torch picks its CPU kernels at run time (AVX2,
    AVX-512, none), and in float32 their last bits differ (the shipped networks' outputs for the same masks hashed
    three ways under ``ATEN_CPU_CAPABILITY`` default, avx2 and this machine's avx512); a fit that starts from the
    proposals would then start elsewhere on another machine. Float64's differences lie some nine digits below
    float32's rounding, so the rounded outputs agree but for a value within them of a rounding boundary."""

    def __init__(self, net: ProposalNet, gen, source: str = ""):
        self.net, self.gen, self.source = net, gen, source
        self._net64 = copy.deepcopy(net).double()

    @torch.no_grad()
    def heads(self, mask: torch.Tensor) -> dict:
        """The network's outputs for one mask ``(H, W)`` (batch of one, float32, on the CPU; see the class
        docstring)."""
        x = encode_mask(mask.detach().cpu(), self.net.config.size, dtype=torch.float64)[None]
        out = self._net64(x)
        return {k: [t.float() for t in v] if isinstance(v, list) else v.float() for k, v in out.items()}

    def propose(self, mask: torch.Tensor, camera: Camera, k: int = MAX_PROPOSALS) -> list[Proposal]:
        """At most ``k`` proposals for the object that ``mask (H, W)`` shows in ``camera``, most probable first,
        taken until they hold :data:`MASS` of the discrete heads' probability."""
        return self.propose_views([mask], [camera], k)

    def propose_views(self, masks, cameras, k: int = MAX_PROPOSALS) -> list[Proposal]:
        """:meth:`propose` for an object seen in several views (``masks (K, H, W)`` in ``cameras``): the network
        reads each view on its own and the views' outputs are taken as independent evidence of the same object
        (:func:`fuse`: a product of the heads' distributions, the yaws turned into the world first); one view is
        :meth:`propose`'s answer as it was."""
        if len(masks) != len(cameras) or len(cameras) == 0:
            raise ValueError(f"propose_views: expected one camera per mask, got {len(masks)} masks and "
                             f"{len(cameras)} cameras")
        outs = [(self.heads(m), cam) for m, cam in zip(masks, cameras)]
        mean, std, probs, yaw = summary(*outs[0]) if len(outs) == 1 else fuse(outs)
        cont = [p for p in self.gen.spec.params if p.continuous]
        base = {p.name: float(p.lo + float(mean[i]) * (p.hi - p.lo)) for i, p in enumerate(cont)}
        stds = {p.name: float(std[i]) for i, p in enumerate(cont)}
        yaw = (yaw + 180.0) % 360.0 - 180.0
        names = [(name, lo) for name, lo, _ in self.net.config.discrete]
        picked, mass = [], 0.0
        for p, combo in _most_probable(probs, k):
            values = dict(base)
            values.update({name: lo + j for (name, lo), j in zip(names, combo)})
            picked.append(Proposal(values, p, yaw, stds))
            mass += p
            if mass >= MASS:
                break
        return picked


View = tuple[torch.Tensor, torch.Tensor, list[torch.Tensor], float]


def summary(out: dict, camera: Camera) -> View:
    """One view's network outputs ``out`` (:meth:`Proposer.heads`) as (continuous means (normalized), their standard
    deviations, each discrete head's probabilities, the world yaw in degrees (any turn)), all float64."""
    mean, std = out["mean"][0].double(), out["log_std"][0].double().exp()
    probs = [_same_bits(torch.softmax(lg[0].double(), 0)) for lg in out["discrete"]]
    yaw_rel = peak_yaw(torch.softmax(out["yaw"][0].double(), 0))
    return mean, std, probs, yaw_rel + camera_azimuth(camera) - TRAIN_AZIMUTH


def fuse(outs: list[tuple[dict, Camera]]) -> View:
    """Several views' :func:`summary` of one object as one: each discrete head's probabilities multiplied over the
    views (and normalized; a handle one view hides and another shows is kept at the showing view's odds), the
    continuous means weighted by their precisions (standard deviation ``1 / sqrt(sum 1 / std^2)``), and the yaw at the
    peak of the product of the views' yaw distributions, each turned from its camera into the world first (a body
    that looks alike turned half way round in one view is told apart by another's)."""
    views = [summary(out, cam) for out, cam in outs]
    prec = torch.stack([1.0 / v[1] ** 2 for v in views])
    mean = (torch.stack([v[0] for v in views]) * prec).sum(0) / prec.sum(0)
    std = prec.sum(0).rsqrt()
    heads = range(len(views[0][2]))
    probs = [_same_bits(torch.softmax(sum(torch.log(v[2][h].clamp_min(1e-300)) for v in views), 0)) for h in heads]
    yaw_p = torch.softmax(sum(torch.log(world_bins(out, cam).clamp_min(1e-300)) for out, cam in outs), 0)
    return mean, std, probs, peak_yaw(yaw_p)


def _same_bits(p: torch.Tensor) -> torch.Tensor:
    """Probabilities ``p`` (float64) rounded to float32 and back: ``exp`` and ``log`` in float64 differ in their last
    bits between torch's CPU kernels (AVX-512, AVX2, none: the discrete heads' probabilities of the same outputs did),
    which would move where :data:`MASS` cuts the proposals and the ranking of near ties from machine to machine."""
    return p.float().double()


def world_bins(out: dict, camera: Camera) -> torch.Tensor:
    """One view's yaw probabilities ``(YAW_BINS,)`` on the world's bins (bin ``j`` at ``j * 360 / YAW_BINS``
    degrees): the network's, relative to the camera, turned by the camera's azimuth (linearly between bins)."""
    p = torch.softmax(out["yaw"][0].double(), 0)
    width = 360.0 / YAW_BINS
    f = (torch.arange(YAW_BINS, dtype=torch.float64) - (camera_azimuth(camera) - TRAIN_AZIMUTH) / width) % YAW_BINS
    lo = f.floor().long()
    t = f - lo
    return (1.0 - t) * p[lo % YAW_BINS] + t * p[(lo + 1) % YAW_BINS]


def peak_yaw(p: torch.Tensor) -> float:
    """The yaw (degrees) of bin probabilities ``p (YAW_BINS,)`` between their bins: the circular mean of the most
    probable bin and its two neighbours, weighted by their probabilities (a yaw half way between two bins splits
    its probability between them). Only the peak's neighbourhood counts: a shape that looks the same turned half
    way round puts a second peak there, which an overall mean would average away."""
    k = int(torch.argmax(p))
    bins = torch.tensor([k - 1, k, k + 1], dtype=torch.float64)
    w = p[bins.long() % YAW_BINS]
    a = torch.deg2rad(bins * (360.0 / YAW_BINS))
    return float(torch.rad2deg(torch.atan2((w * a.sin()).sum(), (w * a.cos()).sum()))) % 360.0


def _most_probable(probs: list[torch.Tensor], k: int):
    """The ``k`` most probable combinations ``(probability, indices)`` of independent heads, best first (a best-first
    walk of the product, each head's values sorted)."""
    if not probs:
        yield 1.0, ()
        return
    order = [torch.argsort(p, descending=True).tolist() for p in probs]
    sorted_p = [[float(p[j]) for j in o] for p, o in zip(probs, order)]

    def prob(ranks):
        return float(torch.tensor([sp[r] for sp, r in zip(sorted_p, ranks)], dtype=torch.float64).prod())

    start = (0,) * len(probs)
    heap, seen = [(-prob(start), start)], {start}
    for _ in itertools.repeat(None, k):
        if not heap:
            return
        neg, ranks = heapq.heappop(heap)
        yield -neg, tuple(o[r] for o, r in zip(order, ranks))
        for h in range(len(ranks)):
            nxt = ranks[:h] + (ranks[h] + 1,) + ranks[h + 1:]
            if nxt[h] < len(order[h]) and nxt not in seen:
                seen.add(nxt)
                heapq.heappush(heap, (-prob(nxt), nxt))
