"""Shared benchmark helpers: timing, machine description, result files."""

from __future__ import annotations

import datetime as _dt
import json
import os
import platform
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import torch

COMMAND = "make bench"


def machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return (f"{cpu}, {os.cpu_count()} cores, torch {torch.__version__} "
            f"({torch.get_num_threads()} threads), Python {platform.python_version()}")


def commit() -> str:
    """The repository's short commit, with " (plus uncommitted changes)" when ``ipm`` or ``benchmarks`` differ
    from it."""
    import subprocess

    root = Path(__file__).resolve().parents[1]
    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=root)
    dirty = subprocess.run(["git", "status", "--porcelain", "--", "ipm", "benchmarks"], capture_output=True,
                           text=True, cwd=root)
    return head.stdout.strip() + (" (plus uncommitted changes)" if dirty.stdout.strip() else "")


def timings(fn: Callable[[], object], repeat: int = 7, warmup: int = 1) -> tuple[float, float]:
    """(median, best) wall time of ``fn`` in seconds (other jobs on a shared machine only ever add
    time, so the best is the stable statistic there)."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), min(times)


def paired_timings(fns: dict[str, Callable[[], object]], repeat: int = 9) -> dict[str, tuple[float, float]]:
    """(median, best) wall time in seconds of each of ``fns``, called in turn in every repeat (after one
    warm-up call each), so that changes in the machine's load fall on all of them alike."""
    for fn in fns.values():
        fn()
    times: dict[str, list[float]] = {k: [] for k in fns}
    for _ in range(repeat):
        for k, fn in fns.items():
            t0 = time.perf_counter()
            fn()
            times[k].append(time.perf_counter() - t0)
    return {k: (statistics.median(t), min(t)) for k, t in times.items()}


def timeit(fn: Callable[[], object], repeat: int = 7, warmup: int = 1) -> float:
    """Median wall time of ``fn`` in seconds."""
    return timings(fn, repeat, warmup)[0]


def write_results(out_dir: Path, name: str, title: str, rows: list[dict], notes: str = "") -> None:
    """Write ``<name>.json`` and a Markdown table ``<name>.md`` with machine, date, load average, commit and
    command."""
    from ipm.files import write_text

    out_dir.mkdir(parents=True, exist_ok=True)
    meta = {"machine": machine(), "date": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
            "command": COMMAND, "commit": commit(), "load_average": [round(x, 2) for x in os.getloadavg()]}
    write_text(out_dir / f"{name}.json", json.dumps({"meta": meta, "rows": rows}, indent=2) + "\n")
    cols = list(rows[0]) if rows else []
    lines = [f"# {title}", "", f"Machine: {meta['machine']}  ", f"Date: {meta['date']}  ",
             f"Load average (1, 5, 15 min) when written: {', '.join(map(str, meta['load_average']))}  ",
             f"Commit: {meta['commit']}  ", f"Command: `{COMMAND}`", ""]
    if notes:
        lines += [notes, ""]
    lines += ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for r in rows:
        lines.append("| " + " | ".join(_fmt(r[c]) for c in cols) + " |")
    write_text(out_dir / f"{name}.md", "\n".join(lines) + "\n")


def _fmt(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def render_counts_target(masks: Path) -> Path:
    """The building counts case's target (``tests/test_stability_counts.py``, the reference fits): ``ipm render``
    of panel5 with 7 floors and 4 windows, one 160 px view with depth and part labels, into ``masks``."""
    from ipm.cli import main

    try:
        main(["render", "building", "--preset", "panel5", "--set", "floors=7", "--set", "windows=4", "--views", "1",
              "--size", "160", "--no-previews", "-q", "-o", str(masks)])
    except SystemExit as e:
        if e.code:
            raise RuntimeError(f"ipm render exited {e.code}") from None
    return masks
