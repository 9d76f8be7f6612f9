"""Neural subdivision (Liu, Kim, Chaudhuri, Aigerman, Jacobson, SIGGRAPH 2020), written from the paper.

Every level takes the Loop topology (old vertices, then one vertex per edge: :func:`next_level`) and
predicts the positions with three small MLPs shared by every half-flap, every mesh and every level:

* **initialization** ``I``: a half-flap's local coordinates -> a feature; a vertex's feature is the mean
  over its outgoing half-flaps (once, on the input mesh);
* **vertex** ``V``: local coordinates and the four corners' features -> a displacement of ``a`` (in the
  half-flap's frame) and a new feature; averaged over the vertex's outgoing half-flaps;
* **edge** ``E``: the same input -> the displacement of the edge's new vertex from the edge's midpoint and
  its feature; averaged over the edge's two half-flaps (so the edge's direction does not matter).

The local frame of the half-flap ``a -> b`` (corners ``c`` and ``d`` across it): x along the edge, z the
mean of the two triangles' unit normals made orthogonal to x, y = z x x; coordinates are divided by the
edge's length and displacements multiplied by it. A rigidly moved (or uniformly scaled) mesh thus gives the
moved (scaled) result; only the frames see the absolute placement. That per-edge scaling is our choice (the
paper normalizes its training shapes instead).

Weights are ``.npz`` files of plain arrays (loaded with ``allow_pickle=False``, so a file from a stranger
cannot run code), one per parameter tensor plus ``config`` (a JSON string: feature size, hidden width).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from ipm.checkpoint import load_state
from ipm.errors import InputError
from ipm.subdiv.halfflap import flaps, next_level

EPS = 1e-12


@dataclass(frozen=True)
class NetConfig:
    features: int = 16
    hidden: int = 64


def _mlp(n_in: int, hidden: int, n_out: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(n_in, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(),
                         nn.Linear(hidden, n_out))


def _unit(v: torch.Tensor) -> torch.Tensor:
    return v / torch.sqrt((v * v).sum(-1, keepdim=True) + EPS)


def _mean_by(values: torch.Tensor, index: torch.Tensor, n: int) -> torch.Tensor:
    """Mean of ``values (H, k)`` over rows with the same ``index (H,)``: ``(n, k)``."""
    out = values.new_zeros(n, values.shape[1]).index_add_(0, index, values)
    count = values.new_zeros(n).index_add_(0, index, values.new_ones(values.shape[0]))
    return out / count.clamp(min=1)[:, None]


def half_flap_frames(V: torch.Tensor, abcd: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(R (H, 3, 3)`` with the frame's axes as columns, ``length (H,)`` of the edge, ``local (H, 9)``: b, c
    and d relative to a in the frame, divided by the edge's length)."""
    a, b, c, d = (V[abcd[:, i]] for i in range(4))
    e = b - a
    length = torch.sqrt((e * e).sum(-1) + EPS)
    x = e / length[:, None]
    n = _unit(torch.linalg.cross(b - a, c - a)) + _unit(torch.linalg.cross(a - b, d - b))
    z = _unit(n - (n * x).sum(-1, keepdim=True) * x)
    y = torch.linalg.cross(z, x)
    R = torch.stack([x, y, z], -1)
    rel = torch.stack([b - a, c - a, d - a], 1)                          # (H, 3, 3): rows b, c, d
    local = (rel @ R) / length[:, None, None]
    return R, length, local.reshape(-1, 9)


class NeuralSubdivision(nn.Module):
    """The three half-flap MLPs (see the module docstring). ``forward(verts, faces, levels)`` returns the
    vertices of every level and the faces of the last."""

    def __init__(self, config: NetConfig = NetConfig()):
        super().__init__()
        self.config = config
        k, h = config.features, config.hidden
        self.init_net = _mlp(9, h, k)
        self.vertex_net = _mlp(9 + 4 * k, h, 3 + k)
        self.edge_net = _mlp(9 + 4 * k, h, 3 + k)

    def _level(self, V: torch.Tensor, feats: torch.Tensor, faces: np.ndarray):
        n = V.shape[0]
        fl = flaps(faces, n)
        abcd = torch.as_tensor(fl.abcd, device=V.device)
        R, length, local = half_flap_frames(V, abcd)
        inp = torch.cat([local, feats[abcd].reshape(abcd.shape[0], -1)], 1)
        a = abcd[:, 0]
        edge = torch.as_tensor(fl.edge, device=V.device)
        ends = torch.as_tensor(fl.edges, device=V.device)

        def displaced(out: torch.Tensor) -> torch.Tensor:     # the frame's displacement, in world units
            return (R @ out[:, :3, None]).squeeze(-1) * length[:, None]

        ov, oe = self.vertex_net(inp), self.edge_net(inp)
        V_old = V + _mean_by(displaced(ov), a, n)
        V_new = 0.5 * (V[ends[:, 0]] + V[ends[:, 1]]) + _mean_by(displaced(oe), edge, len(fl.edges))
        f_new = torch.cat([_mean_by(ov[:, 3:], a, n), _mean_by(oe[:, 3:], edge, len(fl.edges))])
        _, new_faces = next_level(faces, n)
        return torch.cat([V_old, V_new]), f_new, new_faces

    def forward(self, verts: torch.Tensor, faces: np.ndarray, levels: int
                ) -> tuple[list[torch.Tensor], np.ndarray]:
        """The meshes after each of ``levels`` steps (in ``verts``' dtype) and the last level's faces."""
        V = verts.to(next(self.parameters()).dtype)
        fl = flaps(faces, V.shape[0])
        abcd = torch.as_tensor(fl.abcd, device=V.device)
        _, _, local = half_flap_frames(V, abcd)
        feats = _mean_by(self.init_net(local), abcd[:, 0], V.shape[0])
        out = []
        F = np.asarray(faces, dtype=np.int64)
        for _ in range(levels):
            V, feats, F = self._level(V, feats, F)
            out.append(V.to(verts.dtype))
        return out, F


# -- weights files ---------------------------------------------------------------------------------

def save_weights(net: NeuralSubdivision, path: str | Path, extra: dict | None = None) -> Path:
    """Write ``net``'s parameters (and ``extra`` arrays, e.g. a checkpoint's optimizer state) as ``.npz``,
    atomically."""
    import io

    from ipm.files import write_bytes

    arrays = {f"net.{k}": v.detach().cpu().numpy() for k, v in net.state_dict().items()}
    cfg = {"features": net.config.features, "hidden": net.config.hidden}
    arrays["config"] = np.array(json.dumps(cfg))
    arrays.update(extra or {})
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return write_bytes(path, buf.getvalue())


# what a weights file is, for messages about files that are not one
WEIGHTS_FILE = ("an .npz of plain arrays (one float array per network parameter and a JSON config entry, as "
                "written by ipm train-subdivision)")
# the most bytes a weights file's arrays may declare: the largest network (features 1024, hidden 4096)
# with a checkpoint's Adam state is about 1 GB; more is refused from the arrays' headers before reading
MAX_WEIGHTS_BYTES = 2 * 2**30


def load_weights(path: str | Path) -> tuple[NeuralSubdivision, dict]:
    """The network in a weights file, and its other arrays; :class:`InputError` for a file that is not
    one (unreadable, a single ``.npy`` array, pickled objects, arrays declaring more than
    :data:`MAX_WEIGHTS_BYTES`, a missing or malformed config, a missing or misshapen parameter)."""
    from ipm.files import read_npz

    path = Path(path)
    arrays = read_npz(path, "weights file", WEIGHTS_FILE, MAX_WEIGHTS_BYTES)
    try:
        text = str(arrays.pop("config"))
        if len(text) > 1000:
            raise ValueError
        cfg = json.loads(text)
        if any(isinstance(cfg[k], bool) or not isinstance(cfg[k], int) for k in ("features", "hidden")):
            raise ValueError
        config = NetConfig(cfg["features"], cfg["hidden"])
        if not (1 <= config.features <= 1024 and 1 <= config.hidden <= 4096):
            raise ValueError
    except (KeyError, ValueError, TypeError, RecursionError):
        raise InputError(f"weights file {path}: expected a config entry (JSON) with features in 1..1024 and "
                         "hidden in 1..4096") from None
    net = NeuralSubdivision(config)
    load_state(net, arrays, f"weights file {path}")
    return net, {k: v for k, v in arrays.items() if not k.startswith("net.")}

