"""What a small fit costs as a process (issue #30: a 60-evaluation ``ipm fit`` within 2 s of
``python -c "import torch"`` on the same machine): both commands run alternately ``REPEAT`` times, wall time of
each process, medians compared. The fit: ``dishes`` on one 128 px mask of the mug preset (rendered once before),
60 evaluations, one torch thread, a fresh run folder each time (it writes its mesh, overlays and loss plot).

``python -m benchmarks.run results/perf startup`` (seconds).
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.common import write_results

REPEAT = 7
BUDGET = 60


def _wall(cmd: list[str], cwd: Path) -> float:
    """Seconds of one process run to completion (it must succeed)."""
    t0 = time.perf_counter()
    subprocess.run(cmd, cwd=cwd, check=True, capture_output=True, env={**os.environ, "IPM_THREADS": "1"})
    return time.perf_counter() - t0


def run(out_dir: Path) -> None:
    py = sys.executable
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        subprocess.run([py, "-m", "ipm", "render", "dishes", "--preset", "mug", "--views", "1", "--size", "128",
                        "-o", "masks"], cwd=tmp, check=True, capture_output=True)
        torch_s, fit_s = [], []
        for i in range(REPEAT):  # alternately, so that both see the same load
            torch_s.append(_wall([py, "-c", "import torch"], tmp))
            fit_s.append(_wall([py, "-m", "ipm", "fit", "dishes", "--masks", "masks", "--budget", str(BUDGET),
                                "-o", f"run{i}"], tmp))
    t, f = statistics.median(torch_s), statistics.median(fit_s)
    rows = [{"process": 'python -c "import torch"', "median_s": t, "best_s": min(torch_s)},
            {"process": f"ipm fit dishes --masks masks --budget {BUDGET} -o run", "median_s": f, "best_s": min(fit_s)},
            {"process": "the fit beyond torch's import", "median_s": f - t, "best_s": min(fit_s) - min(torch_s)}]
    write_results(out_dir, "startup", "A small fit as a process", rows,
                  notes=f"{REPEAT} runs of each, alternating; wall time of the whole process, one torch thread. The "
                        "fit renders its input at 128 px, writes mesh.obj, mesh.glb, an overlay and loss.png.")
