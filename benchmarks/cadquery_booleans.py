"""How often OpenCascade's booleans give the right solid for a CadQuery program of an SDF tree.

The targets of :mod:`benchmarks.program_exports` (the tree presets and the searched trees of the structure
table), the ten random 3-part truth trees and twenty random 5-part trees of
:func:`benchmarks.table_structure.make_random`, and 120 random 5-part trees whose sizes and centers lie on a
0.1 and 0.05 grid (:func:`grid_tree`): there boxes, cylinders and spheres touch or are tangent as in designed
models, where OpenCascade's booleans fail. Each program is run and scored by
:func:`benchmarks.program_exports.score` (volume IoU against the exact mesh at 128 segments): it matches
(IoU >= 0.99), is wrong, fails (the program raises, or its STL is not closed and manifold) or is refused.

Usage: ``python -m benchmarks.cadquery_booleans OUT_DIR [NAME]``: writes ``NAME.json`` and ``NAME.md``
(NAME: ``cadquery_booleans``).
"""

from __future__ import annotations

import json
import sys
from collections import Counter
from pathlib import Path

import numpy as np

from benchmarks.common import commit, machine

MATCH = 0.99
GRID_TREES = 120


def grid_tree(n: int, seed: int) -> dict:
    """A random tree of ``n`` parts (:func:`benchmarks.table_structure.random_tree`), its full sizes rounded to
    multiples of 0.1 and its centers to multiples of 0.05, so that faces meet and surfaces are tangent."""
    from benchmarks.table_structure import random_tree

    return random_tree(n, np.random.default_rng([77, n, seed]), snap=(0.1, 0.05))


def groups() -> dict[str, list[tuple[str, object]]]:
    """``{group: [(target name, SdfTreeGenerator)]}``."""
    from benchmarks.program_exports import targets
    from benchmarks.table_structure import make_random
    from ipm.generators.sdftree import SdfTreeGenerator

    def gen(tree: dict):
        from ipm.sdf.tree import tree_from_json

        return SdfTreeGenerator(tree_from_json({"tree": tree}))

    return {"program_exports targets": targets()[0],
            "random 3 parts": [(f"random 3 parts #{s}", gen(make_random(3, s))) for s in range(10)],
            "random 5 parts": [(f"random 5 parts #{s}", gen(make_random(5, s))) for s in range(20)],
            "grid 5 parts": [(f"grid 5 parts #{s}", gen(grid_tree(5, s))) for s in range(GRID_TREES)]}


def verdict(row: dict) -> str:
    """``match``, ``wrong``, ``failed`` or ``refused``."""
    if "iou" in row:
        return "match" if row["iou"] >= MATCH else "wrong"
    return "failed" if "failed" in row else "refused"


def run(out_dir: Path, name: str = "cadquery_booleans") -> dict:
    """Score every target's CadQuery program; write ``name.json`` and ``name.md`` in ``out_dir``."""
    from benchmarks.program_exports import FINE, RESOLUTION, score
    from ipm.sdf.exact import exact_mesh

    out_dir.mkdir(parents=True, exist_ok=True)
    rows, found_groups = [], groups()
    for group, found in found_groups.items():
        for target, g in found:
            tree = g.sdf_tree(g.spec.defaults())
            row = score(tree, ".py", reference=exact_mesh(tree, segments=FINE, resolution=RESOLUTION).mesh)
            rows.append({"group": group, "target": target, "verdict": verdict(row), **row})
            print(json.dumps(rows[-1]), file=sys.stderr, flush=True)
    counts = {g: dict(Counter(r["verdict"] for r in rows if r["group"] == g)) for g in found_groups}
    (out_dir / f"{name}.json").write_text(json.dumps({"counts": counts, "rows": rows}, indent=1) + "\n")
    (out_dir / f"{name}.md").write_text(report(counts, rows, name))
    return counts


def report(counts: dict, rows: list[dict], name: str) -> str:
    """Counts per group, then every target that did not match."""
    lines = [f"# CadQuery programs: OpenCascade's booleans ({name})", "",
             f"`python -m benchmarks.cadquery_booleans {{OUT_DIR}} {name}`. Machine: {machine()}; commit {commit()}.",
             "", "| targets | match (IoU >= 0.99) | wrong | failed | refused |", "|---|---|---|---|---|"]
    for group, c in counts.items():
        lines.append(f"| {group} ({sum(c.values())}) | {c.get('match', 0)} | {c.get('wrong', 0)} | "
                     f"{c.get('failed', 0)} | {c.get('refused', 0)} |")
    lines += ["", "Not matching:", ""]
    lines += [f"- {r['target']}: {r['verdict']} ({r.get('iou', r.get('failed', r.get('refused')))})" for r in rows
              if r["verdict"] not in ("match", "refused")] or ["- none"]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    import torch

    torch.set_num_threads(1)
    run(Path(sys.argv[1]) if len(sys.argv) > 1 else Path("results/exports"),
        sys.argv[2] if len(sys.argv) > 2 else "cadquery_booleans")
