"""Discrete (and global) search under one evaluation budget.

Every strategy receives a :class:`Space` (the normalized continuous vector's size, which coordinates
belong to the generator and which to the pose/camera, the discrete parameters, and ranked starting
points) and a ``refine(x, discrete, steps) -> (x, loss)`` callable (gradient refinement that spends
evaluations). Strategies are registered by name in ``STRATEGIES``.

- ``memetic``: a genetic algorithm whose offspring are refined by a short Adam run (Lamarckian), the
  thesis authors' method; defaults are theirs (mutation probability 0.2, Gaussian with 0.3 x range,
  50 Adam steps at lr 0.01), with tournament selection, one-point crossover, elitism and restarts.
  Added to it: a local search on the discrete genes (every generation the elite's untried +-1
  neighbours in each discrete value are refined too), because a count gene rarely moves under
  mutation alone when budgets are small.
- ``nlopt``: a derivative-free global algorithm of nlopt (GN_CRS2_LM, GN_ESCH or GN_ISRES) over the
  generator's normalized parameters with discrete coordinates rounded; each evaluation is refined
  briefly by gradient steps.
- ``enumerate``: every discrete combination (at most 64), refined by gradient with successive halving.
- ``none``: the discrete values stay fixed; multi-start gradient refinement only.
"""

from __future__ import annotations

import itertools
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch

from ipm.optim.evaluator import BudgetExhausted, Evaluator
from ipm.params import Param

log = logging.getLogger(__name__)

# refine(x, discrete, steps) -> (x, loss); raises BudgetExhausted when no evaluation is left.
Refine = Callable[[torch.Tensor, dict, int], tuple[torch.Tensor, float]]
MAX_ENUMERATE = 64


@dataclass
class Space:
    """What a search works on.

    m: length of the normalized continuous vector; gen: indices of the generator's coordinates (the
    rest is pose and camera); discrete: the searched discrete parameters; starts: (x, discrete)
    starting poses, best first; presets: the generator's presets posed like the best start.
    """

    m: int
    gen: np.ndarray
    discrete: list[Param]
    starts: list[tuple[torch.Tensor, dict]]
    fixed_discrete: dict = field(default_factory=dict)
    presets: list[tuple[torch.Tensor, dict]] = field(default_factory=list)
    # (x, discrete) -> x posed anew for these discrete values; set when the starts' poses cannot tell
    pose_search: Callable[[torch.Tensor, dict], torch.Tensor] | None = None

    def encode(self, d: dict) -> np.ndarray:
        return np.array([(d[p.name] - p.lo) / max(p.hi - p.lo, 1) for p in self.discrete], dtype=np.float64)

    def decode(self, z: np.ndarray) -> dict:
        out = dict(self.fixed_discrete)
        for p, v in zip(self.discrete, z):
            out[p.name] = int(np.clip(round(p.lo + float(v) * (p.hi - p.lo)), p.lo, p.hi))
        return out


@dataclass(frozen=True)
class MemeticSettings:
    population: int = 8
    tournament: int = 2
    p_mutation: float = 0.2
    sigma_mutation: float = 0.3
    refine_steps: int = 50
    lr: float | None = None   # Adam step of the offspring refinement; None: the fit's (thesis: 0.01)
    stall_generations: int = 3
    min_diversity: float = 0.02
    neighbours: bool = True   # also refine the elite's untried +-1 neighbours in each discrete value
    refine_elite: bool = True  # the elite is refined again in every generation (not only copied)


@dataclass(frozen=True)
class NloptSettings:
    algorithm: str = "GN_CRS2_LM"
    refine_steps: int = 10
    population: int = 0  # 0: nlopt's default


NLOPT_GLOBAL = ("GN_CRS2_LM", "GN_ESCH", "GN_ISRES")


def best_pose(ev: Evaluator, space: Space, x: torch.Tensor, d: dict) -> torch.Tensor:
    """``x`` with the pose (and camera) of the kept start that suits discrete values ``d`` best.

    The pose grid was ranked with the starting discrete values; another count (of floors, boxes) can
    prefer another of the kept poses, so each is tried once (one evaluation, no gradient). Where the
    starts' poses were all alike for the starting values (``space.pose_search``), the pose grid is
    ranked again for ``d`` instead."""
    if space.pose_search is not None and d != space.starts[0][1]:
        return space.pose_search(x, d)
    if len(space.starts) < 2:
        return x
    best, best_x = math.inf, x
    gen = torch.as_tensor(space.gen)
    for xs, _ in space.starts:
        cand = xs.clone()
        cand[gen] = x[gen]
        loss, _ = ev(cand, d, grad=False)
        if loss < best:
            best, best_x = loss, cand
    return best_x


def _genome(space: Space, x: torch.Tensor, d: dict) -> np.ndarray:
    return np.concatenate([x.numpy()[space.gen], space.encode(d)])


def _from_genome(space: Space, g: np.ndarray, pose_from: torch.Tensor) -> tuple[torch.Tensor, dict]:
    x = pose_from.clone()
    x[torch.as_tensor(space.gen)] = torch.as_tensor(g[: len(space.gen)], dtype=torch.float64)
    return x, space.decode(g[len(space.gen):])


def memetic(ev: Evaluator, space: Space, refine: Refine, rng: np.random.Generator,
            settings: MemeticSettings = MemeticSettings()) -> None:
    """Genetic search with gradient-refined offspring; stops when the budget is spent."""
    s = settings
    pop: list[tuple[torch.Tensor, dict, float]] = []
    pose0 = space.starts[0][0]

    def random_individual() -> tuple[torch.Tensor, dict]:
        g = rng.random(len(space.gen) + len(space.discrete))
        return _from_genome(space, g, pose0)

    ev.phase = "memetic:init"
    # the kept starts (the best poses of the grid: a symmetric body seen from few views often leaves
    # several poses close, and the right one only wins after its shape is refined), then the presets
    # (diverse discrete values), then random individuals
    # (when the start looks alike from every yaw, its poses are one start: pose_search poses the rest)
    n_starts = 1 if space.pose_search is not None else max(1, s.population // 2)
    candidates = list(space.starts[:n_starts]) + list(space.presets)
    while len(candidates) < s.population:
        candidates.append(random_individual())
    tried: set[tuple] = set()

    def key(d: dict) -> tuple:
        return tuple(sorted(d.items()))

    def neighbours(elite) -> list[tuple[torch.Tensor, dict, float]]:
        # tried from this elite's continuous values: a neighbour is retried when the elite changes
        origin = tuple(np.round(elite[0].numpy(), 3))
        out = []
        for p in space.discrete:
            for step in (-1, 1):
                d = dict(elite[1])
                d[p.name] = int(np.clip(d[p.name] + step, p.lo, p.hi))
                if d == elite[1] or (key(d), origin) in tried:
                    continue
                tried.add((key(d), origin))
                xr, loss = refine(elite[0], d, s.refine_steps)
                out.append((xr, d, loss))
        return out

    try:
        for i, (x, d) in enumerate(candidates[: s.population]):
            xr, loss = refine(x if i < n_starts else best_pose(ev, space, x, d), d, s.refine_steps)
            pop.append((xr, d, loss))
        best = min(p[2] for p in pop)
        stall, generation = 0, 0
        while True:
            generation += 1
            ev.phase = f"memetic:gen{generation}"
            pop.sort(key=lambda p: p[2])
            # elitism, and the elite keeps descending: without it no candidate gets more than one short
            # refinement before the polish, which is too little where many parameters are determined
            elite = pop[0]
            if s.refine_elite:
                xr, loss = refine(elite[0], elite[1], s.refine_steps)
                elite = (xr, elite[1], loss) if loss <= elite[2] else elite
            children = [elite]
            while len(children) < s.population:
                a, b = (min(rng.choice(len(pop), size=s.tournament, replace=False)) for _ in range(2))
                ga, gb = _genome(space, pop[a][0], pop[a][1]), _genome(space, pop[b][0], pop[b][1])
                cut = int(rng.integers(1, len(ga))) if len(ga) > 1 else 0
                child = np.concatenate([ga[:cut], gb[cut:]])
                mut = rng.random(len(child)) < s.p_mutation
                child[mut] += rng.normal(0.0, s.sigma_mutation, int(mut.sum()))
                child = np.clip(child, 0.0, 1.0)
                x, d = _from_genome(space, child, pop[a][0])  # pose and camera come from parent a
                xr, loss = refine(x, d, s.refine_steps)
                children.append((xr, d, loss))
            if s.neighbours:
                ev.phase = f"memetic:gen{generation}:neighbours"
                children.sort(key=lambda p: p[2])
                extra = neighbours(children[0])
                children = sorted(children + extra, key=lambda p: p[2])[: s.population]
            pop = children
            gen_best = min(p[2] for p in pop)
            stall = stall + 1 if gen_best >= best - 1e-6 else 0
            best = min(best, gen_best)
            genomes = np.stack([_genome(space, p[0], p[1]) for p in pop])
            diversity = float(genomes.std(0).mean())
            if stall >= s.stall_generations or diversity < s.min_diversity:
                log.info("memetic: restart at generation %d (stall %d, diversity %.3f)", generation, stall,
                         diversity)
                pop.sort(key=lambda p: p[2])
                keep = pop[0]
                ev.phase = f"memetic:restart{generation}"
                pop = [keep]
                for _ in range(s.population - 1):
                    x, d = random_individual()
                    x = best_pose(ev, space, x, d)
                    xr, loss = refine(x, d, s.refine_steps)
                    pop.append((xr, d, loss))
                stall = 0
    except BudgetExhausted:
        return


def nlopt_global(ev: Evaluator, space: Space, refine: Refine, rng: np.random.Generator,
                 settings: NloptSettings = NloptSettings()) -> None:
    """nlopt's global derivative-free search; every point is rounded and briefly refined."""
    import nlopt

    if settings.algorithm not in NLOPT_GLOBAL:
        raise ValueError(f"nlopt algorithm: expected one of {', '.join(NLOPT_GLOBAL)}, got {settings.algorithm!r}")
    pose0 = space.starts[0][0]
    dim = len(space.gen) + len(space.discrete)
    if dim == 0:
        return
    opt = nlopt.opt(getattr(nlopt, settings.algorithm), dim)
    opt.set_lower_bounds([0.0] * dim)
    opt.set_upper_bounds([1.0] * dim)
    if settings.population:
        opt.set_population(settings.population)
    opt.set_maxeval(10**9)
    ev.phase = f"nlopt:{settings.algorithm}"

    def f(z, grad):
        x, d = _from_genome(space, np.asarray(z), pose0)
        try:
            _, loss = refine(x, d, settings.refine_steps)
        except BudgetExhausted:
            raise nlopt.ForcedStop from None
        if ev.remaining <= 0:
            raise nlopt.ForcedStop
        return loss if math.isfinite(loss) else 1e6

    opt.set_min_objective(f)
    z0 = _genome(space, *space.starts[0])
    try:
        opt.optimize(z0)
    except (nlopt.ForcedStop, nlopt.RoundoffLimited, ValueError, RuntimeError) as e:
        log.debug("nlopt %s stopped: %s", settings.algorithm, type(e).__name__)


def enumerate_discrete(ev: Evaluator, space: Space, refine: Refine, rng: np.random.Generator,
                       steps0: int | None = None) -> None:
    """All discrete combinations, refined from the best start with successive halving."""
    ranges = [range(int(p.lo), int(p.hi) + 1) for p in space.discrete]
    combos = [dict(zip((p.name for p in space.discrete), c)) for c in itertools.product(*ranges)]
    if len(combos) > MAX_ENUMERATE:
        raise ValueError(f"--discrete enumerate: {len(combos)} combinations of "
                         f"{', '.join(p.name for p in space.discrete)}; at most {MAX_ENUMERATE} are allowed, "
                         "use memetic or nlopt")
    x0 = space.starts[0][0]
    ev.phase = "enumerate:poses"
    try:
        alive = [(best_pose(ev, space, x0, {**space.fixed_discrete, **c}), {**space.fixed_discrete, **c}, math.inf)
                 for c in combos]
    except BudgetExhausted:
        return
    # successive halving spends about steps0 * len(combos) per round, over log2(len) + 1 rounds
    rounds = math.ceil(math.log2(len(combos))) + 1 if len(combos) > 1 else 1
    steps = steps0 or max(5, ev.remaining // (len(combos) * rounds))
    rnd = 0
    try:
        while alive:
            rnd += 1
            ev.phase = f"enumerate:round{rnd}"
            refined = []
            for x, d, _ in alive:
                xr, loss = refine(x, d, steps)
                refined.append((xr, d, loss))
            alive = sorted(refined, key=lambda a: a[2])
            if len(alive) == 1:
                # the winner gets what is left
                refine(alive[0][0], alive[0][1], ev.remaining)
                return
            alive = alive[: max(1, len(alive) // 2)]
            steps *= 2
    except BudgetExhausted:
        return


def multistart(ev: Evaluator, space: Space, refine: Refine, rng: np.random.Generator,
               starts: int = 3) -> None:
    """Discrete values fixed: refine the best few starts, then continue the best one."""
    chosen = space.starts[:starts]
    share = max(10, ev.remaining // (2 * max(len(chosen), 1)))
    results = []
    try:
        for i, (x, d) in enumerate(chosen):
            ev.phase = f"multistart:{i}"
            results.append((*refine(x, d, share), d))
        results.sort(key=lambda r: r[1])
        ev.phase = "refine"
        x, _, d = results[0]
        refine(x, d, ev.remaining)
    except BudgetExhausted:
        return


STRATEGIES: dict[str, Callable] = {
    "memetic": memetic,
    "nlopt": nlopt_global,
    "enumerate": enumerate_discrete,
    "none": multistart,
}
