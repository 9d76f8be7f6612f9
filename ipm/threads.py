"""How many CPU threads torch uses: one unless the user asks for more, and never more than the idle cores.

One thread is the default everywhere (the command line, ``make demo``, bench workers, ``ipm.fit`` and the
other public functions, the tests): with one thread a run is bit-identical for the same inputs, seed and
settings, and on a busy machine torch's threads wait on each other (on 2 busy cores, 2 threads made the
deferred render 256^2 take 1236-1548 ms against 145 ms with one: issue #28). More are asked for with
``--threads N`` or the environment variable :data:`ENV` (``IPM_THREADS=2``); either way a thread is only
used where a core is idle (:func:`usable`), checked when the work starts and again every
:data:`RECHECK` evaluations of a fit (:func:`adapt`), so asking for more never makes the work slower than
one thread when other processes take the cores.

Results do not depend on the thread count within the fits' tolerance (``benchmarks/perturbation.py``);
bit for bit they may.

Work spread over processes (bench cells, a proposal network's training renders) runs in :func:`process_pool`,
whose workers die with their parent.
"""

from __future__ import annotations

import functools
import logging
import os
import sys
from collections.abc import Callable
from contextlib import contextmanager
from pathlib import Path
from typing import TypeVar

from ipm.errors import InputError

log = logging.getLogger(__name__)

ENV = "IPM_THREADS"
DEFAULT = 1
MAX = 256
RECHECK = 50  # evaluations of a fit between two looks at the idle cores

# the thread counts asked for by the public calls under way (using), innermost last; outside them, the
# environment's (which ask sets for the command line), else DEFAULT
_asked: list[int] = []


def requested(n: int | None = None) -> int:
    """The thread count asked for: ``n`` if given, else :data:`ENV` from the environment, else
    :data:`DEFAULT`. :class:`InputError` for an :data:`ENV` that is not a whole number in [1, MAX]."""
    if n is not None:
        return _checked(n, "threads")
    if _asked:
        return _asked[-1]
    raw = os.environ.get(ENV)
    if raw is None or raw.strip() == "":
        return DEFAULT
    try:
        value = int(raw.strip())
    except ValueError:
        raise InputError(f"{ENV}: expected a whole number of threads in [1, {MAX}], got {raw!r}") from None
    return _checked(value, ENV)


def _checked(n, what: str) -> int:
    if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= MAX:
        raise InputError(f"{what}: expected a whole number of threads in [1, {MAX}], got {n!r}")
    return n


def cores() -> int:
    """The cores this process may run on (its CPU affinity), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def _running_threads(stat_files) -> int:
    n = 0
    for f in stat_files:
        try:
            text = Path(f).read_text()
        except OSError:
            continue
        # "pid (comm) S ...": the state follows the last ")" (comm may hold spaces and parentheses)
        if text[text.rfind(")") + 2: text.rfind(")") + 3] == "R":
            n += 1
    return n


def busy_cores() -> int | None:
    """How many of the machine's runnable threads belong to other processes right now (Linux: the running
    count of ``/proc/loadavg`` less this process's own running threads); None where that cannot be read."""
    try:
        running = int(Path("/proc/loadavg").read_text().split()[3].split("/")[0])
    except (OSError, ValueError, IndexError):
        return None
    own = _running_threads(Path("/proc/self/task").glob("*/stat"))
    return max(0, running - max(own, 1))


def usable(n: int) -> int:
    """``n`` threads, fewer where cores are taken by other processes: at most the idle cores, at least 1."""
    if n <= 1:
        return 1
    n = min(n, cores())
    other = busy_cores()
    if other is None:
        return n
    return max(1, min(n, cores() - other))


def apply(n: int) -> int:
    """Use ``n`` torch CPU threads (set now if torch is loaded, else through ``OMP_NUM_THREADS``, read
    when torch loads, so that commands that do not need torch do not import it); returns ``n``."""
    os.environ["OMP_NUM_THREADS"] = str(n)
    torch = sys.modules.get("torch")
    if torch is not None and torch.get_num_threads() != n:
        torch.set_num_threads(n)
    return n


def ask(n: int | None = None) -> int:
    """Ask for ``requested(n)`` threads for the rest of this process (the command line's ``--threads``):
    child processes (bench workers) inherit it through :data:`ENV`. Uses what is usable of it now
    (:func:`usable`) and returns that."""
    asked = requested(n)
    os.environ[ENV] = str(asked)
    return apply(usable(asked))


def adapt() -> int:
    """Re-check the idle cores for the running work and set torch's threads to what is usable of what was
    asked for (:func:`requested`); cheap (a few ``/proc`` reads). Returns the count in use."""
    asked = requested()
    n = usable(asked)
    torch = sys.modules.get("torch")
    if torch is not None and torch.get_num_threads() != n:
        log.info("threads: %d of the %d asked for (%s other running)", n, asked, busy_cores())
        torch.set_num_threads(n)
    return n


@contextmanager
def using(n: int | None = None):
    """Run the block with ``requested(n)`` threads asked for (used as far as cores are idle), then put back
    the thread count and the request that were in force before."""
    asked = requested(n)
    torch = sys.modules.get("torch")
    before = torch.get_num_threads() if torch is not None else None
    _asked.append(asked)
    try:
        apply(usable(asked))
        yield asked
    finally:
        _asked.pop()
        torch = sys.modules.get("torch")
        if torch is not None and before is not None and torch.get_num_threads() != before:
            torch.set_num_threads(before)


F = TypeVar("F", bound=Callable)


def one_by_default(fn: F) -> F:
    """Decorate a public function so that it runs with the requested threads (default one) and restores the
    caller's count afterwards; the function takes an optional ``threads`` keyword for more."""

    @functools.wraps(fn)
    def wrapper(*args, threads: int | None = None, **kwargs):
        with using(threads):
            return fn(*args, **kwargs)

    return wrapper  # type: ignore[return-value]


def process_pool(workers: int):
    """A ``ProcessPoolExecutor`` of ``workers`` processes that die with this one, even on SIGKILL (Linux:
    ``prctl`` PR_SET_PDEATHSIG; elsewhere the pool's own shutdown applies), so a killed run leaves no orphans."""
    from concurrent.futures import ProcessPoolExecutor

    return ProcessPoolExecutor(max_workers=workers, initializer=die_with_parent, initargs=(os.getpid(),))


def die_with_parent(parent: int) -> None:
    """Worker initializer of :func:`process_pool`: ask Linux to SIGKILL this worker when its parent dies."""
    import ctypes
    import signal

    if sys.platform.startswith("linux"):
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG = 1
        if os.getppid() != parent:  # the parent died before prctl took effect
            os._exit(1)
