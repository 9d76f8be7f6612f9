"""Does a fit's answer hinge on noise? Each case is run under perturbations that stand in for another machine.

Cases (issue #28): the photo + depth fit of the ClearGrasp mug (``photo``), the demo's 2-view fit of the real
mug scan (``demo_mug``), three cells of ``experiments/table1.toml`` at K = 1, seed 0 (``t1_bottle``,
``t1_building``, ``t1_cup``), and the building whose floor and window counts are read off part labels
(``counts``: panel5 with 7 floors and 4 windows, one view at 160 px, enumerate over floors 4-10, windows 2-6).

Variants, each in a fresh process:

- ``base``: the native soft-silhouette kernel, one torch thread;
- ``eager``: the pure-torch kernels instead of the native ones (``IPM_SOFT_BACKEND=eager`` for the soft
  silhouette, ``IPM_DEFERRED_BACKEND=eager`` for the deferred renderer of the depth and part-label cues);
- ``threads2``: two torch threads (another order of torch's parallel reductions), used even where the
  other core is busy (``ipm.threads`` would otherwise fall back to one);
- ``isa``: torch's kernels without SIMD (``ATEN_CPU_CAPABILITY=default``): another CPU's code path for every
  vectorized torch operation (exp, sums, ...);
- ``start``: every start of the fit moved by 1e-6 relative (:meth:`ipm.optim.problem.Problem.x0` scaled);
- ``target``: the target moved by 1e-6 relative (the cameras' eyes, or the photo's focal length).

A case is stable when every variant lands within ``TOLERANCE`` of the base on its scores and on the same
discrete values. ``python -m benchmarks.perturbation [-o results/perturbation.md] [--cases a,b]
[--variants a,b] [--workers N]`` (``make bench-perturbation``); ``--one CASE VARIANT`` runs one in this
process and prints its JSON (what the workers run).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from pathlib import Path

from ipm import data

ROOT = Path(__file__).resolve().parents[1]
DATA = data.root()
PHOTOS = DATA / data.PHOTOS
TABLE1 = ROOT / "experiments" / "table1.toml"
EPS = 1e-6
TOLERANCE = 0.005

VARIANTS: dict[str, dict] = {
    "base": {},
    "eager": {"env": {"IPM_SOFT_BACKEND": "eager", "IPM_DEFERRED_BACKEND": "eager"}},
    "threads2": {"env": {"IPM_THREADS": "2"}, "threads": 2},
    "isa": {"env": {"ATEN_CPU_CAPABILITY": "default"}},
    "start": {"start": EPS},
    "target": {"target": EPS},
}


def _moved_cameras(cams, eps: float):
    """Cameras whose eyes are moved by ``eps`` relative (the target seen from a hair further away)."""
    from dataclasses import replace

    return [replace(c, eye=c.eye * (1.0 + eps)) for c in cams]


@contextmanager
def applied(variant: str):
    """Run the block under ``variant`` (:data:`VARIANTS`) in this process, and undo it after: its environment
    (read at each render, so ``eager`` works in process; ``isa`` does not: torch reads it once, at start),
    its thread count (used even where the other core is busy), starts moved by ``start`` relative
    (:meth:`ipm.optim.problem.Problem.x0`, alternating in sign). Yields the target's relative move."""
    import torch

    from ipm import threads
    from ipm.optim.problem import Problem

    v = VARIANTS[variant]
    saved_env = {k: os.environ.get(k) for k in v.get("env", {})}
    saved = (threads.usable, Problem.x0, torch.get_num_threads())
    os.environ.update(v.get("env", {}))
    if v.get("threads", 1) > 1:
        threads.usable = lambda n: min(n, threads.cores())
    torch.set_num_threads(int(v.get("threads", 1)))
    if v.get("start"):
        eps, x0 = float(v["start"]), Problem.x0

        def moved(self, *a, **kw):
            x = x0(self, *a, **kw)
            sign = torch.ones_like(x)
            sign[1::2] = -1.0
            return (x * (1.0 + eps * sign)).clamp(0.0, 1.0)

        Problem.x0 = moved
    try:
        yield float(v.get("target", 0.0))
    finally:
        threads.usable, Problem.x0 = saved[0], saved[1]
        torch.set_num_threads(saved[2])
        for k, old in saved_env.items():
            if old is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = old


def case_photo(tmp: Path, target_eps: float) -> dict:
    import ipm

    intr = PHOTOS / "camera_intrinsics.yaml"
    if target_eps:
        import yaml

        k = yaml.safe_load(intr.read_text())
        k["fx"] = float(k["fx"]) * (1.0 + target_eps)
        intr = tmp / "intrinsics.yaml"
        intr.write_text(yaml.safe_dump(k))
    r = ipm.fit("dishes", image=PHOTOS / "000000130-opaque-rgb-img.jpg", box=(380, 255, 600, 495),
                depth=PHOTOS / "000000130-opaque-depth-mm.png", intrinsics=intr, photo_size=128, preset="mug",
                budget=1000, polish=0.4, discrete="enumerate", image_weight=0.0, seed=0, run_dir=tmp / "run")
    return {"scores": {"photo_iou": r.scores["photo_iou"], "depth_median_mm": r.scores["depth_median_mm"] / 1000},
            "discrete": {"has_handle": r.params["has_handle"]}, "loss": r.loss, "wall_time_s": r.wall_time_s}


def case_demo_mug(tmp: Path, target_eps: float) -> dict:
    from ipm import showcase

    return showcase.fit_real_mug(tmp, 200, 128, camera_eps=target_eps, scores_only=True)


def _table1_cell(target: str, target_eps: float) -> dict:
    from ipm.bench import harness as H
    from ipm.bench.config import Cell

    if target_eps:
        cams = H._input_cameras
        H._input_cameras = lambda exp, k: _moved_cameras(cams(exp, k), target_eps)
    row = H.run_cell(str(TABLE1), Cell(target, "ipm", 1, 0))
    return {"scores": {"heldout_iou": row["heldout_iou"]}, "discrete": row.get("discrete", {}), "loss": row.get("loss"),
            "wall_time_s": row["wall_time_s"]}


def case_t1_bottle(tmp: Path, target_eps: float) -> dict:
    return _table1_cell("bottle", target_eps)


def case_t1_building(tmp: Path, target_eps: float) -> dict:
    return _table1_cell("building", target_eps)


def case_t1_cup(tmp: Path, target_eps: float) -> dict:
    return _table1_cell("cup_1", target_eps)


COUNTS_FIXED = {"sections": 4, "balcony_pattern": 1, "roof_type": 0, "roof_axis": 0, "has_door": 1, "back_windows": 1,
                "wings": 0, "wing1_side": 0, "wing1_roof": 0, "wing2_side": 2, "wing2_roof": 0, "wing3_side": 1,
                "wing3_roof": 0, "roof_boxes": 0}


def case_counts(tmp: Path, target_eps: float) -> dict:
    """The issue's count case: ``ipm render building --preset panel5 --set floors=7 --set windows=4 --views 1
    --size 160``, then ``ipm fit building --preset panel5 --masks M --parts M --discrete enumerate --range
    floors=4:10 --range windows=2:6`` with the other discrete values fixed at panel5's."""
    import ipm
    from benchmarks.common import render_counts_target

    masks = tmp / "M"
    render_counts_target(masks)
    if target_eps:
        from ipm.files import write_text
        from ipm.render.camera import cameras_to_json, load_cameras

        cams = _moved_cameras(load_cameras(masks / "cameras.json"), target_eps)
        write_text(masks / "cameras.json", cameras_to_json(cams))
    r = ipm.fit("building", masks=masks, parts=masks, preset="panel5", discrete="enumerate",
                ranges={"floors": [4, 10], "windows": [2, 6]}, fix=COUNTS_FIXED, seed=0, run_dir=tmp / "run")
    return {"scores": {"iou": r.scores["iou_mean"]}, "discrete": {k: r.params[k] for k in ("floors", "windows")},
            "loss": r.loss, "wall_time_s": r.wall_time_s}


CASES = {name[5:]: fn for name, fn in dict(globals()).items() if name.startswith("case_")}


def run_one(case: str, variant: str) -> dict:
    """One case under one variant in this process (:func:`applied`; ``isa`` needs :func:`spawn`)."""
    from ipm import threads

    t0 = time.perf_counter()
    with applied(variant) as target_eps, tempfile.TemporaryDirectory() as tmp:
        out = CASES[case](Path(tmp), target_eps)
        used = threads.usable(threads.requested())
    out.update(case=case, variant=variant, seconds=round(time.perf_counter() - t0, 1), threads=used)
    return out


def spawn(case: str, variant: str) -> dict:
    """:func:`run_one` in a fresh process with the variant's environment."""
    env = {**os.environ, "PYTHONHASHSEED": "0", **VARIANTS[variant].get("env", {})}
    r = subprocess.run([sys.executable, "-m", "benchmarks.perturbation", "--one", case, variant], cwd=ROOT, env=env,
                       capture_output=True, text=True)
    if r.returncode != 0:
        return {"case": case, "variant": variant, "error": (r.stderr.strip().splitlines() or ["?"])[-1]}
    return json.loads(r.stdout.strip().splitlines()[-1])


def spread(rows: list[dict]) -> dict:
    """Per case: the largest distance of a variant's score from the base's, and whether the discrete values
    are all the base's."""
    out = {}
    for case in dict.fromkeys(r["case"] for r in rows):
        mine = [r for r in rows if r["case"] == case and "error" not in r]
        base = next((r for r in mine if r["variant"] == "base"), None)
        if base is None:
            continue
        worst = max((abs(r["scores"][k] - base["scores"][k]) for r in mine for k in base["scores"]), default=0.0)
        same = all(r["discrete"] == base["discrete"] for r in mine)
        ranges = {k: (min(r["scores"][k] for r in mine), max(r["scores"][k] for r in mine)) for k in base["scores"]}
        out[case] = {"max_deviation": worst, "same_discrete": same, "ranges": ranges,
                     "stable": worst <= TOLERANCE and same and len(mine) == sum(r["case"] == case for r in rows)}
    return out


def report(rows: list[dict], command: str, seconds: float) -> str:
    from benchmarks.common import machine

    lines = ["# Perturbations: does a fit's answer hinge on noise?", "",
             f"Command: `{command}` ({seconds / 60:.1f} min)  ", f"Machine: {machine()}  ",
             f"Date: {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}  ",
             f"Tolerance: every variant within {TOLERANCE} of the base on each score, the same discrete values.", "",
             "Variants: " + "; ".join(f"`{k}` {VARIANTS[k]}" for k in VARIANTS) + ".", "",
             "| case | variant | scores | discrete | loss | time (s) |", "|---|---|---|---|---|---|"]
    for r in rows:
        if "error" in r:
            lines.append(f"| {r['case']} | {r['variant']} | error: {r['error']} | | | |")
            continue
        sc = ", ".join(f"{k} {v:.4f}" for k, v in r["scores"].items())
        disc = ", ".join(f"{k}={v}" for k, v in r["discrete"].items()) or "-"
        loss = f"{r['loss']:.5f}" if r.get("loss") is not None else "-"
        lines.append(f"| {r['case']} | {r['variant']} | {sc} | {disc} | {loss} | {r['seconds']} |")
    lines += ["", "| case | largest deviation from base | same discrete values | stable |", "|---|---|---|---|"]
    for case, s in spread(rows).items():
        lines.append(f"| {case} | {s['max_deviation']:.4f} | {'yes' if s['same_discrete'] else 'NO'} | "
                     f"{'yes' if s['stable'] else 'NO'} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-o", "--out", default="results/perturbation.md")
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--variants", default=",".join(VARIANTS))
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--one", nargs=2, metavar=("CASE", "VARIANT"))
    a = ap.parse_args(argv)
    if a.one:
        print(json.dumps(run_one(*a.one)))
        return
    cases, variants = a.cases.split(","), a.variants.split(",")
    for c in cases:
        if c not in CASES:
            raise SystemExit(f"--cases: {c!r}: expected some of {', '.join(CASES)}")
    for v in variants:
        if v not in VARIANTS:
            raise SystemExit(f"--variants: {v!r}: expected some of {', '.join(VARIANTS)}")
    jobs = [(c, v) for c in cases for v in variants]
    t0 = time.perf_counter()
    with ThreadPoolExecutor(a.workers) as pool:
        rows = []
        for r in pool.map(lambda j: spawn(*j), jobs):
            print(json.dumps(r), flush=True)
            rows.append(r)
    from ipm.files import write_text

    command = "python -m benchmarks.perturbation " + " ".join(argv if argv is not None else sys.argv[1:])
    write_text(Path(a.out), report(rows, command.strip(), time.perf_counter() - t0))
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
