"""Training a proposal network on its generator's own samples (:mod:`ipm.proposals.data`).

The loss: the Gaussian negative log-likelihood of each normalized continuous parameter under its predicted mean
and standard deviation (the network says how sure it is), the cross-entropy of each discrete head, and half the
cross-entropy of the yaw bins. Adam with a cosine schedule, batches in an order fixed by the seed, augmentations
drawn from a generator seeded by the seed and the step. The data set is drawn once from the seed; checkpoints
hold the weights, Adam's state and the step, so a resumed run ends bit-identical to an uninterrupted one (one
thread: :func:`train` sets it).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from ipm.checkpoint import adam_arrays, cosine_lr, load_adam, same_settings
from ipm.errors import InputError
from ipm.proposals.data import Samples, augment, make_samples
from ipm.proposals.net import NetConfig, ProposalNet, load_weights, save_weights

# the seed of the held-out samples (tests, benchmarks): a stream no training seed draws from
HELDOUT_SEED = 2**31 - 1


@dataclass(frozen=True)
class TrainSettings:
    """samples: training renders drawn once; steps: Adam steps of ``batch`` masks; lr: the first step size."""

    samples: int = 6000
    steps: int = 4000
    batch: int = 64
    lr: float = 2e-3
    seed: int = 0

    def check(self) -> None:
        """``InputError`` naming the first setting out of range."""
        for name, lo, hi in (("samples", 1, 1_000_000), ("steps", 1, 10_000_000), ("batch", 1, 4096),
                             ("seed", 0, HELDOUT_SEED - 1)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
                raise InputError(f"{name}: expected an integer from {lo} to {hi}, got {v!r}")
        if isinstance(self.lr, bool) or not isinstance(self.lr, float | int) or not 0 < self.lr <= 1:
            raise InputError(f"lr: expected a learning rate in (0, 1], got {self.lr!r}")


def loss_terms(out: dict, s: Samples) -> dict[str, torch.Tensor]:
    """The three parts of the training loss of a batch's outputs ``out`` against its answers ``s``."""
    std = out["log_std"].exp()
    nll = (((s.continuous - out["mean"]) / std) ** 2 / 2 + out["log_std"]).mean()
    heads = [F.cross_entropy(logits, s.discrete[:, j]) for j, logits in enumerate(out["discrete"])]
    disc = torch.stack(heads).mean() if heads else nll * 0.0
    return {"continuous": nll, "discrete": disc, "yaw": F.cross_entropy(out["yaw"], s.yaw)}


def train(gen, s: TrainSettings, *, checkpoint: str | Path | None = None, every: int = 200, resume: bool = False,
          data: Samples | None = None, progress: Callable[[str, int, int, float], None] | None = None,
          workers: int = 1) -> ProposalNet:
    """Train a proposal network for ``gen`` from scratch (or from ``checkpoint`` with ``resume``), rewriting the
    checkpoint every ``every`` steps and at the end; ``data`` replaces the samples drawn from the seed (tests), which
    ``workers`` processes draw (the same data for any count).
    ``progress(stage, done, total, loss)`` with stage "data" or "train". Runs on one torch thread (restored
    after), so that a resumed run is bit-identical."""
    s.check()
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        return _train(gen, s, checkpoint, every, resume, data, progress, workers)
    finally:
        torch.set_num_threads(threads)


def _train(gen, s: TrainSettings, checkpoint, every: int, resume: bool, data: Samples | None, progress,
           workers: int) -> ProposalNet:
    torch.manual_seed(s.seed)
    net = ProposalNet(NetConfig.for_generator(gen))
    opt = torch.optim.Adam(net.parameters(), lr=s.lr)
    start = 0
    if resume:
        net, opt, start = _resumed(gen, s, checkpoint)
    if data is None:
        data = make_samples(gen, s.samples, s.seed, workers=workers,
                            progress=None if progress is None else lambda i, n: progress("data", i, n, math.nan))
    order = _Order(len(data), s.seed)
    net.train()
    for step in range(start, s.steps):
        for g in opt.param_groups:
            g["lr"] = cosine_lr(s.lr, step, s.steps)
        idx = torch.as_tensor(order.batch(step, s.batch))
        batch = Samples(augment(data.inputs(idx), torch.Generator().manual_seed(s.seed * 1_000_003 + step)),
                        data.continuous[idx], data.discrete[idx], data.yaw[idx])
        opt.zero_grad()
        terms = loss_terms(net(batch.masks), batch)
        loss = terms["continuous"] + terms["discrete"] + 0.5 * terms["yaw"]
        loss.backward()
        opt.step()
        if checkpoint is not None and ((step + 1) % every == 0 or step + 1 == s.steps):
            save_weights(net, checkpoint, {"step": np.array(step + 1), "settings": np.array(json.dumps(asdict(s))),
                                           **adam_arrays(opt, net)})
        if progress is not None:
            progress("train", step + 1, s.steps, float(loss.detach()))
    net.eval()
    return net


class _Order:
    """The samples' order, one seeded permutation per epoch, drawn as the batches reach it and dropped once passed
    (a long run's whole order would not fit in memory): batch ``step`` is items ``step * batch`` to
    ``(step + 1) * batch`` of the epochs laid end to end."""

    def __init__(self, n: int, seed: int):
        self.n, self.rng, self.epochs, self.drawn = n, np.random.default_rng(seed), {}, 0

    def batch(self, step: int, size: int) -> np.ndarray:
        """The indices of batch ``step`` of ``size`` samples."""
        lo, hi = step * size, (step + 1) * size
        first, last = lo // self.n, (hi - 1) // self.n
        while self.drawn <= last:
            self.epochs[self.drawn] = self.rng.permutation(self.n)
            self.drawn += 1
        for e in [e for e in self.epochs if e < first]:
            del self.epochs[e]
        run = np.concatenate([self.epochs[e] for e in range(first, last + 1)])
        return run[lo - first * self.n: hi - first * self.n]


def _resumed(gen, s: TrainSettings, checkpoint) -> tuple[ProposalNet, torch.optim.Adam, int]:
    """The network, Adam and the step of ``checkpoint``, refused when it was trained with other settings."""
    if checkpoint is None or not Path(checkpoint).is_file():
        raise InputError(f"resume: expected an existing checkpoint, got {checkpoint}")
    net, extra = load_weights(checkpoint, gen)
    if "settings" not in extra or "step" not in extra:
        raise InputError(f"resume: {checkpoint} holds weights without training settings (not a checkpoint)")
    try:
        saved = json.loads(str(extra["settings"]))
        step = extra["step"]
        if not isinstance(saved, dict) or step.shape != () or step.dtype.kind not in "iu":
            raise ValueError
        step = int(step)
    except (ValueError, RecursionError, AttributeError):
        raise InputError(f"resume: {checkpoint}: expected a checkpoint's settings (JSON) and step (an integer), got "
                         "others") from None
    same_settings(saved, asdict(s))
    if not 0 <= step <= s.steps:
        raise InputError(f"resume: {checkpoint}: expected a step from 0 to {s.steps}, got {step}")
    opt = torch.optim.Adam(net.parameters(), lr=s.lr)
    load_adam(opt, net, extra)
    net.train()
    return net, opt, step


def strip_checkpoint(path: str | Path, out: str | Path) -> Path:
    """The weights of checkpoint ``path`` alone (no optimizer state), as the package ships them, written to ``out``
    with the training settings kept (what ``ipm list proposals`` shows)."""
    net, extra = load_weights(path)
    keep = {k: extra[k] for k in ("settings", "step") if k in extra}
    return save_weights(net, out, keep)


@torch.no_grad()
def evaluate(net: ProposalNet, data: Samples) -> dict:
    """On held-out samples: each discrete head's accuracy beside chance (always its most frequent value in
    ``data``), the continuous parameters' mean absolute error (normalized units) beside always guessing their
    mean, and the yaw's accuracy within one bin (15 degrees) beside chance."""
    from ipm.proposals.net import YAW_BINS

    net.eval()
    out = net(data.inputs())
    heads = {}
    for j, (name, _, _) in enumerate(net.config.discrete):
        truth = data.discrete[:, j]
        heads[name] = {"accuracy": float((out["discrete"][j].argmax(1) == truth).double().mean()),
                       "chance": float(torch.bincount(truth).max()) / len(truth)}
    err = (out["mean"] - data.continuous).abs().mean()
    base = (data.continuous - data.continuous.mean(0)).abs().mean()
    off = (out["yaw"].argmax(1) - data.yaw).remainder(YAW_BINS)
    near = (off <= 1) | (off >= YAW_BINS - 1)
    return {"discrete": heads, "continuous_mae": float(err), "continuous_mae_of_the_mean": float(base),
            "yaw_within_one_bin": float(near.double().mean()), "yaw_chance": 3.0 / YAW_BINS,
            "held_out_samples": len(data)}
