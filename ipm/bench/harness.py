"""The bench grid: targets x methods x views x seeds, one JSON row per finished cell.

Rows are appended to ``rows.jsonl`` as soon as a cell finishes, so an interrupted bench resumes where it
stopped (``resume=True`` skips the cells already in the file). Cells run inline (one worker), in local
worker processes, or on a Dask distributed cluster (``scheduler`` address); all three run the same
function, :func:`run_cell`.

A resume reads ``rows.jsonl`` checked (:class:`Row`: a line that is not a row, a field of the wrong type,
a key that does not match its target, method, views and seed, a cell twice: an
:class:`~ipm.errors.InputError` naming the file and the line) and only into a folder of the same
experiment: ``experiment.json`` (:data:`IDENTITY`) records the experiment's name, file and an identity
per cell (a hash of what its row depends on: the protocol's settings, the target's definition and mesh
file's content, the method's settings and budget; :func:`cell_identities`). Cells may be added (a
method, a seed); a row whose cell the experiment no longer has, or has with other settings, is refused,
naming both experiments. A folder of rows without ``experiment.json`` (written before it was kept) is
accepted when each row is a cell of the experiment.
"""

from __future__ import annotations

import hashlib
import json
import logging
import time
from collections.abc import Callable
from contextlib import contextmanager, suppress
from dataclasses import asdict, dataclass
from functools import lru_cache
from pathlib import Path
from typing import Annotated, Literal

import msgspec
import numpy as np
import torch
from msgspec import Meta

from ipm import threads
from ipm.bench.config import Cell, Experiment, load_experiment
from ipm.bench.methods import NO_CUES, Cues
from ipm.bench.protocol import (
    Views,
    align_scale,
    check_border,
    hidden_discrete,
    render_masks,
    render_views,
    scale_about,
)
from ipm.errors import InputError, MethodFailed
from ipm.types import TriMesh

log = logging.getLogger(__name__)
ROWS = "rows.jsonl"


@dataclass(frozen=True)
class BenchTarget:
    """A target in the protocol's frame (DESIGN.md v2: unit bounding sphere about the bounding-box center).

    mesh: a generator sample keeps its face groups (its parts: what part-label cues show);
    frame: the ``(center, scale)`` that took the source to that frame; truth and generator: a generator
    sample's parameters and generator name (None for a mesh file)."""

    mesh: TriMesh
    frame: tuple[np.ndarray, float]
    truth: dict | None = None
    generator: str | None = None


@lru_cache(maxsize=32)
def load_target(exp_path: str, name: str) -> BenchTarget:
    """The normalized target ``name`` of the experiment file ``exp_path``."""
    from ipm.metrics import unit_sphere_frame

    exp = load_experiment(exp_path)
    t = exp.target(name)
    truth, gen_name, groups, names = None, None, None, ()
    if t.mesh is not None:
        from ipm.io.meshes import load_mesh

        path = Path(t.mesh)
        path = path if path.is_absolute() else exp.root / path
        m = load_mesh(path, up=t.up, normalize=False)  # ValueError names a missing or unreadable file
        V, F = m.verts.numpy(), m.faces.numpy()
    else:
        from ipm.generators import get_generator

        gen = get_generator(t.generator)
        values = gen.values(t.preset, t.params)
        if t.random:
            values = gen.spec.validate({**values, **gen.spec.random(np.random.default_rng(t.seed)), **t.params})
        m = gen.to_mesh(values)
        V, F = m.verts.detach().double().numpy(), m.faces.numpy()
        truth, gen_name, groups, names = values, gen.name, m.groups, m.group_names
    center, scale = unit_sphere_frame(V[np.unique(F)])
    mesh = TriMesh(torch.as_tensor((V - center) * scale), torch.as_tensor(F), groups, names)
    return BenchTarget(mesh, (center, scale), truth, gen_name)


def _input_cameras(exp: Experiment, k: int):
    from ipm.render.camera import input_views

    return input_views(k, exp.size, exp.distance)


def _heldout_cameras(exp: Experiment):
    from ipm.render.camera import heldout_views

    return heldout_views(exp.heldout_size, exp.distance)


@lru_cache(maxsize=64)
def target_masks(exp_path: str, name: str, views: int | None) -> np.ndarray:
    """The exact masks (K, H, W) of target ``name`` in the K protocol input views (``views=None``: the 16
    held-out views). Raises ``ValueError`` when one touches the image border (:func:`check_border`)."""
    exp = load_experiment(exp_path)
    cams = _heldout_cameras(exp) if views is None else _input_cameras(exp, views)
    masks = render_masks(load_target(exp_path, name).mesh, cams)
    what = "held-out" if views is None else f"{views}-view input"
    check_border(masks, f"{exp_path}: target {name}, {what} views")
    return masks


@lru_cache(maxsize=64)
def target_views(exp_path: str, name: str, views: int, cues: Cues = NO_CUES) -> Views:
    """Target ``name`` in the K protocol input views: its exact masks (:func:`target_masks`) and the
    ``cues`` a method asked for (:func:`ipm.bench.protocol.render_views`: depth maps, part labels)."""
    masks = target_masks(exp_path, name, views)
    if not cues:
        return Views(masks)
    exp = load_experiment(exp_path)
    seen = render_views(load_target(exp_path, name).mesh, _input_cameras(exp, views), depth=cues.depth,
                        parts=cues.parts)
    return Views(masks, seen.depth, seen.parts, seen.part_names)


def check_targets(exp_path: str, exp: Experiment) -> None:
    """Render every target in every input view set a cell will show it and in the held-out views, and
    refuse (``ValueError``) any that the views clip, before a single cell runs."""
    views: dict[str, set[int]] = {}
    for c in exp.cells():
        views.setdefault(c.target, set()).add(c.views)
    for name, ks in views.items():
        target_masks(exp_path, name, None)
        for k in sorted(ks):
            target_masks(exp_path, name, k)


@lru_cache(maxsize=64)
def _hidden(exp_path: str, name: str, views: int, cues: Cues = NO_CUES) -> dict:
    from ipm.generators import get_generator

    exp = load_experiment(exp_path)
    t = load_target(exp_path, name)
    return hidden_discrete(get_generator(t.generator), t.truth, t.frame, _input_cameras(exp, views),
                           target_views(exp_path, name, views, cues))


def param_error(pred: dict, truth: dict, gen_name: str) -> dict:
    """Mean absolute error of continuous parameters in normalized [0, 1] units, discrete accuracy."""
    from ipm.generators import get_generator

    spec = get_generator(gen_name).spec
    cont = [abs(float(pred[p.name]) - float(truth[p.name])) / max(p.hi - p.lo, 1e-12) for p in spec.continuous]
    disc = [int(pred[p.name]) == int(truth[p.name]) for p in spec.discrete]
    return {"param_error": float(np.mean(cont)) if cont else 0.0,
            "discrete_accuracy": float(np.mean(disc)) if disc else 1.0}


def mesh_path(out_dir: str | Path, key: str) -> Path:
    """Where a cell's predicted mesh (in the frame it was scored in) is kept: ``meshes/<key>.ply``."""
    return Path(out_dir) / "meshes" / (key.replace("|", "__") + ".ply")


def run_cell(exp_path: str, cell: Cell, out_dir: str | None = None) -> dict:
    """Run one cell and score it (DESIGN.md's protocol v2). Safe to call in a fresh process.

    The prediction is scored where the method placed it, in the frame of the input cameras; with one
    view it is first scaled about the input camera's eye by the factor that minimizes Chamfer-L1
    (:func:`ipm.bench.protocol.align_scale`, recorded as ``align_scale``; 1.0 for K >= 2, which are not
    aligned). With ``out_dir`` the scored mesh is written to :func:`mesh_path`, so anyone can re-score
    it. Rows of generator samples list the discrete parameters the input views hide
    (``hidden_discrete``, :func:`ipm.bench.protocol.hidden_discrete`), with the cues the method was given.

    A method that asks for cues (:meth:`ipm.bench.methods.Method.cues`) gets them in its
    :class:`~ipm.bench.methods.Task` (:func:`target_views`) and its row lists them (``cues``:
    ``["depth", "parts:windows"]``).
    """
    with threads.using():  # one thread unless --threads or IPM_THREADS asked for more (ipm.threads)
        return _run_cell(exp_path, cell, out_dir)


def _run_cell(exp_path: str, cell: Cell, out_dir: str | None) -> dict:
    from ipm.bench.methods import METHODS, Task, requested_cues
    from ipm.io.export import export_mesh
    from ipm.metrics import mask_iou, shape_scores

    exp_path = str(exp_path)
    exp = load_experiment(exp_path)
    spec = exp.method(cell.method)
    target = load_target(exp_path, cell.target)
    cams = _input_cameras(exp, cell.views)
    settings = spec.settings_for(exp.target(cell.target))
    cues = requested_cues(spec.method, settings)
    seen = target_views(exp_path, cell.target, cell.views, cues)
    task = Task(seen.masks, cams, seen.depth, seen.parts, seen.part_names)
    t0 = time.perf_counter()
    row = {"target": cell.target, "method": cell.method, "views": cell.views, "seed": cell.seed, "key": cell.key}
    if cues:
        row["cues"] = cues.names()
    try:
        pred = METHODS[spec.method](task, settings, spec.budget_or(exp.budget), cell.seed)
    except MethodFailed as e:
        row.update(status="failed", error=str(e), wall_time_s=round(time.perf_counter() - t0, 3))
        return row
    mesh = TriMesh(pred.mesh.verts.detach().double(), pred.mesh.faces)
    if mesh.n_faces == 0:
        row.update(status="failed", error="prediction: an empty mesh", wall_time_s=round(pred.wall_time_s, 3))
        return row
    scale = 1.0
    if cell.views == 1:
        scale = align_scale(mesh, target.mesh, cams[0].eye, seed=cell.seed).scale
        mesh = scale_about(mesh, cams[0].eye, scale)
    row["align_scale"] = scale
    if out_dir is not None:
        export_mesh(mesh, mesh_path(out_dir, cell.key), sidecar=False)
    p_masks = render_masks(mesh, _heldout_cameras(exp))
    t_masks = target_masks(exp_path, cell.target, None)
    row["heldout_iou"] = float(np.mean([mask_iou(a, b) for a, b in zip(p_masks, t_masks)]))
    s = shape_scores(mesh, target.mesh, n=exp.samples, seed=cell.seed, resolution=exp.iou_resolution,
                     normalize=False)
    row.update(s.to_json())
    row.update(status="ok", evaluations=pred.evaluations, wall_time_s=round(pred.wall_time_s, 3))
    for key in ("discrete", "loss", "evals_to_final"):  # a generator fit's discrete values, final loss and pace
        if key in pred.info:
            row[key] = pred.info[key]
    if target.truth is not None:
        row["hidden_discrete"] = _hidden(exp_path, cell.target, cell.views, cues)
        if "params" in pred.info and settings.get("generator") == target.generator:
            row.update(param_error(pred.info["params"], target.truth, target.generator))
    return row


class Row(msgspec.Struct, rename={"fscore_002": "fscore@0.02", "fscore_005": "fscore@0.05"}):
    """The schema of a line of ``rows.jsonl`` (further fields are a method's own); the numbers the tables
    read are numbers where given."""

    key: str
    target: str
    method: str
    views: Annotated[int, Meta(ge=1)]
    seed: Annotated[int, Meta(ge=0)]
    status: Literal["ok", "failed"]
    heldout_iou: float | None = None
    fscore_002: float | None = None
    fscore_005: float | None = None
    chamfer_l1: float | None = None
    iou_3d: float | None = None
    param_error: float | None = None
    discrete_accuracy: float | None = None
    align_scale: float | None = None
    wall_time_s: float | None = None
    evaluations: int | None = None
    evals_to_final: int | None = None
    cues: list[str] | None = None
    error: str | None = None


def read_rows(out_dir: Path) -> list[dict]:
    """The rows of ``out_dir/rows.jsonl`` (none without the file), each checked (:class:`Row`; a torn last
    line is dropped); :class:`InputError` names the file and the line of anything else."""
    from ipm.io.runs import read_json_lines

    path = Path(out_dir) / ROWS
    rows = read_json_lines(path, "bench rows", Row)
    seen: dict[str, int] = {}
    for n, r in enumerate(rows, 1):
        key = f"{r['target']}|{r['method']}|{r['views']}|{r['seed']}"
        if r["key"] != key:
            raise InputError(f"bench rows {path}: line {n}: key: expected {key!r} (its target, method, views and "
                             f"seed), got {r['key']!r}")
        if key in seen:
            raise InputError(f"bench rows {path}: line {n}: expected each cell once, got {key} again (line "
                             f"{seen[key]})")
        seen[key] = n
    return rows


IDENTITY = "experiment.json"


class Identity(msgspec.Struct):
    """``experiment.json``: the experiment whose rows a bench folder holds (:func:`cell_identities`)."""

    name: str
    file: str
    cells: dict[str, str]


def cell_identities(exp_path: str, exp: Experiment) -> dict[str, str]:
    """``{cell key: identity}``: a hash of what the cell's row depends on: the protocol's settings (sizes,
    samples, distance), the target's definition (a mesh file by its content, not its path), the method's
    kind, settings for that target and budget, the views and the seed."""
    protocol = {k: getattr(exp, k) for k in ("size", "heldout_size", "samples", "iou_resolution", "distance")}
    targets = {}
    for t in exp.targets:
        d = asdict(t)
        del d["split"]  # which run a target belongs to is not what its rows depend on
        if t.mesh is not None:
            path = Path(t.mesh) if Path(t.mesh).is_absolute() else exp.root / t.mesh
            try:
                d["mesh"] = hashlib.sha256(path.read_bytes()).hexdigest()
            except OSError as e:
                raise InputError(f"{exp_path}: target {t.name}: cannot read {path} ({e.strerror})") from None
        targets[t.name] = d
    out = {}
    for c in exp.cells():
        m = exp.method(c.method)
        what = {"protocol": protocol, "target": targets[c.target], "method": m.method,
                "settings": m.settings_for(exp.target(c.target)), "budget": m.budget_or(exp.budget),
                "views": c.views, "seed": c.seed}
        text = json.dumps(what, sort_keys=True, default=str)
        out[c.key] = hashlib.sha256(text.encode()).hexdigest()[:16]
    return out


def check_same_experiment(out: Path, rows: list[dict], exp_path: str, exp: Experiment, ids: dict[str, str]) -> None:
    """Refuse (:class:`InputError`, one line naming both experiments) to add to ``out`` rows of another
    experiment than the one its ``experiment.json`` records (see the module docstring)."""
    from ipm.io.runs import checked, read_json_file

    if not rows:
        return
    path = out / IDENTITY
    this = f"experiment {exp.name!r} ({exp_path})"
    if path.is_file():
        ident = checked(read_json_file(path, "bench experiment file"), Identity, f"bench experiment file {path}")
        theirs = f"experiment {ident.name!r} ({ident.file})"
        for r in rows:
            k = r["key"]
            if k not in ids or ident.cells.get(k) != ids[k]:
                why = ("has no such cell" if k not in ids else
                       "gives it other settings (protocol, target or method)" if k in ident.cells else
                       f"has it, but {path.name} does not")
                raise InputError(f"{out}: holds rows of {theirs}; expected {this}, which {why}: {k}; choose "
                                 "another output folder")
        return
    stray = next((r["key"] for r in rows if r["key"] not in ids), None)
    if stray is not None:
        raise InputError(f"{out}: holds rows of another experiment than {this}: cell {stray} is not one of its "
                         "cells; choose another output folder")


def run_experiment(exp_path: str | Path, out_dir: str | Path, *, workers: int = 1, scheduler: str | None = None,
                   resume: bool = False, dry_run: bool = False, split: str | None = None,
                   progress: Callable[[dict, int, int], None] | None = None) -> list[dict]:
    """Run every cell (of the targets of ``split``, if given) not yet in ``out_dir/rows.jsonl``; return all rows
    (old and new)."""
    exp_path = str(Path(exp_path).resolve())
    exp: Experiment = load_experiment(exp_path, split)
    out = Path(out_dir)
    if not resume and not dry_run and (out / ROWS).is_file():
        n = sum(1 for line in (out / ROWS).read_bytes().split(b"\n") if line.strip())
        if n:
            raise InputError(f"{out / ROWS} already has {n} rows; pass --resume to continue it, "
                             "or choose another output folder")
    done = read_rows(out)
    ids = cell_identities(exp_path, exp)
    check_same_experiment(out, done, exp_path, exp, ids)
    finished = {r["key"] for r in done}
    todo = [c for c in exp.cells() if c.key not in finished]
    if dry_run:
        return [{"key": c.key, "status": "todo"} for c in todo]
    check_targets(exp_path, exp)
    if out.exists() and not out.is_dir():
        raise InputError(f"output {out}: expected a folder, got a file")
    created = not out.exists()
    with _executor(workers, scheduler) as submit:  # a scheduler that cannot be reached fails here
        from ipm.files import make_parent, refused, write_text
        from ipm.io.runs import write_json

        make_parent(out / ROWS)
        rows = list(done)
        try:
            with _exclusive(out):
                done = read_rows(out)  # again, now that no other bench writes here
                check_same_experiment(out, done, exp_path, exp, ids)
                todo = [c for c in exp.cells() if c.key not in {r["key"] for r in done}]
                rows = list(done)
                write_json(out / IDENTITY, {"name": exp.name, "file": exp_path, "cells": ids})
                if done:  # drop a torn last line before appending (atomically: a full disk keeps the rows)
                    write_text(out / ROWS, "".join(json.dumps(r) + "\n" for r in done))
                try:
                    f = open(out / ROWS, "a", buffering=1)
                except OSError as e:
                    raise refused(out / ROWS, e) from None
                try:
                    for row in submit(exp_path, todo, str(out.resolve())):
                        try:
                            f.write(json.dumps(row) + "\n")
                            f.flush()
                        except OSError as e:
                            raise refused(out / ROWS, e) from None
                        rows.append(row)
                        if progress is not None:
                            progress(row, len(rows) - len(done), len(todo))
                finally:
                    with suppress(OSError):  # a full disk: reported by the write
                        f.close()
        except BaseException:
            if created and len(rows) == 0:  # nothing to resume: leave nothing behind
                import shutil

                shutil.rmtree(out, ignore_errors=True)
            raise
    return rows


LOCK = ".bench.lock"


@contextmanager
def _exclusive(out: Path):
    """Hold ``out/.bench.lock`` for the run: a second bench on the same folder would rewrite rows.jsonl under
    the first one's appends and lose rows, so it is refused (``ValueError``) instead."""
    import fcntl

    with open(out / LOCK, "a") as lock:
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise InputError(f"{out}: another ipm bench is writing to this folder; wait for it to finish or "
                             "choose another output folder") from None
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


@contextmanager
def _executor(workers: int, scheduler: str | None):
    """Yield ``submit(exp_path, cells, out_dir)``, an iterator of finished rows, for the chosen backend:
    inline (one worker), local worker processes (which die with this process, even on SIGKILL), or a
    Dask scheduler (connected to before anything is written; ``InputError`` when it cannot be reached)."""
    if scheduler is not None:
        from dask.distributed import Client, as_completed

        try:
            client = Client(scheduler, timeout="10s")
        except (OSError, TimeoutError, ValueError) as e:
            raise InputError(f"--scheduler {scheduler}: cannot reach a Dask scheduler there ({e})") from None

        def submit_dask(exp_path, cells, out_dir):
            futures = [client.submit(run_cell, exp_path, c, out_dir, pure=False) for c in cells]
            for fut in as_completed(futures):
                yield fut.result()

        with client:
            yield submit_dask
        return
    if workers <= 1:
        yield lambda exp_path, cells, out_dir: (run_cell(exp_path, c, out_dir) for c in cells)
        return
    from concurrent.futures import as_completed

    from ipm.threads import process_pool

    pool = process_pool(workers)

    def submit_pool(exp_path, cells, out_dir):
        futures = [pool.submit(run_cell, exp_path, c, out_dir) for c in cells]
        for fut in as_completed(futures):
            yield fut.result()

    try:
        yield submit_pool
    finally:  # on an error or Ctrl-C, cells not yet started are dropped instead of waited for
        pool.shutdown(wait=True, cancel_futures=True)
