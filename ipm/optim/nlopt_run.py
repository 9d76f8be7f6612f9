"""Running an nlopt optimizer so that only its own stop conditions end a search quietly.

nlopt reports stops as exceptions (``ForcedStop``, ``RoundoffLimited``), and an exception raised inside
the objective passes through its C code. :func:`minimize` ends a run quietly on the budget
(:class:`~ipm.optim.evaluator.BudgetExhausted` inside the objective, which becomes a forced stop) and on
``RoundoffLimited``; any other exception raised inside the objective (a renderer bug, a resume that does
not match its recorded run) is kept and raised again, unchanged, once nlopt has returned.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable

import numpy as np

from ipm.optim.evaluator import BudgetExhausted

log = logging.getLogger(__name__)


def minimize(opt, objective: Callable[[np.ndarray, np.ndarray], float], z0: np.ndarray, label: str, *,
             line_search: bool = False) -> None:
    """Run ``opt`` (an ``nlopt.opt`` with bounds and limits set) on ``objective(z, grad) -> loss`` from
    ``z0 (d,)`` float64. The caller keeps the best point it saw; ``label`` names the run in the log.
    ``line_search``: the algorithm ends with nlopt's generic failure when its line search finds no
    decrease (LD_LBFGS); after more than one evaluation that is a stop, not an error."""
    import nlopt

    failures: list[BaseException] = []
    stopped: list[bool] = []
    calls = [0]

    def f(z, grad):
        # A stop is asked for with force_stop() rather than by raising nlopt.ForcedStop in here: LD_LBFGS
        # calls the objective once more after a stop, which with a Python exception still pending fails
        # inside the next call (SystemError). Calls after a stop evaluate nothing.
        if stopped:
            return math.inf
        calls[0] += 1
        try:
            return objective(z, grad)
        except BudgetExhausted:
            pass
        except Exception as e:  # kept: raised again once nlopt has returned
            failures.append(e)
        stopped.append(True)
        opt.force_stop()
        return math.inf

    opt.set_min_objective(f)
    try:
        opt.optimize(z0)
    except (nlopt.ForcedStop, nlopt.RoundoffLimited) as e:
        if not failures:
            log.debug("nlopt %s stopped: %s", label, type(e).__name__)
    except Exception as e:
        # after a stop that was asked for, some algorithms report a generic failure (LD_LBFGS, having
        # seen the infinite value returned above); before it, a failure of nlopt's is a bug: loud
        # LD_LBFGS's line search also ends with a generic failure when it finds no decrease along its
        # direction (a loss that is not smooth everywhere: a face's visibility switches); the caller
        # keeps the best point it saw, as after any other stop
        if stopped:
            log.debug("nlopt %s stopped: %s after a forced stop", label, type(e).__name__)
        elif line_search and not failures and isinstance(e, nlopt.runtime_error) and calls[0] > 1:
            log.debug("nlopt %s: line search failed after %d evaluations", label, calls[0])
        else:
            raise
    if failures:
        raise failures[0]
