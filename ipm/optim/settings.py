"""Everything a fit can be told: :class:`FitSettings`, one documented object, checked in one place."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from ipm import losses as L
from ipm.errors import InputError
from ipm.optim import discrete as D
from ipm.optim import gradient as G
from ipm.optim.strategies import STRATEGIES
from ipm.params import dataclass_from

# Default Adam steps in normalized parameter space (generators may set ``mask_lr``; ``--lr`` overrides)
MASK_LR = 0.02
MESH_LR = 0.02
# blur of the final refinement of mesh generators, relative to the search's: 0.03 px^2 by default,
# where the soft silhouette's 0.5 level lies within about 0.2 px of the hard one (measured on the
# teacup-to-mug test: final exact IoU 0.96 with 0.15, 0.98 with 0.03)
POLISH_SIGMA_FACTOR = 0.03
CAMERA_MODES = ("known", "fit")


@dataclass
class FitSettings:
    """Everything a fit can be told. Defaults are what ``ipm fit`` uses."""

    budget: int = 1500
    seed: int = 0
    discrete: str = "memetic"        # a search strategy: ipm.optim.strategies.STRATEGIES
    camera: str = "known"            # known | fit
    loss: str = "iou"                # a mask loss of ipm.losses.LOSSES; chamfer for mesh targets is automatic
    local: str = "adam"              # adam | mma | lbfgs
    lr: float | None = None          # Adam step in normalized space; None: the generator's (see fit_lr)
    sigma: float = 0.0               # soft rasterizer blur; 0 = the renderer's default for the image size
    preset: str | None = None        # start from this preset (default: the generator's defaults)
    free: list[str] | None = None    # continuous parameters to fit (default: all)
    fix: dict = field(default_factory=dict)   # parameters held at given values
    ranges: dict = field(default_factory=dict)  # discrete parameter -> [lo, hi]: search only these values
    pose: bool = True
    prior_weight: float = 0.0        # pull towards the starting preset in normalized space
    polish: float = 0.15             # share of the budget kept for the final gradient refinement
    coarse_to_fine: bool = True      # silhouettes: hold the generator's detail parameters during the search
    lod: Any = None
    resolution: int = 128            # SDF generators: meshing of the result
    ties: bool = True                # discrete values the input cannot tell apart go to the preset's (break_ties)
    memetic: D.MemeticSettings = field(default_factory=D.MemeticSettings)
    nlopt: D.NloptSettings = field(default_factory=D.NloptSettings)

    def __post_init__(self):
        # nested settings may come as dicts (JSON run files, experiment TOML, the Python API)
        for name, cls in (("memetic", D.MemeticSettings), ("nlopt", D.NloptSettings)):
            v = getattr(self, name)
            if isinstance(v, dict):
                setattr(self, name, dataclass_from(cls, v, f"{name} settings", "setting(s)"))

    def check(self) -> None:
        """Raise :class:`~ipm.errors.InputError` ("expected ..., got ...") for a field out of range."""
        _whole(self.budget, "budget", 1, "at least 1 evaluation")
        _whole(self.seed, "seed", 0, "a seed >= 0")
        _one_of(self.discrete, "discrete search", STRATEGIES.names())
        _one_of(self.camera, "camera", CAMERA_MODES)
        _one_of(self.loss, "loss", L.LOSSES.names())
        _one_of(self.local, "local optimizer", G.LOCAL)
        if self.lr is not None:
            _number(self.lr, "lr", "a learning rate in (0, 1]", lambda v: 0 < v <= 1)
        _number(self.sigma, "sigma", "a blur >= 0 (0: the renderer's default)", lambda v: v >= 0)
        _number(self.prior_weight, "prior weight", "a weight >= 0", lambda v: v >= 0)
        _number(self.polish, "polish", "a share of the budget in [0, 1]", lambda v: 0 <= v <= 1)
        _whole(self.resolution, "resolution", 8, "a meshing resolution >= 8")
        for name in ("pose", "coarse_to_fine", "ties"):
            if not isinstance(getattr(self, name), bool):
                raise InputError(f"{name}: expected true or false, got {getattr(self, name)!r}")
        if self.free is not None and not (isinstance(self.free, (list, tuple)) and
                                          all(isinstance(n, str) for n in self.free)):
            raise InputError(f"free: expected a list of parameter names, got {self.free!r}")
        for name in ("fix", "ranges"):
            if not isinstance(getattr(self, name), dict):
                raise InputError(f"{name}: expected a dict of parameter names, got {getattr(self, name)!r}")
        m = self.memetic
        _whole(m.population, "memetic population", 2, "at least 2 individuals")
        _whole(m.tournament, "memetic tournament", 1, f"a size in [1, {m.population}] (the population)")
        if m.tournament > m.population:
            raise InputError(f"memetic tournament: expected a size in [1, {m.population}] (the population), "
                             f"got {m.tournament}")
        _number(m.p_mutation, "memetic p_mutation", "a probability in [0, 1]", lambda v: 0 <= v <= 1)
        _number(m.sigma_mutation, "memetic sigma_mutation", "a spread >= 0", lambda v: v >= 0)
        _whole(m.refine_steps, "memetic refine_steps", 1, "at least 1 step")
        if m.lr is not None:
            _number(m.lr, "memetic lr", "a learning rate in (0, 1]", lambda v: 0 < v <= 1)
        _whole(m.stall_generations, "memetic stall_generations", 1, "at least 1 generation")
        _number(m.min_diversity, "memetic min_diversity", "a diversity >= 0", lambda v: v >= 0)
        _one_of(self.nlopt.algorithm, "nlopt algorithm", D.NLOPT_GLOBAL)
        _whole(self.nlopt.refine_steps, "nlopt refine_steps", 1, "at least 1 step")
        _whole(self.nlopt.population, "nlopt population", 0, "a population >= 0 (0: nlopt's default)")

    def to_json(self) -> dict:
        return asdict(self)


def _whole(value, name: str, lo: int, expected: str) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < lo:
        raise InputError(f"{name}: expected {expected}, got {value!r}")


def _number(value, name: str, expected: str, ok: Callable[[float], bool]) -> None:
    if (isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating))
            or not math.isfinite(value) or not ok(value)):
        raise InputError(f"{name}: expected {expected}, got {value!r}")


def _one_of(value, name: str, known) -> None:
    if value not in known:
        raise InputError(f"{name}: expected one of {', '.join(known)}, got {value!r}")
