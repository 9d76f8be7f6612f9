"""How long a proposal takes (issue #29: at most 20 ms per target on one thread): the shipped networks on
held-out samples' masks at 128 and 256 px, the whole of :meth:`ipm.proposals.Proposer.propose` (crop, network,
the most probable combinations), one torch thread, median and best of ``REPEAT`` calls per mask after one warm-up.

``python -m benchmarks.run results/perf proposals`` (seconds).
"""

from __future__ import annotations

import statistics
import time
from pathlib import Path

import numpy as np
import torch

from benchmarks.common import write_results

REPEAT = 20


def run(out_dir: Path) -> None:
    from ipm.generators import get_generator
    from ipm.proposals import load_proposer, shipped
    from ipm.proposals.data import render_sample, sample_values
    from ipm.proposals.train import HELDOUT_SEED
    from ipm.render.camera import orbit_camera

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    rows = []
    try:
        for name in sorted(shipped()):
            gen = get_generator(name)
            proposer = load_proposer(gen)
            rng = np.random.default_rng(HELDOUT_SEED)
            for size in (128, 256):
                mask = None
                while mask is None:
                    mask = render_sample(gen, sample_values(gen, rng), 40.0, 25.0, 3.2, size=size)
                cam = orbit_camera(30.0, 25.0, 3.2, width=size)
                proposer.propose(mask, cam)
                times = []
                for _ in range(REPEAT):
                    t0 = time.perf_counter()
                    proposer.propose(mask, cam)
                    times.append((time.perf_counter() - t0) * 1000)
                rows.append({"generator": name, "mask_px": size, "median_ms": statistics.median(times),
                             "best_ms": min(times), "threads": 1})
    finally:
        torch.set_num_threads(threads)
    write_results(out_dir, "proposals", "Proposal inference per target", rows,
                  notes="The whole proposal: crop and resample the mask, the network, the most probable "
                        "combinations of the discrete heads. One torch thread.")
