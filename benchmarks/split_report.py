"""Tune against validation (issue #34): the public table's two splits side by side, per class and number of
views, and the issue's checks on the validation split, read from the rows the bench wrote.

Reads ``results/table1/rows.jsonl`` (``make table1``: the tune split), ``results/table_validation/rows.jsonl``
(``make table-validation``) and, for the teapot's 8-view bound, ``results/table_coverage/rows.jsonl``; classes
come from ``experiments/table1.toml``. Writes ``results/split.md`` and ``.json``.

Usage: ``python -m benchmarks.split_report [RESULTS_DIR]``.
"""

from __future__ import annotations

import json
import statistics
import sys
from pathlib import Path

from benchmarks import common
from benchmarks.draw_split import EXPERIMENT

VESSELS = ("mug", "bowl", "plate", "pitcher", "bottle", "vase")
FURNITURE = ("chair", "table")


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


def checks(val: list[dict], coverage: list[dict], classes: dict[str, str]) -> list[str]:
    """The issue's done-when lines on the validation split, each with the numbers it rests on."""
    def group(names):
        return sorted({r["target"] for r in val if classes.get(r["target"]) in names})

    lines = []
    vessels, buildings, furniture = group(VESSELS), group(("building",)), group(FURNITURE)
    for k, need in ((1, 0.92), (2, 0.96)):
        m = _mean([_iou(val, t, "ipm", k) for t in vessels])
        lines.append(f"- vessels (n {len(vessels)}), K = {k}: {m} (asked >= {need})")
    for k, need in ((1, 0.85), (2, 0.92)):
        m = _mean([_iou(val, t, "ipm", k) for t in buildings])
        lines.append(f"- buildings (n {len(buildings)}), K = {k}: {m} (asked >= {need})")
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
    rows = per_class(tune, val, classes)
    notes = ("Held-out IoU of the generator fits (seed 0; for chairs and tables the better of the fixed tree, "
             "`ipm`, and the structure search, `structure`), mean over each split's targets of the class; tune: "
             "`make table1`, validation: `make table-validation` (experiments/table1.toml, split drawn by "
             "benchmarks/draw_split.py). The issue asks validation within 0.03 of tune per class at K = 1 and 2.\n\n"
             "Checks on the validation split (protocol v2, budget 500):\n\n"
             + "\n".join(checks(val, coverage, classes)))
    common.write_results(out, "split", "Tune against validation (issue #34)", rows, notes)


if __name__ == "__main__":
    main()
