"""The structure-recovery table (issue #16, ``make table-structure``): trees searched from meshes, against the
fixed ``chair`` / ``table`` trees fitted to the same meshes, the BSP conversion written as an SDF tree
(``ipm convert --to sdftree``) and a dense SDF grid with as many values as the searched tree has parameters.

Targets, every one normalized to DESIGN.md's unit sphere: random trees of 3, 5 and 8 primitives (box,
cylinder, sphere; joined by union, some cut by subtraction; every primitive changes the solid by at least 5 %
of its volume: exact ground truth), the ``chair`` and ``table`` preset trees with their sizes scaled at
random, and the real furniture of ``../shared/data/real/furniture``.

Scores (protocol v2's, in the normalized frame where every method places its result): held-out silhouette
IoU (16 views), F-score at 0.02 and 0.05, node count of the tree as written; for random trees whether the
recovered tree has the same primitives up to order (adding and cutting: ``ipm.optim.structure.signature``).

Usage: ``python -m benchmarks.table_structure OUT_DIR [--quick]``.
"""

from __future__ import annotations

import datetime as dt
import json
import platform
import re
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "real" / "furniture"
# the egg chair (trimesh_egg_chair.obj) is left out: its faces are unwelded and inconsistently oriented, so its
# winding number is about 0 everywhere and no point is inside it (mesh targets need an inside)
FURNITURE = (("armchair", "kaolin_armchair.obj", "y", "chair"), ("side table", "trimesh_side_table.obj", "z", "table"))
KINDS = ("box", "cylinder", "sphere")
MIN_SHARE = 0.05          # every primitive of a random tree changes the solid by this share of its volume
BUDGET = 16000            # search evaluations (StructureSettings' default)
NODE_BUDGET = 24          # StructureSettings.max_nodes: the BSP tree gets as many nodes
GRID = 8                  # the SDF grid: 8³ = 512 values, 10-30x a searched tree's parameters
FIT_BUDGET = 1500         # the fixed trees' fits (ipm fit's default)
PRESETS = ("chair", "table")   # preset trees sampled with every size scaled by a factor in [0.7, 1.3]
BSP_SIZES = ((1, 8), (2, 6), (2, 8), (3, 6))  # (convexes, planes) tried for the BSP tree


def random_tree(n: int, rng: np.random.Generator, snap: tuple[float, float] | None = None) -> dict:
    """A random tree of ``n`` parts: the first adds, later ones add (70 %) or cut. ``snap``: full sizes and
    centers rounded to multiples of these two steps (the same draws), so that faces meet and surfaces are
    tangent as in designed models."""
    from ipm.optim.structure.program import combine, part

    tree = None
    for i in range(n):
        kind = KINDS[int(rng.integers(3))]
        ext = rng.uniform(0.25, 0.9, 3)
        center = rng.uniform(-0.35, 0.35, 3)
        if snap is not None:
            ext, center = np.round(ext / snap[0]) * snap[0], np.round(center / snap[1]) * snap[1]
        if tree is None:
            tree = part(f"part{i + 1}", kind, center, ext)
        else:
            op = "union" if rng.random() < 0.7 else "subtraction"
            tree = combine(op, tree, part(f"{'part' if op == 'union' else 'cut'}{i + 1}", kind, center, ext))
    return tree


def _occupancy(tree: dict, pts: torch.Tensor) -> torch.Tensor:
    from ipm.sdf.tree import tree_from_json

    return tree_from_json({"tree": tree}).sdf(None, pts) < 0


def every_part_matters(tree: dict, pts: torch.Tensor) -> bool:
    """True when deleting any one part changes the solid by at least MIN_SHARE of its volume."""
    from ipm.optim.structure.program import walk

    full = _occupancy(tree, pts)
    if int(full.sum()) == 0:
        return False
    for path, node in walk(tree):
        if node["node"] in ("union", "subtraction"):
            for k in ((0, 1) if node["node"] == "union" else (0,)):
                from ipm.optim.structure.program import replaced

                less = _occupancy(replaced(tree, path, node["children"][k]), pts)
                if int((less ^ full).sum()) < MIN_SHARE * int(full.sum()):
                    return False
    return True


def make_random(n: int, seed: int) -> dict:
    rng = np.random.default_rng([n, seed])
    pts = torch.as_tensor(np.random.default_rng(0).uniform(-1.2, 1.2, (20000, 3)))
    while True:
        tree = random_tree(n, rng)
        if every_part_matters(tree, pts):
            return tree


def tree_mesh(tree: dict, resolution: int = 128):
    from ipm.generators import get_generator

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "tree.json"
        path.write_text(json.dumps({"tree": tree}))
        gen = get_generator(str(path))
        return gen.to_mesh(gen.spec.defaults(), resolution=resolution)


def normalized(mesh):
    from ipm.metrics import mesh_arrays, normalize_vertices
    from ipm.types import TriMesh

    V, F = mesh_arrays(mesh)
    return TriMesh(torch.as_tensor(normalize_vertices(V)), torch.as_tensor(F))


def scores(pred, target) -> dict:
    from ipm.bench.protocol import render_masks
    from ipm.metrics import fscore, mask_iou
    from ipm.render.camera import heldout_views

    cams = heldout_views(256)
    a, b = render_masks(pred, cams), render_masks(target, cams)
    iou = float(np.mean([mask_iou(x, y) for x, y in zip(a, b)]))
    return {"heldout_iou": iou, "fscore@0.02": fscore(pred, target, 0.02, normalize=False),
            "fscore@0.05": fscore(pred, target, 0.05, normalize=False)}


def search_row(target, budget: int, seed: int = 0) -> tuple[dict, dict]:
    from ipm.optim.structure import StructureSettings, mesh_samples, search
    from ipm.optim.structure.program import count_nodes

    torch.manual_seed(0)
    s = StructureSettings(budget=budget, seed=seed)
    samples = mesh_samples(target, surface=s.surface, volume=s.volume, grid=s.grid, seed=seed).to(dtype=torch.float32)
    t0 = time.perf_counter()
    r = search(samples, s)
    seconds = time.perf_counter() - t0
    pred = tree_mesh(r.tree)
    from ipm.sdf.tree import tree_from_json

    return ({"method": "search", "nodes": count_nodes(r.tree), "parameters": tree_from_json({"tree": r.tree}).n_params,
             "evaluations": r.evaluations, "seconds": seconds, "structure": r.structure, "rounds": r.rounds,
             "stopped": r.stopped, **scores(pred, target)}, r.tree)


def preset_sample(name: str, seed: int):
    """The preset tree ``name`` with every size scaled by a factor in [0.7, 1.3], meshed and normalized."""
    from ipm.generators import get_generator

    gen = get_generator(name)
    rng = np.random.default_rng([7, seed])
    values = {k: float(v) * float(rng.uniform(0.7, 1.3)) for k, v in gen.spec.defaults().items()}
    return normalized(gen.to_mesh(values, resolution=128))


def fixed_row(name: str, path: Path, up: str) -> dict:
    import ipm
    from ipm.io.meshes import load_mesh
    from ipm.sdf.tree import load_tree

    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        res = ipm.fit(name, target_mesh=path, up=up, budget=FIT_BUDGET, seed=0, discrete="none",
                      run_dir=Path(tmp) / "run")
        seconds = time.perf_counter() - t0
        pred = load_mesh(Path(tmp) / "run" / "mesh.obj", normalize=False)
    target = load_mesh(path, up=up)
    tree = load_tree(Path(__file__).resolve().parents[1] / "ipm" / "sdf" / "presets" / f"{name}.json")
    return {"method": f"fixed {name} tree", "nodes": _expanded_nodes(tree.root), "parameters": tree.n_params,
            "evaluations": res.evaluations, "seconds": seconds, **scores(pred, target)}


def _expanded_nodes(root) -> int:
    """Nodes of a tree with its macro nodes expanded (a macro counts the nodes of its template)."""
    from ipm.sdf.complex import MacroNode
    from ipm.tree import preorder

    total = 0
    for v in preorder(root):
        total += _expanded_nodes(v.node.template) if isinstance(v.node, MacroNode) else 1
    return total


def bsp_row(target, node_budget: int) -> dict:
    """The BSP conversion whose tree has the most nodes within ``node_budget`` over :data:`BSP_SIZES`."""
    from ipm.convert.sdftree import convert_sdftree
    from ipm.optim.structure.program import count_nodes

    best = None
    for convexes, planes in BSP_SIZES:
        t0 = time.perf_counter()
        conv = convert_sdftree(target, seed=0, planes=planes, convexes=convexes)
        seconds = time.perf_counter() - t0
        n = count_nodes(conv.data["tree"])
        if n <= node_budget and (best is None or n >= best[0]):
            best = (n, conv, seconds, f"{convexes} convexes, {planes} planes")
    if best is None:
        return {"method": "BSP tree", "nodes": None}
    n, conv, seconds, size = best
    pred = conv.generator.to_mesh(conv.values, resolution=128)
    return {"method": "BSP tree", "nodes": n, "parameters": conv.generator.tree.n_params, "evaluations": 0,
            "seconds": seconds, "size": size, **scores(pred, target)}


def grid_row(target, parameters: int) -> dict:
    from benchmarks.table_convert import dense_grid
    from ipm.convert.common import prepare

    mesh, seconds, nodes = dense_grid(prepare(target), parameters)
    if mesh.n_faces == 0:
        return {"method": "SDF grid", "nodes": None, "parameters": nodes}
    return {"method": "SDF grid", "nodes": None, "parameters": nodes, "evaluations": 0, "seconds": seconds,
            **scores(mesh, target)}


def run(out_dir: Path, quick: bool = False) -> list[dict]:
    from ipm.io.meshes import load_mesh
    from ipm.optim.structure import count_nodes, signature

    torch.set_num_threads(1)
    rows: list[dict] = []
    random_sets = [(3, s) for s in range(2 if quick else 6)] + ([] if quick else [(5, 0), (5, 1), (8, 0)])
    for n, seed in random_sets:
        truth = make_random(n, seed)
        target = normalized(tree_mesh(truth))
        name = f"random {n} parts #{seed}"
        row, tree = search_row(target, BUDGET // (4 if quick else 1))
        row.update(target=name, equivalent=signature(tree) == signature(truth),
                   truth_nodes=count_nodes(truth))
        rows.append(row)
        write_tree(out_dir, name, tree)
        rows.append({"target": name, **bsp_row(target, NODE_BUDGET)})
        rows.append({"target": name, **grid_row(target, GRID ** 3)})
        write(out_dir, rows, quick)
        print(f"{name}: search IoU {row['heldout_iou']:.3f}, {row['nodes']} nodes, equivalent {row['equivalent']}, "
              f"{row['seconds']:.0f} s", file=sys.stderr, flush=True)
    for preset in PRESETS[:1] if quick else PRESETS:
        from ipm.io.export import export_mesh

        target = preset_sample(preset, 0)
        name = f"{preset} tree, sizes x0.7-1.3"
        row, tree = search_row(target, BUDGET // (4 if quick else 1))
        rows.append({"target": name, **row})
        write_tree(out_dir, name, tree)
        with tempfile.TemporaryDirectory() as tmp:
            export_mesh(target, Path(tmp) / "t.obj", sidecar=False)
            rows.append({"target": name, **fixed_row(preset, Path(tmp) / "t.obj", "y")})
        rows.append({"target": name, **bsp_row(target, NODE_BUDGET)})
        rows.append({"target": name, **grid_row(target, GRID ** 3)})
        write(out_dir, rows, quick)
        print(f"{name}: search IoU {row['heldout_iou']:.3f} ({row['nodes']} nodes), "
              f"fixed {rows[-3]['heldout_iou']:.3f}", file=sys.stderr, flush=True)
    for name, rel, up, fixed in FURNITURE[:1] if quick else FURNITURE:
        target = load_mesh(DATA / rel, up=up)
        row, tree = search_row(target, BUDGET // (4 if quick else 1))
        rows.append({"target": name, **row})
        write_tree(out_dir, name, tree)
        rows.append({"target": name, **fixed_row(fixed, DATA / rel, up)})
        rows.append({"target": name, **bsp_row(target, NODE_BUDGET)})
        rows.append({"target": name, **grid_row(target, GRID ** 3)})
        write(out_dir, rows, quick)
        print(f"{name}: search IoU {row['heldout_iou']:.3f} ({row['nodes']} nodes), "
              f"fixed {rows[-3]['heldout_iou']:.3f}", file=sys.stderr, flush=True)
    write(out_dir, rows, quick)
    return rows


def write_tree(out_dir: Path, target: str, tree: dict) -> Path:
    """Keep a searched tree as a tree file (``trees/<target>.json``, nested JSON): ``ipm generate`` meshes it and
    exports it as a program (OpenSCAD, CadQuery)."""
    from ipm.files import write_text

    slug = re.sub(r"[^a-z0-9]+", "_", target.lower()).strip("_")
    path = out_dir / "trees" / f"{slug}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text(path, json.dumps({"tree": tree}, indent=1) + "\n")
    return path


def _f(v, fmt="{:.3f}"):
    return "—" if v is None else (fmt.format(v) if isinstance(v, float) else str(v))


def write(out_dir: Path, rows: list[dict], quick: bool) -> None:
    import subprocess

    from ipm.files import write_text

    out_dir.mkdir(parents=True, exist_ok=True)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                            cwd=Path(__file__).resolve().parents[1]).stdout.strip()
    dirty = subprocess.run(["git", "status", "--porcelain", "--", "ipm", "benchmarks"], capture_output=True, text=True,
                           cwd=Path(__file__).resolve().parents[1]).stdout.strip()
    lines = [
        "# Structure recovery (issue #16: `make table-structure`)", "",
        f"Command: `python -m benchmarks.table_structure {out_dir}{' --quick' if quick else ''}`  ",
        f"Commit: {commit}{' (plus uncommitted changes)' if dirty else ''}  ",
        f"Machine: {platform.node()} ({platform.machine()}), torch {torch.__version__} with "
        f"{torch.get_num_threads()} thread(s), Python {platform.python_version()}  ",
        f"Date: {dt.datetime.now(dt.UTC).isoformat(timespec='seconds')}", "",
        "- Every target in DESIGN.md's unit sphere; scores in that frame, where each method placed its result: "
        "held-out silhouette IoU (16 views, protocol v2), F-score at 0.02 / 0.05.",
        f"- search: `ipm fit --structure search` defaults (beam 3, 12 proposals per tree and round, 40 Adam steps "
        f"each, 600 polish steps, a cost of 0.005 per node, at most {NODE_BUDGET} nodes), "
        f"{BUDGET // (4 if quick else 1)} evaluations (one evaluation: one Adam step or one score of a tree); seed 0.",
        f"- fixed tree: `ipm fit chair|table --target-mesh` ({FIT_BUDGET} evaluations, discrete none); its node "
        "count with the macro expanded.",
        "- BSP tree: `ipm convert --to sdftree` with (convexes, planes) among "
        f"{', '.join(str(b) for b in BSP_SIZES)}: the tree with the most nodes within {NODE_BUDGET} (the search's "
        "limit); its seconds are that conversion's.",
        f"- SDF grid: marching cubes of the exact signed distance on {GRID}³ nodes ({GRID ** 3} values, 10-30x a "
        "searched tree's parameters); \"—\" where its zero level set is empty (every part thinner than the "
        "grid's spacing).",
        "- equivalent: the recovered tree has the truth's primitives up to order (the kinds that add and the "
        "kinds that cut).",
        "- The searched trees are kept in `trees/`, one nested JSON tree file per target (`ipm generate "
        "trees/<target>.json -o x.obj`).",
        "- The egg chair of the furniture folder is left out: its faces are unwelded and inconsistently oriented, "
        "its winding number is about 0 everywhere, so no point is inside it (a mesh target needs an inside; "
        "`ipm fit --structure search` says so and points to masks).", "",
        "| target | method | held-out IoU | F@0.02 | F@0.05 | nodes | parameters | equivalent | evaluations | s |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        eq = "—" if "equivalent" not in r else ("yes" if r["equivalent"] else "no")
        nodes = _f(r.get("nodes")) + (f" (truth {r['truth_nodes']})" if "truth_nodes" in r else "")
        method = r["method"] + (f" ({r['size']})" if r.get("size") else "")
        lines.append(f"| {r['target']} | {method} | {_f(r.get('heldout_iou'))} | {_f(r.get('fscore@0.02'))} | "
                     f"{_f(r.get('fscore@0.05'))} | {nodes} | {_f(r.get('parameters'))} | {eq} | "
                     f"{_f(r.get('evaluations'))} | {_f(r.get('seconds'), '{:.0f}')} |")
    lines += ["", "Recovered structures:", ""]
    lines += [f"- {r['target']}: `{r['structure']}` ({r['rounds']} rounds, stopped: {r['stopped']})"
              for r in rows if r["method"] == "search"]
    write_text(out_dir / "table.md", "\n".join(lines) + "\n")
    write_text(out_dir / "rows.json", json.dumps(rows, indent=1, default=str) + "\n")


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    if len(args) != 1:
        sys.exit("usage: python -m benchmarks.table_structure OUT_DIR [--quick]")
    run(Path(args[0]), quick="--quick" in sys.argv)
