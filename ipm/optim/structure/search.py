"""The beam search over trees (:func:`search`).

Start: one part per primitive kind fitted to the target's bounding box and one fitted to its core (or a
tree the user gives), refined and scored. Each round, every tree of the beam gets proposals from the edits
(taken from the edits in turn, so that each kind of edit is tried, each edit's list read from a later
position every round, up to ``proposals`` per tree; none larger than ``max_nodes``, none proposed twice),
and the tree itself is refined further alongside them; each proposal is refined by ``steps`` Adam steps
and scored (grid IoU plus ``node_cost`` per node, :mod:`~ipm.optim.structure.candidate`); the
``beam`` best trees of different structure go on. The search stops when a round no longer improves
the best score for ``patience`` rounds, after ``rounds`` rounds, or when the budget (less the polish)
is spent; the best tree is then refined by ``polish`` steps and kept if its score did not get worse.

Deterministic: no random choice is made after the target's samples are drawn; one thread of torch
gives the same floats. Resumable: after every round the state (beam, best, evaluations, elapsed time,
records written) goes to ``checkpoint``; :func:`search` given that state continues with the next round,
and ends where an uninterrupted search would. A state read back from a file is checked first:
:class:`State` is its schema, and :func:`verify_state` scores its trees again and refuses a state whose
recorded scores they do not reproduce (an edited or another target's checkpoint).
"""

from __future__ import annotations

import json
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Annotated, Any, Literal

import msgspec
import numpy as np
from msgspec import Meta

from ipm.errors import InputError
from ipm.optim.structure import candidate as C
from ipm.optim.structure.edits import EDITS, Context, Proposal
from ipm.optim.structure.program import count_nodes, part, signature, structure
from ipm.optim.structure.samples import Samples
from ipm.optim.structure.settings import StructureSettings

log = logging.getLogger(__name__)

IMPROVEMENT = 1e-4   # a round counts as an improvement when it lowers the best score by more


@dataclass
class Scored:
    tree: dict
    score: float
    iou: float
    nodes: int
    loss: float = math.nan
    label: str = "start"

    def to_json(self) -> dict:
        return {"tree": self.tree, "score": self.score, "iou": self.iou, "nodes": self.nodes, "loss": self.loss,
                "label": self.label}

    @classmethod
    def from_json(cls, d: dict) -> Scored:
        return cls(d["tree"], float(d["score"]), float(d["iou"]), int(d["nodes"]), float(d["loss"]), d["label"])


@dataclass
class SearchResult:
    """The best tree (nested JSON dict), its score, grid IoU and node count, the evaluations and seconds
    spent (every resumed run included), the rounds run and why the search stopped."""

    tree: dict
    score: float
    iou: float
    nodes: int
    evaluations: int
    wall_time_s: float
    rounds: int
    stopped: str
    beam: list[Scored] = field(default_factory=list)

    @property
    def structure(self) -> str:
        return structure(self.tree)

    @property
    def signature(self) -> tuple[tuple[str, ...], tuple[str, ...]]:
        return signature(self.tree)


class ScoredState(msgspec.Struct):
    """A scored tree in a checkpoint (:meth:`Scored.to_json`); ``loss`` is NaN for a tree not refined."""

    tree: dict[str, Any]
    score: float
    iou: Annotated[float, Meta(ge=0.0, le=1.0)]
    nodes: Annotated[int, Meta(ge=1)]
    loss: float
    label: str


class State(msgspec.Struct):
    """The schema of a search's checkpoint (what ``checkpoint`` is given after every round): the round
    finished, the beam and the best tree, rounds without improvement, evaluations used, seconds elapsed,
    records written, and why the search stopped (None: not yet)."""

    round: Annotated[int, Meta(ge=0)]
    beam: Annotated[list[ScoredState], Meta(min_length=1)]
    best: ScoredState
    stale: Annotated[int, Meta(ge=0)]
    used: Annotated[int, Meta(ge=0)]
    elapsed: Annotated[float, Meta(ge=0.0)]
    records: Annotated[int, Meta(ge=0)]
    stopped: Literal["rounds", "budget", "converged"] | None = None


SCORE_RTOL = 1e-6   # re-scored trees: the score is a count ratio plus a cost per node (bit-identical in tests)


def verify_state(state: dict, samples: Samples, settings: StructureSettings) -> None:
    """Refuse (:class:`~ipm.errors.InputError`, "beam[1]: ...") a checkpoint ``state`` that does not fit
    ``settings`` or whose trees, scored again on ``samples``, do not give their recorded score and IoU.
    ``state`` is assumed to have :class:`State`'s schema already."""
    from ipm.sdf.tree import tree_from_json

    if state["used"] > settings.budget:
        raise InputError(f"used: expected at most the budget's {settings.budget} evaluations, got {state['used']}")
    if state["round"] > settings.rounds:
        raise InputError(f"round: expected at most the settings' {settings.rounds} rounds, got {state['round']}")
    entries = [(f"beam[{i}]", b) for i, b in enumerate(state["beam"])] + [("best", state["best"])]
    for where, entry in entries:
        try:
            tree_from_json({"tree": entry["tree"]})
        except InputError as e:
            raise InputError(f"{where}.tree: expected a tree, got one that does not load ({e})") from None
        for name in ("score", "iou"):
            if not math.isfinite(entry[name]):
                raise InputError(f"{where}.{name}: expected a finite number, got {entry[name]!r}")
        if entry["nodes"] != count_nodes(entry["tree"]):
            raise InputError(f"{where}.nodes: expected the tree's {count_nodes(entry['tree'])} nodes, got "
                             f"{entry['nodes']!r}")
    for where, entry in entries:
        sc, q, _ = C.score(entry["tree"], samples, settings.node_cost)
        for name, got in (("score", sc), ("iou", q)):
            want = float(entry[name])
            if abs(got - want) > SCORE_RTOL * max(abs(got), abs(want), 1.0):
                raise InputError(f"{where}.{name}: expected what the tree scores, {got!r}, got {want!r} (an edited "
                                 "checkpoint, or another target or settings?)")


def starts(samples: Samples, kinds) -> list[Proposal]:
    """One part per kind over the target's bounding box and one over its core (the largest box of cells
    nearly all inside: the body of a chair, the base of a lamp)."""
    regions = C.regions(samples.grid_inside, samples, 1, 10 ** 9)
    if not regions:
        raise InputError("structure search: the target has no inside (an empty mesh or masks without a "
                         "common silhouette)")
    lo = np.min([r.lo for r in regions], axis=0)
    hi = np.max([r.hi for r in regions], axis=0)
    core = regions[0]
    out = [Proposal(f"start {k} at the bounds", part("part1", k, 0.5 * (lo + hi), hi - lo)) for k in kinds]
    return out + [Proposal(f"start {k} at the core", part("part1", k, core.center_core, core.core_hi - core.core_lo))
                  for k in kinds]


def _interleave(lists: list[list[Proposal]], cap: int, shift: int = 0) -> list[Proposal]:
    """Up to ``cap`` proposals taken from the lists in turn, each list read from position ``shift`` on
    (cyclically), so that successive rounds try different members of a long list."""
    lists = [x[shift % len(x):] + x[:shift % len(x)] if x else x for x in lists]
    out: list[Proposal] = []
    i = 0
    while len(out) < cap and any(i < len(x) for x in lists):
        for x in lists:
            if i < len(x) and len(out) < cap:
                out.append(x[i])
        i += 1
    return out


@dataclass
class _Run:
    """One search's running parts: the target, the settings, the budget, the records written and the
    callbacks; it scores proposals, picks the beam and writes the checkpoint."""

    samples: Samples
    s: StructureSettings
    budget: C.Budget
    info: dict
    records: int
    t_before: float
    record: Callable[[dict], None] | None
    progress: Callable[[int, int, dict], None] | None
    checkpoint: Callable[[dict], None] | None
    t0: float = field(default_factory=time.perf_counter)

    def tick(self) -> None:
        """Report the evaluations used to ``progress``, if given."""
        if self.progress is not None:
            self.progress(self.budget.used, self.s.budget, self.info)

    def elapsed(self) -> float:
        """Seconds spent, every resumed run included."""
        return self.t_before + time.perf_counter() - self.t0

    def evaluate(self, p: Proposal, rnd: int, parent: int) -> Scored:
        """Proposal ``p`` refined by the settings' steps and scored (and recorded, if ``record`` is given)."""
        s = self.s
        tree, loss = C.refine(p.tree, self.samples, s.steps, s.lr, self.budget, self.tick)
        sc, q, _ = C.score(tree, self.samples, s.node_cost)
        self.budget.take()
        out = Scored(tree, sc, q, count_nodes(tree), loss, p.label)
        if self.record is not None:
            self.record({"i": self.records, "round": rnd, "parent": parent, "edit": p.label,
                         "structure": structure(tree), "nodes": out.nodes, "iou": q, "score": sc, "loss": loss,
                         "evaluations": self.budget.used, "t": round(self.elapsed(), 3), "tree": tree})
        self.records += 1
        return out

    def select(self, pool: list[Scored]) -> list[Scored]:
        """The ``beam`` best trees of ``pool`` of different structure, best first."""
        kept, seen = [], set()
        for c in sorted(pool, key=lambda c: c.score):  # stable: ties keep the earlier tree
            key = structure(c.tree)
            if key not in seen:
                seen.add(key)
                kept.append(c)
            if len(kept) == self.s.beam:
                break
        return kept

    def save(self, rnd: int, beam: list[Scored], best: Scored, stale: int, stopped: str | None) -> None:
        """Hand the state after round ``rnd`` to ``checkpoint``, if given."""
        if self.checkpoint is not None:
            self.checkpoint({"round": rnd, "beam": [b.to_json() for b in beam], "best": best.to_json(),
                             "stale": stale, "used": self.budget.used, "elapsed": self.elapsed(),
                             "records": self.records, "stopped": stopped})


def _first_beam(run: _Run, start: dict | None) -> list[Scored]:
    """The first beam: the start trees (``start``, or :func:`starts`) refined and scored."""
    s = run.s
    first = [Proposal("start (given)", start)] if start is not None else starts(run.samples, s.kinds)
    beam = run.select([run.evaluate(p, 0, -1) for p in first if run.budget.left > 0])
    if not beam:
        raise InputError(f"structure search: budget {s.budget} leaves no evaluation for the start after the "
                         f"polish's {s.polish}")
    return beam


def _proposals(run: _Run, tree: dict, seen: set[str], min_cells: int, rnd: int) -> list[Proposal]:
    """Round ``rnd``'s proposals for ``tree``: each edit's proposals within ``max_nodes`` and not in
    ``seen`` (which they join), interleaved up to ``proposals``."""
    s, samples = run.s, run.samples
    along = None if samples.rays is None else C.missed_cells(tree, samples)
    missing, extra = C.residual(C.occupancy(tree, samples), samples, along)
    ctx = Context(samples, tuple(C.regions(missing, samples, min_cells, s.regions)),
                  tuple(C.regions(extra, samples, min_cells, s.regions)), s.kinds)
    lists = []
    for name in s.edits:
        ok = []
        for p in EDITS.get(name)(tree, ctx):
            key = json.dumps(p.tree, sort_keys=True)
            if count_nodes(p.tree) <= s.max_nodes and key not in seen:
                seen.add(key)
                ok.append(p)
        lists.append(ok)
    return _interleave(lists, s.proposals, rnd - 1)


def _round(run: _Run, beam: list[Scored], rnd: int, min_cells: int) -> list[Scored]:
    """The beam after round ``rnd``: the beam's trees, each refined again, and their proposals, scored."""
    seen = {json.dumps(b.tree, sort_keys=True) for b in beam}
    pool = list(beam)
    for j, cand in enumerate(beam):
        # the tree itself, refined as long as its proposals are: an edit must beat its parent given the
        # same steps, not only the steps it got
        for p in [Proposal("refine", cand.tree), *_proposals(run, cand.tree, seen, min_cells, rnd)]:
            if run.budget.left <= 0:
                break
            pool.append(run.evaluate(p, rnd, j))
    return run.select(pool)


def _polish(run: _Run, best: Scored) -> tuple[Scored, C.Budget]:
    """The best tree refined by the rest of the budget at a third of the step (kept if its score did not get
    worse), and the whole search's budget."""
    s, samples, progress, info = run.s, run.samples, run.progress, run.info
    polish = C.Budget(s.budget, run.budget.used)
    final = best
    if polish.left > 0 and s.polish > 0:
        tree, loss = C.refine(best.tree, samples, polish.left - 1, s.lr / 3, polish,
                              lambda: progress(polish.used, s.budget, info) if progress else None)
        sc, q, _ = C.score(tree, samples, s.node_cost)
        polish.take()
        if sc <= best.score:
            final = Scored(tree, sc, q, count_nodes(tree), loss, "polish")
    return final, polish


def search(samples: Samples, settings: StructureSettings = StructureSettings(), *, start: dict | None = None,
           state: dict | None = None, checkpoint: Callable[[dict], None] | None = None,
           record: Callable[[dict], None] | None = None,
           progress: Callable[[int, int, dict], None] | None = None) -> SearchResult:
    """Search trees for ``samples`` (module docstring). ``start``: a tree to begin from instead of the
    bounding-box parts; ``state``: a checkpoint to resume; ``record``: called with every scored tree
    (the trajectory); ``progress``: called with (evaluations, budget, info) after each step."""
    settings.check()
    s = settings
    run = _Run(samples, s, C.Budget(s.budget - s.polish, int(state["used"]) if state else 0),
               {"round": int(state["round"]) if state else 0, "iou": math.nan},
               int(state["records"]) if state else 0, float(state["elapsed"]) if state else 0.0,
               record, progress, checkpoint)
    if state:
        beam = [Scored.from_json(d) for d in state["beam"]]
        best = Scored.from_json(state["best"])
        rnd, stale, stopped = int(state["round"]), int(state["stale"]), state.get("stopped")
    else:
        beam = _first_beam(run, start)
        best, rnd, stale, stopped = beam[0], 0, 0, None
        run.save(rnd, beam, best, stale, stopped)
    min_cells = max(2, int(s.min_region * int(samples.grid_inside.sum())))
    while stopped is None:
        if rnd >= s.rounds:
            stopped = "rounds"
            break
        if run.budget.left <= 0:
            stopped = "budget"
            break
        rnd += 1
        run.info["round"] = rnd
        beam = _round(run, beam, rnd, min_cells)
        if beam[0].score < best.score - IMPROVEMENT:
            best, stale = beam[0], 0
        else:
            stale += 1
        run.info["iou"] = best.iou
        log.info("structure round %d: best %s, %d nodes, IoU %.4f, score %.4f (%d evaluations)", rnd,
                 structure(best.tree), best.nodes, best.iou, best.score, run.budget.used)
        if stale >= s.patience:
            stopped = "converged"
        run.save(rnd, beam, best, stale, stopped)
    final, polish = _polish(run, best)
    return SearchResult(final.tree, final.score, final.iou, final.nodes, polish.used, run.elapsed(), rnd, stopped,
                        beam)


__all__ = ["IMPROVEMENT", "Scored", "SearchResult", "State", "search", "starts", "verify_state"]
