"""``results/proposals.md``: the shipped proposal networks (issue #29) in numbers, from the committed code and weights.

1. Each head on 200 held-out generator samples (:data:`ipm.proposals.train.HELDOUT_SEED`'s stream, which no
   training run draws): every discrete head's accuracy beside chance (its most frequent value), the continuous
   parameters' mean absolute error beside guessing their mean, the yaw within one bin beside chance.
2. ``results/table_proposals`` (the network's guess alone, scored as a K = 1 cell) and ``results/table_init``
   (K = 1 fits started from the presets, the proposals or both), summarized per generator and per target.
3. The pace of those fits: the evaluations each needed to first come within 0.01 of its final mask IoU on the
   input view (the rows' ``evals_to_final``, :func:`ipm.bench.methods.ipm.evaluations_to_final`), per target
   the median over the seeds, and the median over the targets of the presets' count over each start's.

``python -m benchmarks.proposal_report`` (about two minutes; run ``make table-proposals table-init`` first).
"""

from __future__ import annotations

import collections
import json
import statistics
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
HELD_OUT = 200


def _heads() -> list[str]:
    from ipm.generators import get_generator
    from ipm.proposals import shipped
    from ipm.proposals.data import make_samples
    from ipm.proposals.net import load_weights
    from ipm.proposals.train import HELDOUT_SEED, evaluate

    lines = ["## Each head on held-out generator samples", "",
             f"{HELD_OUT} samples per generator from the held-out seed's stream; accuracy against always guessing the "
             "most frequent value.", ""]
    for name, path in shipped().items():
        gen = get_generator(name)
        net, extra = load_weights(path, gen)
        s = evaluate(net, make_samples(gen, HELD_OUT, HELDOUT_SEED))
        train = json.loads(str(extra["settings"]))
        lines += [f"### {name} ({train['samples']} training renders, {train['steps']} steps, "
                  f"{sum(p.numel() for p in net.parameters()):,} weights)", "",
                  "| head | accuracy | chance |", "|---|---|---|"]
        lines += [f"| {h} | {v['accuracy']:.3f} | {v['chance']:.3f} |" for h, v in s["discrete"].items()]
        lines += [f"| yaw within 15 deg | {s['yaw_within_one_bin']:.3f} | {s['yaw_chance']:.3f} |", "",
                  f"Continuous parameters: mean absolute error {s['continuous_mae']:.4f} (normalized units) against "
                  f"{s['continuous_mae_of_the_mean']:.4f} for always guessing their mean.", ""]
    return lines


def _rows(folder: str) -> list[dict]:
    """The folder's rows in its experiment's cell order (a resumed run appends the cells it ran again)."""
    path = ROOT / "results" / folder / "rows.jsonl"
    if not path.is_file():
        return []
    rows = [json.loads(line) for line in path.read_text().splitlines()]
    exp = path.parent / "experiment.json"
    order = {key: i for i, key in enumerate(json.loads(exp.read_text())["cells"])} if exp.is_file() else {}
    return sorted(rows, key=lambda r: order.get(r.get("key"), len(order)))


def _tables() -> list[str]:
    lines = ["## The guess alone (results/table_proposals)", "",
             "| generator | targets | held-out IoU mean | median | discrete accuracy | parameter error |",
             "|---|---|---|---|---|---|"]
    rows = [r for r in _rows("table_proposals") if r.get("status") == "ok"]
    for g in sorted({r["target"].rsplit("_", 1)[0] for r in rows}):
        rs = [r for r in rows if r["target"].rsplit("_", 1)[0] == g]
        iou = [r["heldout_iou"] for r in rs]
        lines.append(f"| {g} | {len(rs)} | {statistics.mean(iou):.3f} | {statistics.median(iou):.3f} | "
                     f"{statistics.mean(r['discrete_accuracy'] for r in rs):.3f} | "
                     f"{statistics.mean(r['param_error'] for r in rs):.3f} |")
    by = collections.defaultdict(lambda: collections.defaultdict(list))
    for r in _rows("table_init"):
        by[r["target"]][r["method"]].append(r["heldout_iou"])
    methods = ["ipm-presets", "ipm-learned", "ipm-both"]
    lines += ["", "## Where a K = 1 fit starts (results/table_init; mean of seeds 0, 1, 2)", "",
              "| target | " + " | ".join(methods) + " |", "|---" * (len(methods) + 1) + "|"]
    for t, m in by.items():
        lines.append(f"| {t} | " + " | ".join(f"{statistics.mean(m[k]):.3f}" for k in methods) + " |")
    if by:
        lines.append("| mean | " + " | ".join(f"{statistics.mean(statistics.mean(by[t][k]) for t in by):.3f}"
                                             for k in methods) + " |")
    return lines + _pace(methods)


def _pace(methods: list[str]) -> list[str]:
    """Section 3 of the module docstring (empty where the rows predate ``evals_to_final``)."""
    by = collections.defaultdict(lambda: collections.defaultdict(list))
    for r in _rows("table_init"):
        if r.get("evals_to_final") is not None:
            by[r["target"]][r["method"]].append(r["evals_to_final"])
    by = {t: m for t, m in by.items() if all(m[k] for k in methods)}
    if not by:
        return []
    med = {t: {k: statistics.median(m[k]) for k in methods} for t, m in by.items()}
    lines = ["", "## How soon a K = 1 fit lands (results/table_init)", "",
             "Evaluations until the fit first comes within 0.01 of its final mask IoU on the input view (median of "
             "seeds 0, 1, 2; the budget is 500).", "",
             "| target | " + " | ".join(methods) + " |", "|---" * (len(methods) + 1) + "|"]
    for t, m in med.items():
        lines.append(f"| {t} | " + " | ".join(f"{m[k]:g}" for k in methods) + " |")
    lines.append("| median | " + " | ".join(f"{statistics.median(m[k] for m in med.values()):g}"
                                             for k in methods) + " |")
    for k in methods[1:]:
        ratio = statistics.median(m[methods[0]] / m[k] for m in med.values())
        lines.append(f"\nMedian over the {len(med)} targets of {methods[0]}'s count over {k}'s: {ratio:.2f}x.")
    return lines


def main() -> int:
    from benchmarks.common import machine
    from ipm.files import write_text

    lines = ["# Learned proposals (issue #29)", "", f"Machine: {machine()}  ",
             "Command: `python -m benchmarks.proposal_report`", "", *_heads(), *_tables()]
    write_text(ROOT / "results" / "proposals.md", "\n".join(lines) + "\n")
    print(ROOT / "results" / "proposals.md")
    return 0


if __name__ == "__main__":
    sys.exit(main())
