"""Training neural subdivision on procedural pairs (:mod:`ipm.subdiv.pairs`): the paper's loss, the
squared distance of every level's vertices to their exact positions (summed over levels), divided by
the coarse mesh's mean squared edge length so that every pair weighs alike; Adam with a cosine
schedule; one pair per step, in an order fixed by the seed. Checkpoints hold the weights, Adam's state
and the step, so a resumed run continues exactly where it stopped."""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from ipm.checkpoint import cosine_lr, load_adam, same_settings
from ipm.errors import InputError
from ipm.subdiv.neural import NetConfig, NeuralSubdivision, load_weights, save_weights
from ipm.subdiv.pairs import Pair, dish_pair, random_dishes


@dataclass(frozen=True)
class TrainSettings:
    pairs: int = 32          # training dishes
    steps: int = 1500
    lr: float = 2e-3
    levels: int = 2
    seed: int = 0
    features: int = 16
    hidden: int = 64
    procedural: bool = True   # dish pairs (ipm.subdiv.pairs)
    real: tuple[str, ...] = ()  # closed mesh files, each decimated to REAL_VERTICES (ipm.subdiv.mapped)
    map: str = "closest"      # how a real pair's levels are mapped back (ipm.subdiv.mapped.METHODS)

    def check(self) -> None:
        """Raises ``InputError`` naming the first setting out of range, an unknown ``map``, or no pairs at all."""
        from ipm.subdiv.mapped import METHODS

        for name, lo, hi in (("pairs", 1, 100_000), ("steps", 1, 10_000_000), ("levels", 1, 3),
                             ("features", 1, 1024), ("hidden", 1, 4096)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
                raise InputError(f"{name}: expected an integer from {lo} to {hi}, got {v!r}")
        if not (isinstance(self.lr, float | int) and 0 < self.lr <= 1):
            raise InputError(f"lr: expected a learning rate in (0, 1], got {self.lr!r}")
        if self.map not in METHODS:
            raise InputError(f"map: expected one of {', '.join(METHODS)}, got {self.map!r}")
        if not self.procedural and not self.real:
            raise InputError("training pairs: expected procedural pairs, real meshes or both, got neither")


# each real mesh gives one pair per decimation target
REAL_VERTICES = (300, 400, 500)


def make_pairs(n: int, levels: int, seed: int) -> list[Pair]:
    """``n`` procedural pairs (float32) from dishes presets moved by the seed's random numbers."""
    return [dish_pair(v, levels, torch.float32) for v in random_dishes(n, np.random.default_rng(seed))]


def _read(path: str) -> tuple[np.ndarray, np.ndarray]:
    """A mesh file's vertices and faces as stored (trimesh; no up axis or normalization: the network and
    its loss do not depend on the placement, the orientation or the scale of a mesh)."""
    import trimesh

    p = Path(path)
    if not p.is_file():
        raise InputError(f"real mesh: expected an existing mesh file, got {path}")
    try:
        # materials are not needed (and a missing texture would be logged with a traceback)
        kwargs = {"skip_materials": True} if p.suffix.lower() in (".obj", ".ply") else {}
        m = trimesh.load_mesh(str(p), process=False, **kwargs)
        V = np.asarray(m.vertices, dtype=np.float64)
        F = np.asarray(m.faces, dtype=np.int64).reshape(-1, 3)
    except MemoryError:
        raise
    except Exception as e:  # trimesh raises many kinds of errors for broken files (and, for an ASCII STL of
        # garbage, an ImportError: it reaches for charset_normalizer to guess the encoding)
        why = "" if isinstance(e, ImportError) else f" ({type(e).__name__})"
        raise InputError(f"real mesh {path}: expected a readable mesh (.ply, .obj, .stl, .glb, .off), got a file "
                         f"that is not a valid {p.suffix.lower() or 'mesh'} file{why}") from None
    if len(F) == 0 or not np.isfinite(V).all():
        raise InputError(f"real mesh {path}: expected triangles with finite vertices")
    return V, F


def real_pairs(paths: tuple[str, ...], levels: int, method: str) -> list[Pair]:
    """Pairs from closed mesh files, one per decimation target of :data:`REAL_VERTICES`
    (:func:`ipm.subdiv.mapped.mapped_pair`)."""
    from ipm.subdiv import clean
    from ipm.subdiv.mapped import mapped_pair

    out = []
    for path in paths:
        V, F = clean(*_read(path))
        for n in REAL_VERTICES:
            try:
                out.append(mapped_pair(V, F, n, levels, method))
            except InputError as e:
                raise InputError(f"real mesh {path}: {e}") from None
    return out


def training_pairs(s: TrainSettings) -> list[Pair]:
    """The settings' procedural dish pairs (if ``procedural``) followed by the real meshes' pairs."""
    return (make_pairs(s.pairs, s.levels, s.seed) if s.procedural else []) + real_pairs(s.real, s.levels, s.map)


def pair_loss(net: NeuralSubdivision, pair: Pair) -> torch.Tensor:
    """Mean squared vertex error summed over the levels, divided by the coarse mesh's mean squared edge
    length (so the loss does not depend on the mesh's scale)."""
    out, _ = net(pair.verts, pair.faces, len(pair.levels))
    e = pair.verts[pair.faces[:, [0, 1]]]
    scale = ((e[:, 0] - e[:, 1]) ** 2).sum(-1).mean()
    return sum(((o - g) ** 2).sum(-1).mean() for o, g in zip(out, pair.levels)) / scale


def train(s: TrainSettings, *, checkpoint: str | Path | None = None, every: int = 100, resume: bool = False,
          progress: Callable[[int, float], None] | None = None) -> NeuralSubdivision:
    """Train from scratch (or from ``checkpoint`` with ``resume``); the checkpoint is rewritten every
    ``every`` steps and at the end. Returns the network (float32).

    Runs on one torch thread (restored after): with two, the scatter-adds of the half-flaps' pooling
    sum in an order that varies from run to run, and a resumed run drifted from an uninterrupted one in
    the last bits (tests/test_subdiv_neural.py); the network is small enough that threads gain little."""
    s.check()
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        return _train(s, checkpoint, every, resume, progress)
    finally:
        torch.set_num_threads(threads)


def _train(s: TrainSettings, checkpoint, every: int, resume: bool, progress) -> NeuralSubdivision:
    torch.manual_seed(s.seed)
    net = NeuralSubdivision(NetConfig(s.features, s.hidden))
    opt = torch.optim.Adam(net.parameters(), lr=s.lr)
    start = 0
    if resume:
        if checkpoint is None or not Path(checkpoint).is_file():
            raise InputError(f"resume: expected an existing checkpoint, got {checkpoint}")
        net, extra = load_weights(checkpoint)
        saved = json_settings(extra)
        now = json.loads(json.dumps(asdict(s)))   # tuples as lists, as the checkpoint holds them
        same_settings(saved, now)
        opt = torch.optim.Adam(net.parameters(), lr=s.lr)
        load_adam(opt, net, extra)
        start = int(extra["step"])
    pairs = training_pairs(s)
    order = np.random.default_rng(s.seed).permutation(np.arange(s.steps) % len(pairs))
    for step in range(start, s.steps):
        for g in opt.param_groups:
            g["lr"] = cosine_lr(s.lr, step, s.steps)
        opt.zero_grad()
        loss = pair_loss(net, pairs[order[step]])
        loss.backward()
        opt.step()
        if progress is not None:
            progress(step + 1, float(loss.detach()))
        if checkpoint is not None and ((step + 1) % every == 0 or step + 1 == s.steps):
            save_checkpoint(net, opt, s, step + 1, checkpoint)
    return net


def json_settings(extra: dict) -> dict:
    """The training settings stored in a checkpoint's extra arrays; ``InputError`` when there are none."""
    raw = extra.get("settings")
    if raw is None:
        raise InputError("resume: the file holds weights without training settings (not a checkpoint)")
    return json.loads(str(raw))


def save_checkpoint(net: NeuralSubdivision, opt: torch.optim.Adam, s: TrainSettings, step: int,
                    path: str | Path) -> Path:
    """Write the weights, ``step``, the settings as JSON and Adam's moments to ``path`` (``.npz``, atomically)."""
    from ipm.checkpoint import adam_arrays

    extra: dict = {"step": np.array(step), "settings": np.array(json.dumps(asdict(s))), **adam_arrays(opt, net)}
    return save_weights(net, path, extra)


def evaluate(net: NeuralSubdivision, pairs: list[Pair]) -> dict[str, float]:
    """Mean distance of the last level's vertices to their exact positions, for the network, midpoint and
    Loop subdivision, over ``pairs``."""
    from ipm.subdiv import subdivide

    out: dict[str, list[float]] = {"neural": [], "midpoint": [], "loop": []}
    with torch.no_grad():
        for p in pairs:
            L = len(p.levels)
            pred = {"neural": net(p.verts, p.faces, L)[0][-1],
                    "midpoint": subdivide(p.verts, p.faces, "midpoint", L)[0],
                    "loop": subdivide(p.verts, p.faces, "loop", L)[0]}
            for k, v in pred.items():
                out[k].append(float((v - p.levels[-1]).norm(dim=1).mean()))
    return {k: float(np.mean(v)) for k, v in out.items()}
