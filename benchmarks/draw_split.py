"""How the tune / validation split of ``experiments/table1.toml`` was drawn (issue #34), and its check.

The public real set had been tuned on for seventeen of its meshes (every table before the split used only
those: :data:`TUNED_BEFORE`). A validation split that holds any of them would not estimate how the fits do on
a user's objects, so the validation targets are drawn from the other files only: per class, half of the
class's targets (rounded up), or all of its never-used files when there are fewer, taken from a shuffle of
the never-used targets' names (sorted first) by ``random.Random(f"{SEED}:{class}")``. Every other target is
in ``tune``.

``python -m benchmarks.draw_split`` prints the draw and whether the file's ``split`` keys agree with it;
``tests/test_split.py`` fails when they do not, so the split cannot drift with tuning."""

from __future__ import annotations

import random
import sys
from collections import defaultdict
from pathlib import Path

SEED = 34
EXPERIMENT = Path(__file__).resolve().parent.parent / "experiments" / "table1.toml"
# the mesh files every table before issue #34 used (the fits were tuned on them)
TUNED_BEFORE = frozenset({
    "vessels/ocrtoc_mug.ply", "vessels/probcomp_mug.obj", "vessels/ocrtoc_bowl.ply", "vessels/ocrtoc_plate.ply",
    "vessels/ocrtoc_pitcher.ply", "vessels/trimesh_teapot.stl", "vessels/trimesh_fuze_bottle.obj",
    "vessels/compas_simple_vase_open.stl", "buildings/denhaag_B06DD5CD_lod2.obj",
    "buildings/rotterdam_F4B0DABD_lod2.obj", "buildings/denhaag_999_0170_lod2.obj",
    "buildings/denhaag_84A7976B_lod2.obj", "buildings/3dbag_0503100000031927_lod22.obj",
    "buildings/rotterdam_AB05BE98_lod2.obj", "furniture/kaolin_armchair.obj", "furniture/trimesh_egg_chair.obj",
    "furniture/trimesh_side_table.obj"})


def _data_file(mesh: str) -> str:
    """``vessels/x.ply`` from ``../shared/data/real/vessels/x.ply``."""
    parts = Path(mesh).parts
    return "/".join(parts[-2:])


def draw(targets) -> dict[str, str]:
    """``{target name: "tune" | "validation"}`` for the experiment's mesh targets (``TargetSpec``s)."""
    by_class: dict[str, list] = defaultdict(list)
    for t in targets:
        by_class[t.cls].append(t)
    out = {}
    for cls, ts in sorted(by_class.items()):
        fresh = sorted(t.name for t in ts if _data_file(t.mesh) not in TUNED_BEFORE)
        random.Random(f"{SEED}:{cls}").shuffle(fresh)
        chosen = set(fresh[:min(len(fresh), (len(ts) + 1) // 2)])
        out.update({t.name: "validation" if t.name in chosen else "tune" for t in ts})
    return out


def main() -> int:
    from ipm.bench.config import load_experiment

    exp = load_experiment(EXPERIMENT)
    drawn = draw(exp.targets)
    wrong = [t.name for t in exp.targets if t.split != drawn[t.name]]
    for cls in sorted({t.cls for t in exp.targets}):
        for split in ("tune", "validation"):
            names = [t.name for t in exp.targets if t.cls == cls and drawn[t.name] == split]
            print(f"{cls:9s} {split:10s} {len(names):2d}  {', '.join(names)}")
    if wrong:
        print(f"{EXPERIMENT.name}: split keys differ from the draw for {', '.join(wrong)}", file=sys.stderr)
        return 1
    print(f"{EXPERIMENT.name}: every split key agrees with the draw")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
