"""Threads on a quiet and on a busy machine: asking for more must never be slower than one (issue #28).

One workload, the demo's fit of the dishes generator to two masks of the real mug scan (200 evaluations at
128 px, ``ipm.showcase.fit_real_mug``), each run in a fresh process, timed with 1 thread, with 2 asked for
through ``IPM_THREADS`` (``ipm.threads`` uses them only where cores are idle) and with 2 forced (torch's
own behaviour: ``ipm.threads.usable`` bypassed), on a quiet machine and with as many busy processes as cores
(``python -c "while True: pass"``, the ``yes > /dev/null`` of the issue). Median and best of ``REPEAT``
runs; the three settings alternate within each repeat so that the machine's other load hits them alike.

``python -m benchmarks.run results/perf threads`` (about 3 minutes on 2 cores).
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

from benchmarks.common import write_results

REPEAT = 3
ROOT = Path(__file__).resolve().parents[1]
SETTINGS = {"1 thread": ("1", False), "2 asked": ("2", False), "2 forced": ("2", True)}

_CHILD = """
import json, sys, tempfile, time
from pathlib import Path
from ipm import threads
if sys.argv[1] == "forced":
    threads.usable = lambda n: min(n, threads.cores())
from ipm import showcase as demo
t0 = time.perf_counter()
with threads.using(), tempfile.TemporaryDirectory() as tmp:
    used = threads.usable(threads.requested())
    demo.fit_real_mug(Path(tmp), 200, 128)
print(json.dumps({"seconds": time.perf_counter() - t0, "threads": used}))
"""


def _one(n: str, forced: bool) -> dict:
    env = {**os.environ, "IPM_THREADS": n}
    r = subprocess.run([sys.executable, "-c", _CHILD, "forced" if forced else "asked"], cwd=ROOT, env=env,
                       capture_output=True, text=True, check=True)
    return json.loads(r.stdout.strip().splitlines()[-1])


def _busy(k: int) -> list[subprocess.Popen]:
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(k)]


def run(out_dir: Path) -> None:
    from ipm.threads import cores

    _one("1", False)  # the native kernel built, caches warm
    rows = []
    for load in ("quiet", "busy"):
        loops = _busy(cores()) if load == "busy" else []
        try:
            time.sleep(0.5)
            times: dict[str, list[float]] = {k: [] for k in SETTINGS}
            used: dict[str, int] = {}
            for _ in range(REPEAT):
                for name, (n, forced) in SETTINGS.items():
                    r = _one(n, forced)
                    times[name].append(r["seconds"])
                    used[name] = r["threads"]
        finally:
            for p in loops:
                p.kill()
                p.wait()
        for name in SETTINGS:
            rows.append({"machine load": load if load == "quiet" else f"{cores()} busy processes",
                         "threads": name, "threads used": used[name],
                         "median s": round(statistics.median(times[name]), 2), "best s": round(min(times[name]), 2)})
    write_results(out_dir, "threads", "Threads on a quiet and a busy machine (the demo's 2-view mug fit, 200 "
                  "evaluations)", rows,
                  notes="Each run is a fresh process (python -c ... ipm.showcase.fit_real_mug), so the times include "
                        "importing torch (about 3 s). '2 asked': IPM_THREADS=2, used as far as cores are idle "
                        "(ipm.threads); '2 forced': the same with ipm.threads.usable bypassed, torch's own behaviour. "
                        "Busy: one `python -c 'while True: pass'` per core.")
