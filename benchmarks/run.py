"""Run every ``benchmarks/bench_*.py`` (each has ``run(out_dir)``) and write results under OUT_DIR.

Usage: ``python -m benchmarks.run [OUT_DIR] [NAME ...]`` (default ``results/perf``, all benchmarks).
"""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

import torch


def main() -> None:
    out = Path(sys.argv[1]) if len(sys.argv) > 1 else Path("results/perf")
    only = set(sys.argv[2:])
    torch.set_num_threads(2)
    here = Path(__file__).parent
    for path in sorted(here.glob("bench_*.py")):
        name = path.stem.removeprefix("bench_")
        if only and name not in only:
            continue
        print(f"== {name}", flush=True)
        importlib.import_module(f"benchmarks.{path.stem}").run(out)
        print(f"   wrote {out / (name + '.md')}", flush=True)


if __name__ == "__main__":
    main()
