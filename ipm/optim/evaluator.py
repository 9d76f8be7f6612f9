"""Counted, recorded, replayable evaluations.

Every search strategy sees the problem only through an :class:`Evaluator`: ``ev(x, discrete)`` returns
the loss (and its gradient with respect to ``x``) and counts one evaluation (one render + loss). The
evaluator stops the search when the budget is spent, remembers the best point, and hands every
record to a sink (the run's ``trajectory.jsonl``).

Resuming: records of an interrupted run are *replayed*. A deterministic search (same seed) asks for the
same points in the same order, so the evaluator answers from the records while they last (checking
that the point matches) and then goes on live. The resumed run therefore ends exactly where an
uninterrupted run would, whatever the search strategy (nlopt's internal state included). A point that
differs from its record raises :class:`ReplayMismatch` (an :class:`~ipm.errors.InputError`: the run folder
does not belong to these settings or this code).

The records' losses and gradients are taken on trust, except for a few that the replay evaluates again
(:func:`checked_records`): the last one replayed (its gradient and loss steer the first live step) and,
in every phase, the one with the lowest loss (the point that phase would keep as its best). A
re-evaluation whose loss or gradient differs from the record's (beyond :data:`LOSS_RTOL`,
:data:`GRAD_RTOL`) raises :class:`ReplayMismatch` naming the evaluation: an edited trajectory, or target
files that changed since the run was recorded. A record whose loss was raised, not lowered, in the middle
of a phase is not caught. Every record's ``t`` is the run's elapsed time in seconds,
counted over all its runs (the replayed records' time included), so :attr:`Evaluator.elapsed_s` is the
time of the whole run after any number of resumes.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field

import torch

from ipm import threads
from ipm.errors import InputError

log = logging.getLogger(__name__)

# objective(x (m,) float64 in [0, 1], discrete, need_grad) -> (loss (0-dim), grad (m,) or None, extras)
Objective = Callable[[torch.Tensor, dict, bool], tuple[torch.Tensor, torch.Tensor | None, dict]]


class BudgetExhausted(Exception):
    """Raised by the evaluator when the evaluation budget is spent."""


class ReplayMismatch(InputError):
    """A resumed run asked for a different point than the recorded run did, or a recorded loss or gradient
    differs from what the point evaluates to again."""


# How far a re-evaluated record may be from its recorded loss (relative) and gradient (relative to its
# largest component). With the same code and one thread the replay is bit-identical, also with two
# threads (measured: dishes, memetic, 60 evaluations at 64 px); the eager soft-silhouette kernel, which a
# machine without a C compiler falls back to, differs from the native one by up to 3e-6 in the loss and
# 1.5e-5 in the gradient, and a run may be resumed there.
LOSS_RTOL = 1e-4
GRAD_RTOL = 1e-3


def checked_records(replay: Sequence[dict]) -> set[int]:
    """Indices of the replayed records that the replay evaluates again: the last one, and per phase the one
    with the lowest loss (the first of equals)."""
    if not replay:
        return set()
    lowest: dict[str, int] = {}
    for i, r in enumerate(replay):
        phase = str(r.get("phase", ""))
        if phase not in lowest or r["loss"] < replay[lowest[phase]]["loss"]:
            lowest[phase] = i
    return {len(replay) - 1, *lowest.values()}


@dataclass
class Best:
    loss: float = math.inf
    x: torch.Tensor | None = None
    discrete: dict = field(default_factory=dict)
    index: int = -1
    extras: dict = field(default_factory=dict)  # the objective's extras at this point (per-view IoU, ...)


class Evaluator:
    """Budgeted access to an objective, with recording and replay (see the module docstring)."""

    def __init__(self, objective: Objective, budget: int, *, sink: Callable[[dict], None] | None = None,
                 replay: Sequence[dict] = (), progress: Callable[[Evaluator], None] | None = None):
        if budget < 1:
            raise InputError(f"budget: expected at least 1 evaluation, got {budget}")
        self.objective = objective
        self.budget = int(budget)
        self.sink = sink
        self.replay = list(replay)
        self.checked = checked_records(self.replay)
        self.progress = progress
        self.count = 0
        # the count at which the running phase stops (running(until=...)); the budget outside phases
        self.cap = self.budget
        # what the objective evaluates (ipm.optim.phases.Phase): None calls objective(x, discrete, grad)
        self.mode = None
        self.best = Best()
        self.phase = "start"
        self.last: dict = {}   # the latest record, live or replayed
        # False while evaluations of another objective run (a phase with keep_best off: the outline without
        # part labels): counted and recorded, but not candidates for the best point
        self.keep_best = True
        self.best_by_discrete: dict[tuple, Best] = {}
        self.t0 = time.perf_counter()
        # the recorded time of the runs before this one (records' "t" count from the first run's start)
        self.t_before = float(self.replay[-1].get("t", 0.0)) if self.replay else 0.0

    @property
    def elapsed_s(self) -> float:
        """Seconds spent on this run, earlier runs of a resumed one included."""
        return self.t_before + time.perf_counter() - self.t0

    @property
    def remaining(self) -> int:
        """Evaluations left before the current cap (the budget, or the enclosing phase's stop)."""
        return self.cap - self.count

    @contextmanager
    def running(self, mode=None, *, label: str | None = None, until: int | None = None) -> Iterator[Evaluator]:
        """Evaluate as phase ``mode`` (an :class:`ipm.optim.phases.Phase`: its terms, blur and whether its
        points are candidates for the result) under the record label ``label``, stopping at evaluation
        ``until`` (at most the budget; default: where the enclosing phase stops) within the block; what was in force
        before comes back after it."""
        saved = (self.mode, self.keep_best, self.phase, self.cap)
        if mode is not None:
            self.mode, self.keep_best = mode, mode.keep_best
        if label is not None:
            self.phase = label
        if until is not None:
            self.cap = min(self.budget, int(until))
        try:
            yield self
        finally:
            self.mode, self.keep_best, self.phase, self.cap = saved

    @property
    def replaying(self) -> bool:
        """True while the evaluations are taken from a resumed run's records instead of computed."""
        return self.count < len(self.replay)

    def __call__(self, x: torch.Tensor, discrete: dict, *, grad: bool = True) -> tuple[float, torch.Tensor | None]:
        if self.count >= self.cap:
            raise BudgetExhausted
        x = x.detach().to(torch.float64).clamp(0.0, 1.0)
        xs = [float(v) for v in x.tolist()]
        disc = {k: int(v) for k, v in discrete.items()}
        if self.replaying:
            rec = self.replay[self.count]
            if rec["x"] != xs or rec["discrete"] != disc or bool(rec.get("grad") is not None) != grad:
                raise ReplayMismatch(f"resume: evaluation {self.count}: expected the recorded run's point, got "
                                     f"{_difference(rec, xs, disc, grad)} (different seed, settings or code?); "
                                     "start a new run instead")
            loss = float(rec["loss"])
            g = torch.tensor(rec["grad"], dtype=torch.float64) if rec.get("grad") is not None else None
            extras = {k: rec[k] for k in rec if k not in ("i", "x", "discrete", "loss", "grad", "phase", "t")}
            if self.count in self.checked:
                self._check(rec, x, disc, grad)
        else:
            if self.count % threads.RECHECK == 0:
                threads.adapt()  # fewer torch threads while other processes take the cores
            loss, g, extras = self._evaluate(x, disc, grad)
            rec = {"i": self.count, "phase": self.phase, "loss": loss, "x": xs, "discrete": disc,
                   "grad": None if g is None else [float(v) for v in g.tolist()],
                   "t": round(self.elapsed_s, 4), **extras}
            if self.sink is not None:
                self.sink(rec)
        self.last = rec
        if self.keep_best:
            key = _combination(disc)
            best = Best(loss, torch.tensor(xs, dtype=torch.float64), dict(disc), self.count, extras)
            if loss < self.best_by_discrete.get(key, Best()).loss:
                self.best_by_discrete[key] = best
            if loss < self.best.loss:
                self.best = best
        self.count += 1
        if self.progress is not None:
            self.progress(self)
        return loss, g

    def _evaluate(self, x: torch.Tensor, disc: dict, grad: bool) -> tuple[float, torch.Tensor | None, dict]:
        """The objective at ``x``: the loss (1e6 where not finite), the gradient (non-finite parts 0), extras."""
        if self.mode is None:
            loss_t, g_t, extras = self.objective(x, disc, grad)
        else:
            loss_t, g_t, extras = self.objective(x, disc, grad, self.mode)
        loss = float(loss_t.detach())
        if not math.isfinite(loss):
            loss = 1e6  # a degenerate shape: steer away instead of crashing the search
            g_t = torch.zeros_like(x) if grad else None
        g = None
        if grad:
            gl = [float(v) for v in g_t.detach().to(torch.float64).tolist()]
            gl = [v if math.isfinite(v) else 0.0 for v in gl]
            g = torch.tensor(gl, dtype=torch.float64)
        return loss, g, extras

    def _check(self, rec: dict, x: torch.Tensor, disc: dict, grad: bool) -> None:
        """Evaluate a replayed record again; :class:`ReplayMismatch` where its loss or gradient differs."""
        loss, g, _ = self._evaluate(x, disc, grad)
        want = float(rec["loss"])
        why = None
        if abs(loss - want) > LOSS_RTOL * max(abs(loss), abs(want)):
            why = f"a loss of {loss!r} where the record has {want!r}"
        elif g is not None:
            rg = torch.tensor(rec["grad"], dtype=torch.float64)
            scale = max(float(rg.abs().max()), float(g.abs().max())) if len(rg) else 0.0
            diff = (g - rg).abs()
            if len(rg) and float(diff.max()) > GRAD_RTOL * scale:
                j = int(diff.argmax())
                why = f"a gradient with grad[{j}] = {float(g[j])!r} where the record has {float(rg[j])!r}"
        if why is not None:
            raise ReplayMismatch(f"resume: evaluation {self.count}: evaluated again, the recorded point gives {why} "
                                 "(an edited trajectory, or target files, settings or code that changed since?); "
                                 "start a new run instead")

    def forget_best(self) -> None:
        """Start the best-point records afresh (the objective changed, e.g. a finer blur: losses from
        before are not comparable with later ones)."""
        self.best = Best()
        self.best_by_discrete = {}

    def best_of(self, discrete: dict) -> Best:
        """The best point seen with discrete values ``discrete`` (an empty :class:`Best` where there is none)."""
        return self.best_by_discrete.get(_combination(discrete), Best())

    def leaders(self, k: int) -> list[Best]:
        """The best point of each of the ``k`` best discrete combinations."""
        return sorted(self.best_by_discrete.values(), key=lambda b: b.loss)[:k]


def _combination(discrete: dict) -> tuple:
    """The key of a discrete combination in :attr:`Evaluator.best_by_discrete`."""
    return tuple(sorted(discrete.items()))


def _difference(rec: dict, xs: list[float], disc: dict, grad: bool) -> str:
    """What differs between a recorded evaluation and the one asked for, in words."""
    if rec["discrete"] != disc:
        return f"discrete values {disc} instead of {rec['discrete']}"
    if (rec.get("grad") is not None) != grad:
        return "an evaluation " + ("with" if grad else "without") + " a gradient where the record has " + (
            "none" if grad else "one")
    if len(rec["x"]) != len(xs):
        return f"a vector of length {len(xs)} instead of {len(rec['x'])}"
    i = next(i for i, (a, b) in enumerate(zip(rec["x"], xs)) if a != b)
    return f"x[{i}] = {xs[i]!r} instead of {rec['x'][i]!r}"
