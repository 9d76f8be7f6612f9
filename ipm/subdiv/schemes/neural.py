"""Neural subdivision (:mod:`ipm.subdiv.neural`) as a scheme: closed, consistently oriented meshes only
(half-flaps need a twin for every edge). The weights shipped in the package
(``ipm/subdiv/weights/neural_dishes.npz``, rebuilt by ``make weights``) were trained on procedural dish
pairs; :meth:`NeuralScheme.with_weights` takes another file."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from ipm.subdiv import SCHEMES
from ipm.subdiv.linear import check_levels, check_mesh

WEIGHTS = Path(__file__).resolve().parents[1] / "weights" / "neural_dishes.npz"


@dataclass
class NeuralScheme:
    """Neural subdivision (Liu et al. 2020): half-flap MLPs, the weights shipped in ipm/subdiv/weights."""

    name: str = "neural"
    boundary: bool = False
    weights: Path = WEIGHTS
    _net: object = field(default=None, repr=False)
    _checked: set = field(default_factory=set, repr=False)

    def with_weights(self, path: str | Path) -> NeuralScheme:
        """The scheme with the network of another weights file (checked when loaded)."""
        return NeuralScheme(weights=Path(path))

    def network(self):
        """The network of the weights file, loaded on first use (``InputError`` if the file is not a weights file)."""
        if self._net is None:
            from ipm.subdiv.neural import load_weights

            self._net = load_weights(self.weights)[0]
        return self._net

    def subdivide(self, verts: torch.Tensor, faces: np.ndarray, levels: int) -> tuple[torch.Tensor, np.ndarray]:
        """The network's mesh after ``levels`` steps; a mesh's faces are checked the first time only."""
        check_levels(levels)
        F = np.ascontiguousarray(faces)
        key = (verts.shape[0], levels, F.shape, F.dtype.str, F.tobytes())
        if key not in self._checked:  # a fit renders the same faces again: check them once
            F = check_mesh(F, verts.shape[0], self, levels)
            if len(self._checked) >= 16:
                self._checked.clear()
            self._checked.add(key)
        F = F.astype(np.int64, copy=False)
        net = self.network()
        out, NF = net.to(verts.device)(verts, F, levels)
        return out[-1], NF


SCHEMES.add("neural", NeuralScheme())
