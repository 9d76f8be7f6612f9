"""Five reference fits whose records must not change when the fit's code is reorganized (issue #33).

The 2-view dishes mug of the demo (200 evaluations), the building whose floors and windows are read off part
labels (enumerate, 400 evaluations), the photo + depth mug (1000), the structure search on the real armchair
(the demo's, 8000) and the 2D profile of the real bottle (the demo's). Each gives a fingerprint (a hash of its
records without their times: every evaluation's point, loss, gradient and extras; for the structure search
every tree tried and the tree found; for the profile the fitted tree) and its final numbers.

``python -m benchmarks.reference_fits [--write]`` runs them and prints the fingerprints (about 1.5 minutes on one
thread); ``--write`` stores them in ``tests/data/reference_fits.json`` with the machine they were made on.
``tests/test_reference_fits.py`` runs them again: on that same machine (CPU, torch build and its SIMD path)
the fingerprints must match bit for bit; elsewhere the last bits differ (results/perturbation.md), and the
final numbers must agree within the perturbation tolerance.
"""

from __future__ import annotations

import hashlib
import json
import platform
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
STORED = ROOT / "tests" / "data" / "reference_fits.json"


def machine() -> str:
    """What decides the last bits: the CPU (vendor and model), the machine type, torch's version and the SIMD
    path its kernels chose."""
    import torch

    cpu = {}
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            key, _, value = line.partition(":")
            if key.strip() in ("vendor_id", "model name") and key.strip() not in cpu:
                cpu[key.strip()] = value.strip()
    except OSError:
        pass
    return " | ".join([cpu.get("vendor_id", "?"), cpu.get("model name", "?"), platform.machine(), torch.__version__,
                       torch.backends.cpu.get_cpu_capability()])


def _records(path: Path, drop=("t", "wall_time_s", "seconds")) -> str:
    rows = []
    for line in Path(path).read_text().splitlines():
        r = json.loads(line)
        for k in drop:
            r.pop(k, None)
        rows.append(r)
    return json.dumps(rows, sort_keys=True)


def _hash(*texts: str) -> str:
    return hashlib.sha256("\0".join(texts).encode()).hexdigest()[:16]


def run_all(out: Path) -> dict:
    """``{name: {"fingerprint", "final": {number: value}}}`` of the five reference fits, run into ``out``."""
    import torch

    import ipm
    from benchmarks.common import render_counts_target
    from benchmarks.perturbation import COUNTS_FIXED
    from ipm import data as D
    from ipm import showcase

    torch.set_num_threads(1)
    res = {}
    mug = showcase.fit_real_mug(out, 200, 128)
    res["mug"] = {"fingerprint": _hash(_records(out / "mug_fit" / "trajectory.jsonl")),
                  "final": {"heldout_iou": mug["heldout_iou_mean"]}}
    masks = out / "M"
    render_counts_target(masks)
    counts = ipm.fit("building", masks=masks, parts=masks, preset="panel5", discrete="enumerate",
                     ranges={"floors": [4, 10], "windows": [2, 6]}, fix=COUNTS_FIXED, seed=0, budget=400,
                     run_dir=out / "counts")
    res["counts"] = {"fingerprint": _hash(_records(out / "counts" / "trajectory.jsonl")),
                     "final": {"iou": counts.scores["iou_mean"], "floors": counts.params["floors"],
                               "windows": counts.params["windows"]}}
    photo = ipm.fit("dishes", image=D.path(D.PHOTO), box=D.PHOTO_BOX, depth=D.path(D.PHOTO_DEPTH),
                    intrinsics=D.path(D.PHOTO_INTRINSICS), photo_size=128, preset="mug", budget=1000, polish=0.4,
                    discrete="enumerate", image_weight=0.0, seed=0, run_dir=out / "photo")
    res["photo"] = {"fingerprint": _hash(_records(out / "photo" / "trajectory.jsonl")),
                    "final": {"photo_iou": photo.scores["photo_iou"], "has_handle": photo.params["has_handle"]}}
    st = showcase.structure_showcase(out)
    tree = json.loads((out / "structure" / "tree.json").read_text())["tree"]
    inner = tree["children"][0] if tree.get("node") == "place" else tree
    res["structure"] = {"fingerprint": _hash(_records(out / "structure" / "structures.jsonl"),
                                             json.dumps(inner, sort_keys=True)),
                        "final": {"heldout_iou": st["heldout_iou"], "nodes": st["nodes"]}}
    cv = showcase.curves_showcase(out)
    res["profile"] = {"fingerprint": _hash((out / "curves" / "bottle_lifted.json").read_text()),
                      "final": {"profile_iou": cv["profile_iou"]}}
    return res


def main(argv=None) -> None:
    args = sys.argv[1:] if argv is None else argv
    with tempfile.TemporaryDirectory() as tmp:
        res = run_all(Path(tmp))
    print(json.dumps(res, indent=1))
    if "--write" in args:
        from ipm.files import write_text

        write_text(STORED, json.dumps({"machine": machine(), "fits": res}, indent=1) + "\n")
        print(f"wrote {STORED}")


if __name__ == "__main__":
    main()
