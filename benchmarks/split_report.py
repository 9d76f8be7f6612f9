"""Tune against validation (issue #34): the public table's two splits side by side, per class and number of
views, and the issue's checks on the validation split, read from the rows the bench wrote.

Reads ``results/table1/rows.jsonl`` (``make table1``: the tune split), ``results/table_validation/rows.jsonl``
(``make table-validation``), for the teapot's 8-view bound ``results/table_coverage/rows.jsonl`` and for the
validation targets' 8-view fits ``results/coverage_validation/rows.jsonl``; classes come from
``experiments/table1.toml``. Writes ``results/split.md`` and ``.json``.

Beside the checks, :func:`split_chance`: how often the per-class check (validation within 0.03 of tune) would
hold if the same fits had been split otherwise, over every way of drawing each class's split with the sizes it
has: with one to nine targets a side (most classes one to three), the gap between two halves measures which objects
fell where as much as any tuning.

Usage: ``python -m benchmarks.split_report [RESULTS_DIR]``.
"""

from __future__ import annotations

import itertools
import json
import math
import statistics
import sys
from pathlib import Path

from benchmarks import common
from benchmarks.draw_split import EXPERIMENT

VESSELS = ("mug", "bowl", "plate", "pitcher", "bottle", "vase")
FURNITURE = ("chair", "table")
GAP = 0.03   # the per-class check: validation within this of tune at K = 1 and 2


def _rows(path: Path) -> list[dict]:
    if not path.is_file():
        return []
    return [r for r in map(json.loads, path.read_text().splitlines()) if r.get("status") == "ok"]


def _iou(rows: list[dict], target: str, method: str, views: int, seed: int | None = 0) -> float | None:
    """The held-out IoU of one cell (``seed=None``: the mean over the seeds there are)."""
    vals = [r["heldout_iou"] for r in rows if (r["target"], r["method"], r["views"]) == (target, method, views)
            and (seed is None or r["seed"] == seed)]
    return statistics.fmean(vals) if vals else None


def _generator_iou(rows: list[dict], target: str, views: int) -> float | None:
    """The generator fit's IoU: ``ipm``, or for furniture the better of ``ipm`` and ``structure`` (seed 0)."""
    vals = [v for v in (_iou(rows, target, m, views) for m in ("ipm", "structure")) if v is not None]
    return max(vals) if vals else None


def _r(v: float | None) -> float | None:
    return None if v is None else round(v, 3)


def _mean(vals: list[float | None]) -> float | None:
    vals = [v for v in vals if v is not None]
    return round(statistics.fmean(vals), 3) if vals else None


def per_class(tune: list[dict], val: list[dict], classes: dict[str, str]) -> list[dict]:
    """One row per class and K: the generator fit's mean over each split's targets, and the gap."""
    out = []
    for cls in sorted(set(classes.values())):
        for k in (1, 2, 4):
            row = {"class": cls, "K": k}
            for name, rows in (("tune", tune), ("validation", val)):
                targets = sorted({r["target"] for r in rows if classes.get(r["target"]) == cls})
                row[name] = _mean([_generator_iou(rows, t, k) for t in targets])
                row[f"n {name}"] = len(targets)
            gap = None if None in (row["tune"], row["validation"]) else round(row["validation"] - row["tune"], 3)
            row["validation - tune"] = gap
            out.append(row)
    return out


def split_chance(tune: list[dict], val: list[dict], classes: dict[str, str], gap: float = GAP) -> list[dict]:
    """Per class with targets on both sides: the share of all re-splits of its targets (same sizes a side, the
    same fits) in which validation is within ``gap`` of tune at K = 1 and 2 (``both ways``), and in which it is
    not below tune by more than ``gap`` (``not below``); exact, by enumeration. The last row: all classes at
    once (the product: each class is split on its own)."""
    out, exact = [], []
    for cls in sorted(set(classes.values())):
        sides = [sorted({r["target"] for r in rows if classes.get(r["target"]) == cls}) for rows in (tune, val)]
        if not all(sides):
            continue
        scores = {t: [_generator_iou(rows, t, k) for k in (1, 2)] for side, rows in zip(sides, (tune, val))
                  for t in side}
        pool, n_tune = sorted(scores), len(sides[0])
        if any(v is None for vs in scores.values() for v in vs):
            continue
        both = not_below = 0
        splits = list(itertools.combinations(pool, n_tune))
        for first in splits:
            second = [t for t in pool if t not in first]
            gaps = [statistics.fmean(scores[t][i] for t in second) - statistics.fmean(scores[t][i] for t in first)
                    for i in (0, 1)]
            both += all(abs(g) <= gap for g in gaps)
            not_below += all(g >= -gap for g in gaps)
        exact.append((both / len(splits), not_below / len(splits)))
        out.append({"class": cls, "n tune": n_tune, "n validation": len(pool) - n_tune, "splits": len(splits),
                    "both ways": round(exact[-1][0], 3), "not below": round(exact[-1][1], 3)})
    out.append({"class": "all at once", "n tune": sum(r["n tune"] for r in out),
                "n validation": sum(r["n validation"] for r in out), "splits": math.prod(r["splits"] for r in out),
                "both ways": round(math.prod(b for b, _ in exact), 4),
                "not below": round(math.prod(n for _, n in exact), 4)})
    return out


def _chance_table(rows: list[dict]) -> str:
    head = f"| class | n tune | n validation | re-splits | within {GAP} both ways | validation not below by more |"
    lines = [head, "|---|---|---|---|---|---|"]
    lines += [f"| {r['class']} | {r['n tune']} | {r['n validation']} | {r['splits']} | {r['both ways']} | "
              f"{r['not below']} |" for r in rows]
    return "\n".join(lines)


def checks(val: list[dict], coverage: list[dict], classes: dict[str, str],
           coverage_val: list[dict] = ()) -> list[str]:
    """The issue's done-when lines on the validation split, each with the numbers it rests on (and, for the
    bars at K = 2, what the same targets' four- and eight-view fits reach)."""
    def group(names):
        return sorted({r["target"] for r in val if classes.get(r["target"]) in names})

    def more_views(targets):
        k4 = _mean([_iou(val, t, "ipm", 4) for t in targets])
        k8 = _mean([_iou(coverage_val, t, "ipm-bound", 8) for t in targets])
        return f"; the same targets from 4 views {k4}, from 8 views (coverage_validation) {k8}"

    lines = []
    vessels, buildings, furniture = group(VESSELS), group(("building",)), group(FURNITURE)
    for k, need in ((1, 0.92), (2, 0.96)):
        m = _mean([_iou(val, t, "ipm", k) for t in vessels])
        lines.append(f"- vessels (n {len(vessels)}), K = {k}: {m} (asked >= {need})"
                     + (more_views(vessels) if k == 2 else ""))
    for k, need in ((1, 0.85), (2, 0.92)):
        m = _mean([_iou(val, t, "ipm", k) for t in buildings])
        lines.append(f"- buildings (n {len(buildings)}), K = {k}: {m} (asked >= {need})"
                     + (more_views(buildings) if k == 2 else ""))
    ipm4 = _mean([_iou(val, t, "ipm", 4) for t in buildings])
    md4 = _mean([_iou(val, t, "mesh-deform", 4) for t in buildings])
    lines.append(f"- buildings, K = 4: ipm {ipm4} against mesh-deform {md4} (asked: above)")
    for t in furniture:
        g, vh = _r(_generator_iou(val, t, 4)), _r(_iou(val, t, "visual-hull", 4))
        lines.append(f"- {t} ({classes[t]}), K = 4: generator fit {g} (ipm {_r(_iou(val, t, 'ipm', 4))}, structure "
                     f"{_r(_iou(val, t, 'structure', 4))}) against the 4-view visual hull {vh} (asked: above)")
    below = [f"{t} {_iou(val, t, 'ipm', 1):.3f} < {_iou(val, t, 'visual-hull', 1):.3f}"
             for t in sorted({r["target"] for r in val})
             if None not in (_iou(val, t, "ipm", 1), _iou(val, t, "visual-hull", 1))
             and _iou(val, t, "ipm", 1) < _iou(val, t, "visual-hull", 1)]
    lines.append(f"- validation targets below the 1-view visual hull at K = 1: {', '.join(below) or 'none'}")
    spreads = {}
    for t in sorted({r["target"] for r in val}):
        s = [r["heldout_iou"] for r in val if (r["target"], r["method"], r["views"]) == (t, "ipm", 1)]
        if len(s) >= 3:
            spreads[t] = max(s) - min(s)
    wide = [f"{t} {v:.3f}" for t, v in spreads.items() if v > 0.01]
    lines.append(f"- seed spread at K = 1 (seeds 0, 1, 2) above 0.01: {', '.join(wide) or 'none'} "
                 f"(largest {max(spreads.values(), default=0.0):.3f})")
    bound = _iou(coverage, "teapot", "ipm-bound", 8)
    k1 = _iou(coverage, "teapot", "ipm", 1, None)
    lines.append(f"- the teapot (tune), K = 1 (mean of 3 seeds, table_coverage): {_r(k1)} against its 8-view bound "
                 f"{_r(bound)} (asked: within 0.03)")
    return lines


def main(argv: list[str] | None = None) -> None:
    from ipm.bench.config import load_experiment

    argv = sys.argv[1:] if argv is None else argv
    out = Path(argv[0]) if argv else Path("results")
    common.COMMAND = "python -m benchmarks.split_report " + " ".join(argv)
    classes = {t.name: t.cls for t in load_experiment(EXPERIMENT).targets}
    tune, val = _rows(out / "table1" / "rows.jsonl"), _rows(out / "table_validation" / "rows.jsonl")
    coverage = _rows(out / "table_coverage" / "rows.jsonl")
    coverage_val = _rows(out / "coverage_validation" / "rows.jsonl")
    rows = per_class(tune, val, classes)
    notes = ("Held-out IoU of the generator fits (seed 0; for chairs and tables the better of the fixed tree, "
             "`ipm`, and the structure search, `structure`), mean over each split's targets of the class; tune: "
             "`make table1`, validation: `make table-validation` (experiments/table1.toml, split drawn by "
             "benchmarks/draw_split.py). The issue asks validation within 0.03 of tune per class at K = 1 and 2.\n\n"
             "Checks on the validation split (protocol v2, budget 500):\n\n"
             + "\n".join(checks(val, coverage, classes, coverage_val))
             + "\n\nThe per-class check by chance: had the same fits been split otherwise (every way of drawing each "
             "class's targets into halves of the sizes it has, the tune split's own targets included), the share of "
             "splits in which it holds at K = 1 and 2 (`split_chance`):\n\n"
             + _chance_table(split_chance(tune, val, classes)))
    common.write_results(out, "split", "Tune against validation (issue #34)", rows, notes)


if __name__ == "__main__":
    main()
