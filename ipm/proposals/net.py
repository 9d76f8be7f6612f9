"""The proposal network: a small convolutional encoder of one cropped mask (:mod:`ipm.proposals.encode`) and
one head per kind of answer: the generator's continuous parameters (normalized to [0, 1], each a mean and a log
standard deviation), each discrete parameter (a distribution over its values) and the object's yaw relative to
the camera (a distribution over :data:`YAW_BINS` bins; symmetric shapes spread it).

Weights files are ``.npz`` of plain arrays (``net.*`` per parameter and a JSON ``config`` naming the generator,
its continuous parameters and its discrete parameters with their ranges), read by :func:`load_weights` with the
checks of :func:`ipm.files.read_npz`; a file trained for other parameters (names, order, discrete ranges) is
refused with one line. Weights of one generator serve another with the same parameters.
"""

from __future__ import annotations

import io
import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from ipm.checkpoint import load_state
from ipm.errors import InputError

YAW_BINS = 24
WEIGHTS_FILE = ("an .npz of plain arrays (one float array per network parameter and a JSON config entry, as "
                "written by ipm train-proposals)")
MAX_WEIGHTS_BYTES = 2**30


@dataclass(frozen=True)
class NetConfig:
    """The network's shape and what it was trained for: the generator's name, its continuous parameters'
    names, its discrete parameters as ``[name, lo, hi]``, the input size and the encoder's widths."""

    generator: str
    continuous: tuple[str, ...]
    discrete: tuple[tuple[str, int, int], ...]
    size: int = 64
    channels: tuple[int, ...] = (16, 32, 64, 128)
    hidden: int = 256

    def to_json(self) -> str:
        """The config as the JSON string a weights file stores."""
        return json.dumps(asdict(self))

    @staticmethod
    def from_json(text: str) -> NetConfig:
        """The config of a weights file; ``ValueError`` (or ``KeyError``, ``TypeError``) when malformed."""
        d = json.loads(text)
        cfg = NetConfig(str(d["generator"]), tuple(str(n) for n in d["continuous"]),
                        tuple((str(n), int(lo), int(hi)) for n, lo, hi in d["discrete"]), int(d["size"]),
                        tuple(int(c) for c in d["channels"]), int(d["hidden"]))
        if not (8 <= cfg.size <= 256 and 1 <= len(cfg.channels) <= 6 and all(1 <= c <= 512 for c in cfg.channels)
                and 1 <= cfg.hidden <= 4096 and all(hi >= lo for _, lo, hi in cfg.discrete)
                and cfg.size % 2 ** len(cfg.channels) == 0):
            raise ValueError("out of range")
        return cfg

    @staticmethod
    def for_generator(gen, **kw) -> NetConfig:
        """The config of a network for generator ``gen`` (its parameter spec)."""
        return NetConfig(gen.name, tuple(p.name for p in gen.spec.continuous),
                         tuple((p.name, int(p.lo), int(p.hi)) for p in gen.spec.discrete), **kw)


class ProposalNet(nn.Module):
    """Mask ``(B, 1, S, S)`` -> ``{"mean": (B, n) in [0, 1], "log_std": (B, n), "discrete": [(B, values)] logits
    per discrete parameter, "yaw": (B, YAW_BINS) logits}``."""

    def __init__(self, config: NetConfig):
        super().__init__()
        self.config = config
        layers: list[nn.Module] = []
        c_in = 1
        for c in config.channels:
            layers += [nn.Conv2d(c_in, c, 3, stride=2, padding=1), nn.GroupNorm(min(8, c), c), nn.SiLU()]
            c_in = c
        self.encoder = nn.Sequential(*layers)
        side = config.size // 2 ** len(config.channels)
        self.trunk = nn.Sequential(nn.Flatten(), nn.Linear(c_in * side * side, config.hidden), nn.SiLU(),
                                   nn.Linear(config.hidden, config.hidden), nn.SiLU())
        n = len(config.continuous)
        self.continuous = nn.Linear(config.hidden, 2 * n)
        self.discrete = nn.ModuleList(nn.Linear(config.hidden, hi - lo + 1) for _, lo, hi in config.discrete)
        self.yaw = nn.Linear(config.hidden, YAW_BINS)

    def forward(self, x: torch.Tensor) -> dict:
        """The heads' outputs for a batch of encoded masks (see the class docstring)."""
        h = self.trunk(self.encoder(x))
        n = len(self.config.continuous)
        c = self.continuous(h)
        return {"mean": torch.sigmoid(c[:, :n]), "log_std": c[:, n:].clamp(-7.0, 2.0),
                "discrete": [head(h) for head in self.discrete], "yaw": self.yaw(h)}


def save_weights(net: ProposalNet, path: str | Path, extra: dict | None = None) -> Path:
    """Write ``net``'s parameters, its config and ``extra`` arrays (a checkpoint's state) as ``.npz``, atomically."""
    from ipm.files import write_bytes

    arrays = {f"net.{k}": v.detach().cpu().numpy() for k, v in net.state_dict().items()}
    arrays["config"] = np.array(net.config.to_json())
    arrays.update(extra or {})
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return write_bytes(path, buf.getvalue())


def load_weights(path: str | Path, gen=None) -> tuple[ProposalNet, dict]:
    """The network in a weights file and its other arrays. ``InputError`` for a file that is not one, and, with
    ``gen``, for weights trained for another generator or other parameters than ``gen``'s."""
    from ipm.files import read_npz

    path = Path(path)
    arrays = read_npz(path, "proposal weights", WEIGHTS_FILE, MAX_WEIGHTS_BYTES)
    try:
        config = NetConfig.from_json(str(arrays.pop("config")))
    except (KeyError, ValueError, TypeError, RecursionError, OverflowError):
        raise InputError(f"proposal weights {path}: expected a config entry (JSON: generator, continuous, discrete, "
                         "size, channels, hidden)") from None
    if gen is not None:
        want = NetConfig.for_generator(gen)
        if (config.continuous, config.discrete) != (want.continuous, want.discrete):
            raise InputError(f"proposal weights {path}: trained for {config.generator}'s parameters "
                             f"({len(config.continuous)} continuous, {len(config.discrete)} discrete), which do not "
                             f"match {gen.name}'s ({len(want.continuous)}, {len(want.discrete)}); expected weights "
                             f"made by ipm train-proposals {gen.name}")
    net = ProposalNet(config)
    load_state(net, arrays, f"proposal weights {path}")
    net.eval()
    return net, {k: v for k, v in arrays.items() if not k.startswith("net.")}
