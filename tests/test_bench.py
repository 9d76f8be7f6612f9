"""The bench harness end to end on a small experiment, resume without recomputation, a Dask local
cluster giving the same rows, and the tables."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from conftest import require_file

from ipm.bench.config import load_experiment
from ipm.bench.tables import latex, markdown
from ipm.errors import InputError

ROOT = Path(__file__).resolve().parents[1]
SMALL = ROOT / "experiments" / "small.toml"
SHARED = (ROOT / ".." / "shared" / "data" / "real" / "vessels" / "ocrtoc_mug.ply").resolve()


def small_experiment(tmp_path: Path, views=(1, 2), fits: bool = True) -> Path:
    """A copy of experiments/small.toml in a temporary project (so relative data paths still resolve);
    ``fits=False`` drops the generator fit (only the deterministic visual hull is left)."""
    require_file(SHARED)
    proj = tmp_path / "proj"
    (proj / "experiments").mkdir(parents=True)
    text = SMALL.read_text().replace("../shared/data/real/vessels/ocrtoc_mug.ply", str(SHARED))
    text = text.replace("views = [1, 2]", f"views = {list(views)}")
    if not fits:
        text = text[:text.index('[[methods]]\nname = "ipm-dishes"')]
    path = proj / "experiments" / "small.toml"
    path.write_text(text)
    return path


@pytest.mark.slow
def test_small_experiment_end_to_end_and_resume(tmp_path, capsys):
    from ipm.cli import main

    exp = small_experiment(tmp_path)
    out = tmp_path / "res"
    with pytest.raises(SystemExit) as e:
        main(["bench", str(exp), "-o", str(out), "--json"])
    assert e.value.code == 0, capsys.readouterr().err
    rows = [json.loads(x) for x in (out / "rows.jsonl").read_text().splitlines()]
    assert len(rows) == 3 and all(r["status"] == "ok" for r in rows), rows
    vh = [r for r in rows if r["method"] == "visual-hull"]
    assert len(vh) == 2 and all(0.3 < r["heldout_iou"] <= 1.0 for r in vh)
    fit = next(r for r in rows if r["method"] == "ipm-dishes")
    assert fit["evaluations"] == 60 and 0.5 < fit["heldout_iou"] <= 1.0 and "params" not in fit
    assert 1 <= fit["evals_to_final"] <= 60  # the fit's pace (ipm.bench.methods.ipm.evaluations_to_final)
    for name in ("table.md", "table.csv", "table.tex", "README.md", "sheet_cup_1.png"):
        assert (out / name).is_file()
    assert len(list((out / "meshes").glob("*.ply"))) == 3
    assert "sheet_cup_1.png" in (out / "README.md").read_text()
    # resume: nothing is recomputed (rows unchanged, no new lines)
    before = (out / "rows.jsonl").read_text()
    capsys.readouterr()
    with pytest.raises(SystemExit) as e:
        main(["bench", str(exp), "-o", str(out), "--resume"])
    assert e.value.code == 0
    assert (out / "rows.jsonl").read_text() == before
    printed = capsys.readouterr().out  # the terminal table
    assert "held-out silhouette IoU" in printed and "ipm-dishes" in printed and "visual-hull" in printed
    # predictions are not committed: a resumed bench without them keeps the sheet instead of redrawing
    # it with the target alone
    sheet = (out / "sheet_cup_1.png").read_bytes()
    stored = sorted((out / "meshes").glob("*.ply"))
    stored[0].rename(tmp_path / stored[0].name)
    with pytest.raises(SystemExit) as e:
        main(["bench", str(exp), "-o", str(out), "--resume"])
    assert e.value.code == 0
    assert (out / "sheet_cup_1.png").read_bytes() == sheet
    assert "sheet_cup_1.png: kept; 1 of 3 predictions" in capsys.readouterr().err
    assert "sheet_cup_1.png" in (out / "README.md").read_text()
    (tmp_path / stored[0].name).rename(stored[0])
    # an interrupted bench (last row missing, torn line) resumes with only the missing cell
    lines = before.splitlines()
    (out / "rows.jsonl").write_text("\n".join(lines[:-1]) + "\n" + lines[-1][:20])
    with pytest.raises(SystemExit) as e:
        main(["bench", str(exp), "-o", str(out), "--resume", "--json"])
    assert e.value.code == 0
    rows2 = [json.loads(x) for x in (out / "rows.jsonl").read_text().splitlines()]
    assert len(rows2) == 3 and {r["key"] for r in rows2} == {r["key"] for r in rows}


def test_existing_rows_without_resume_is_an_error(tmp_path):
    from ipm.bench.harness import run_experiment

    exp = small_experiment(tmp_path)
    out = tmp_path / "res"
    out.mkdir()
    (out / "rows.jsonl").write_text(json.dumps({"key": "x", "status": "ok"}) + "\n")
    with pytest.raises(ValueError, match="--resume"):
        run_experiment(exp, out)


@pytest.mark.slow
def test_dask_local_cluster_gives_the_same_rows(tmp_path):
    import dask.distributed as distributed

    from ipm.bench.harness import run_experiment

    exp = small_experiment(tmp_path, views=(1, 2), fits=False)  # two cells
    local = run_experiment(exp, tmp_path / "local")
    assert len(local) == 2
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:
        remote = run_experiment(exp, tmp_path / "dask", scheduler=cluster.scheduler_address)
    strip = lambda rows: sorted(({k: v for k, v in r.items() if k != "wall_time_s"} for r in rows),  # noqa: E731
                                key=lambda r: r["key"])
    assert strip(local) == strip(remote)


def test_tables_mark_the_best():
    rows = [{"status": "ok", "method": m, "views": 1, "target": "t", "seed": s, "key": f"{m}{s}",
             "heldout_iou": v, "chamfer_l1": c} for m, s, v, c in
            [("a", 0, 0.9, 0.01), ("a", 1, 0.8, 0.02), ("b", 0, 0.5, 0.005)]]
    md = markdown(rows)
    assert "**0.850 ± 0.050**" in md and "| **0.005** |" in md  # one seed: no spread shown
    assert "\\textbf{0.850 $\\pm$ 0.050}" in latex(rows)
    rows[0]["param_error"] = 0.1  # only method a has a parameter error: b gets no row in that table
    section = markdown(rows).split("### param. error")[1].split("###")[0]
    assert "| a | 1 |" in section and "| b |" not in section


def test_class_tables_average_targets_and_summarize_against_the_best_other_method():
    from ipm.bench.tables import class_markdown, class_summary

    def row(m, k, t, s, v):
        return {"status": "ok", "method": m, "views": k, "target": t, "seed": s, "key": f"{t}|{m}|{k}|{s}",
                "heldout_iou": v}

    rows = [row("fit", 1, "m1", 0, 0.9), row("fit", 1, "m1", 1, 0.7), row("fit", 1, "m2", 0, 0.6),
            row("hull", 1, "m1", 0, 0.5), row("hull", 1, "m2", 0, 0.7),
            row("hull", 12, "m1", 0, 0.95), row("hull", 12, "m2", 0, 0.85),
            row("deform", 1, "m1", 0, 0.99)]  # only one of the two mugs: does not compete
    classes = {"m1": "mug", "m2": "mug"}
    md = class_markdown(rows, classes)
    # fit: mean over targets of each target's mean over seeds: (0.8 + 0.6) / 2
    assert "| fit | 1 | 0.700 |" in md and "| hull | 12 | **0.900** |" in md and "| 0.990 (1/2) |" in md
    summary = class_summary(rows, classes, {"fit"})
    assert "| mug | 1 | 0.700 (fit) | 0.600 (hull) | +0.100 | 0.900 (hull) | -0.200 |" in summary, summary
    assert class_markdown(rows, {}) == "" and class_summary(rows, classes, set()) == ""


def test_bad_experiment_files(tmp_path):
    bad = tmp_path / "x.toml"
    bad.write_text("name = 'x'\n[[targets]]\nname='t'\n[[methods]]\nname='m'\nmethod='visual-hull'\n")
    with pytest.raises(InputError, match="exactly one of mesh or generator"):
        load_experiment(bad)
    bad.write_text("[[targets]]\nname='t'\nmesh='m.ply'\n[[methods]]\nname='m'\nmethod='magic'\n")
    with pytest.raises(InputError, match="method m: unknown bench method 'magic'"):
        load_experiment(bad)
    with pytest.raises(ValueError, match="not found"):
        load_experiment(tmp_path / "none.toml")
    shutil.rmtree(tmp_path)


def cell_keys(path, text: str) -> list[str]:
    """Write an experiment file and list its cells' keys, sorted."""
    path.write_text(text)
    return sorted(c.key for c in load_experiment(path).cells())


def test_methods_can_be_limited_to_some_targets(tmp_path):
    exp = tmp_path / "e.toml"
    assert cell_keys(exp, 'name = "e"\nviews = [1]\n[[targets]]\nname = "a"\ngenerator = "dishes"\npreset = "mug"\n'
                     '[[targets]]\nname = "b"\ngenerator = "dishes"\npreset = "bowl"\n'
                     '[[methods]]\nname = "vh"\nmethod = "visual-hull"\ntargets = ["b"]\n'
                     '[[methods]]\nname = "vh_all"\nmethod = "visual-hull"\n'
                     ) == ["a|vh_all|1|0", "b|vh_all|1|0", "b|vh|1|0"]
    exp.write_text(exp.read_text().replace('targets = ["b"]', 'targets = ["c"]'))
    with pytest.raises(ValueError, match="unknown targets c"):
        load_experiment(exp)


def test_methods_can_have_their_own_seeds(tmp_path):
    exp = tmp_path / "e.toml"
    assert cell_keys(exp, 'name = "e"\nviews = [1]\nseeds = [0, 1, 2]\n'
                     '[[targets]]\nname = "a"\ngenerator = "dishes"\npreset = "mug"\n'
                     '[[methods]]\nname = "vh"\nmethod = "visual-hull"\nseeds = [0]\n'
                     '[[methods]]\nname = "vh3"\nmethod = "visual-hull"\n'
                     ) == ["a|vh3|1|0", "a|vh3|1|1", "a|vh3|1|2", "a|vh|1|0"]
    assert "seeds" not in load_experiment(exp).method("vh").settings
    exp.write_text(exp.read_text().replace("seeds = [0]\n", "seeds = []\n", 1).replace("seeds = [0, 1, 2]", "seeds = [0]"))
    with pytest.raises(InputError, match=r"method vh: Expected `array` of length >= 1 - at `\$.seeds`"):
        load_experiment(exp)


def test_a_method_can_have_its_own_budget(tmp_path):
    exp = tmp_path / "e.toml"
    exp.write_text('name = "e"\nbudget = 300\n[[targets]]\nname = "a"\ngenerator = "dishes"\npreset = "mug"\n'
                   '[[methods]]\nname = "bound"\nmethod = "ipm"\ngenerator = "dishes"\nbudget = 1500\n'
                   '[[methods]]\nname = "vh"\nmethod = "visual-hull"\n')
    e = load_experiment(exp)
    assert e.method("bound").budget_or(e.budget) == 1500 and e.method("vh").budget_or(e.budget) == 300
    assert "budget" not in e.method("bound").settings  # the bench's, not a fit setting
    exp.write_text(exp.read_text().replace("budget = 1500", "budget = 0"))
    with pytest.raises(InputError, match=r"method bound: Expected `int` >= 1 - at `\$.budget`"):
        load_experiment(exp)


def _scaled_target_cell(tmp_path, views: int, factor: float) -> tuple[dict, Path]:
    """Run one cell whose method returns the target itself scaled by ``factor`` about the first input
    camera's eye; returns (row, output folder)."""
    from ipm.bench import harness
    from ipm.bench.methods import METHODS, Prediction
    from ipm.bench.protocol import scale_about

    exp = tmp_path / "proj" / "experiments" / "e.toml"
    exp.parent.mkdir(parents=True)
    exp.write_text(f'name = "e"\nviews = [{views}]\nsize = 64\nheldout_size = 64\nsamples = 2000\n'
                   'iou_resolution = 24\n[[targets]]\nname = "mug"\ngenerator = "dishes"\npreset = "mug"\n'
                   '[[methods]]\nname = "scaled"\nmethod = "_scaled_target"\n')

    def scaled(task, settings, budget, seed):
        target = harness.load_target(str(exp.resolve()), "mug").mesh
        return Prediction(scale_about(target, task.cameras[0].eye, factor), 1, 0.0)

    METHODS.add("_scaled_target", scaled)
    try:
        out = tmp_path / "out"
        return harness.run_cell(str(exp.resolve()), load_experiment(exp).cells()[0], str(out)), out
    finally:
        METHODS.remove("_scaled_target")


def test_one_view_predictions_are_scaled_about_the_eye(tmp_path):
    """Protocol v2, K = 1: the target scaled by 1.3 about the input camera's eye looks the same from that
    camera; the alignment finds s = 1 / 1.3 and the scores are those of the target itself."""
    row, out = _scaled_target_cell(tmp_path, 1, 1.3)
    assert row["status"] == "ok", row
    assert abs(row["align_scale"] * 1.3 - 1.0) < 0.01, row["align_scale"]
    assert row["heldout_iou"] >= 0.99 and row["fscore@0.02"] > 0.99 and row["iou_3d"] > 0.97, row
    # the stored mesh is the one scored (aligned, in the input cameras' frame): it lies on the target
    import trimesh

    from ipm.bench import harness

    V = trimesh.load(harness.mesh_path(out, row["key"]), force="mesh", process=False).vertices
    T = harness.load_target(str((tmp_path / "proj" / "experiments" / "e.toml").resolve()), "mug").mesh.verts.numpy()
    assert np.abs(V - T).max() < 0.01


def test_several_views_are_not_aligned(tmp_path):
    """Protocol v2, K >= 2: nothing is rescaled, so a scaled prediction loses held-out IoU."""
    row, _ = _scaled_target_cell(tmp_path, 2, 1.3)
    assert row["status"] == "ok", row
    assert row["align_scale"] == 1.0
    assert row["heldout_iou"] < 0.8 and row["fscore@0.02"] < 0.5, row


def test_target_normalization_is_the_unit_bounding_sphere(tmp_path):
    from ipm.bench import harness

    exp = tmp_path / "proj" / "experiments" / "e.toml"
    exp.parent.mkdir(parents=True)
    exp.write_text('name = "e"\n[[targets]]\nname = "b"\ngenerator = "building"\npreset = "panel5"\n'
                   '[[methods]]\nname = "vh"\nmethod = "visual-hull"\n')
    t = harness.load_target(str(exp.resolve()), "b")
    V = t.mesh.verts.numpy()
    assert abs(np.linalg.norm(V, axis=1).max() - 1.0) < 1e-12
    assert np.abs(V.max(0) + V.min(0)).max() < 1e-12  # bounding-box center at the origin


def test_a_clipped_target_is_refused_with_one_line(tmp_path, capsys):
    """Cameras closer than the protocol's (distance 1.6) clip the unit sphere: the bench refuses the
    target before any cell runs, with one line and exit code 2, and writes nothing."""
    from ipm.cli import main

    exp = tmp_path / "proj" / "experiments" / "e.toml"
    exp.parent.mkdir(parents=True)
    exp.write_text('name = "e"\nsize = 48\nheldout_size = 48\ndistance = 1.6\n[[targets]]\nname = "mug"\n'
                   'generator = "dishes"\npreset = "mug"\n[[methods]]\nname = "vh"\nmethod = "visual-hull"\n')
    out = tmp_path / "res"
    with pytest.raises(SystemExit) as e:
        main(["bench", str(exp), "-o", str(out)])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "target mug" in err[0] and "touches the image border" in err[0], err
    assert not (out / "rows.jsonl").exists()


def test_rows_list_the_discrete_parts_the_input_views_hide(tmp_path):
    """A mug whose handle points along the input camera's line of sight (azimuth 120 degrees: behind the
    body from azimuth 30) hides it from one view, not from two orthogonal views."""
    from ipm.bench import harness

    exp = tmp_path / "proj" / "experiments" / "e.toml"
    exp.parent.mkdir(parents=True)
    exp.write_text('name = "e"\nviews = [1, 2]\nsize = 96\nheldout_size = 32\nsamples = 500\n'
                   'iou_resolution = 16\n[[targets]]\nname = "mug"\ngenerator = "dishes"\npreset = "mug"\n'
                   'params = { handle_azimuth = 120.0 }\n'
                   '[[methods]]\nname = "vh"\nmethod = "visual-hull"\nresolution = 24\n')
    rows = {c.views: harness.run_cell(str(exp.resolve()), c) for c in load_experiment(exp).cells()}
    # the spout tube a mug could have would point at the camera (opposite the handle): hidden too; and a
    # lid knob of the default size stands inside the mug's opening, below its rim: hidden from two views too
    assert rows[1]["hidden_discrete"] == {"has_handle": [0], "has_spout": [1], "has_knob": [1]}, rows[1]
    assert rows[2]["hidden_discrete"] == {"has_knob": [1]}, rows[2]
    from ipm.bench.tables import hidden_markdown

    text = hidden_markdown(list(rows.values()))
    assert "- mug, 1 view: has_handle (also 0), has_knob (also 1), has_spout (also 1)" in text, text
    assert "- mug, 2 views: has_knob (also 1)" in text, text


def test_a_second_bench_on_the_same_folder_is_refused(tmp_path):
    """Two benches appending to one rows.jsonl lose rows (the second rewrites the file it read under the
    first one's appends); the folder is locked for the run instead."""
    import fcntl

    from ipm.bench.harness import LOCK, run_experiment

    exp = small_experiment(tmp_path, views=(1,), fits=False)
    out = tmp_path / "res"
    out.mkdir()
    with open(out / LOCK, "a") as held:
        fcntl.flock(held, fcntl.LOCK_EX | fcntl.LOCK_NB)
        with pytest.raises(ValueError, match="another ipm bench is writing to this folder"):
            run_experiment(exp, out)
    rows = run_experiment(exp, out)  # released: the run goes ahead
    assert [r["status"] for r in rows] == ["ok"]


def test_bench_workers_die_with_their_parent(tmp_path):
    """A bench killed with SIGKILL leaves no worker processes behind (``ipm.threads.process_pool``)."""
    import os
    import subprocess
    import sys
    import time

    script = tmp_path / "parent.py"
    script.write_text(
        "import os, signal, time\n"
        "from ipm.threads import process_pool\n"
        "pool = process_pool(2)\n"
        "futs = [pool.submit(time.sleep, 120) for _ in range(2)]\n"
        "time.sleep(1.5)\n"
        "print(' '.join(str(p) for p in pool._processes), flush=True)\n"
        "os.kill(os.getpid(), signal.SIGKILL)\n")
    proc = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120,
                          cwd=Path(__file__).resolve().parents[1])
    pids = [int(p) for p in proc.stdout.split()]
    assert len(pids) == 2, proc.stderr

    def alive(pid: int) -> bool:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return False
        stat_file = Path(f"/proc/{pid}/stat")  # a zombie waiting for init to reap it counts as gone
        return not (stat_file.is_file() and stat_file.read_text().split()[2] == "Z")

    deadline = time.time() + 20
    while any(alive(p) for p in pids) and time.time() < deadline:
        time.sleep(0.2)
    assert not any(alive(p) for p in pids), f"workers {pids} outlived their parent"
