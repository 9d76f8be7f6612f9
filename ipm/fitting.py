"""``ipm.fit(...)``: the fit in a few lines, with a run folder, checkpoints and resume.

    import ipm
    result = ipm.fit("dishes", masks="out/mug_masks", preset="teacup", discrete="memetic",
                     budget=1500, seed=0, run_dir="runs/mug")
    result.params, result.scores["iou_mean"]

The run folder holds ``settings.json``, ``trajectory.jsonl`` (every evaluation; also the checkpoint),
``params.json``, ``mesh.glb``, ``mesh.obj``, ``result.json``, ``overlay_000.png`` ... and ``loss.png``.
``resume=True`` continues an interrupted run: the recorded evaluations are replayed, so with the same
seed the run ends where an uninterrupted one would (a replay that differs from its record, in the points
asked for or in the losses of the records it re-evaluates, raises :class:`~ipm.errors.InputError` naming
the folder), and ``wall_time_s`` counts the time of every run. ``settings.json`` keeps absolute paths (the
target's files, a generator file, macro folders), so a run resumes from any working folder; a damaged
``settings.json`` or ``trajectory.jsonl`` is an :class:`~ipm.errors.InputError` naming the file and the
field. A first run that fails on bad input (a full disk included) leaves no run folder behind; the final
files (``params.json`` to ``result.json``) are written all together or not at all.

:func:`fit_structure` does the same for a structure search (``checkpoint.json`` after every round).
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable
from dataclasses import fields, replace
from pathlib import Path

import torch

from ipm.errors import InputError
from ipm.threads import one_by_default
from ipm.types import FitResult

log = logging.getLogger(__name__)


def _settings_from_json(d: dict):
    """FitSettings from a run's settings.json; a key this version does not know is refused (a run of another
    version, or an edited file), naming it."""
    from ipm.optim.fit import FitSettings

    if not isinstance(d, dict):
        raise InputError(f"settings: expected an object, got {type(d).__name__}")
    known = {f.name for f in fields(FitSettings)}
    # runs recorded before the description length, the anchor and the learned proposals replay without them,
    # and those before the iso-surface silhouettes with the sphere tracer they ran; before the strategies owned
    # their settings, memetic's and nlopt's were fields of their own
    d = {"part_cost": 0.0, "anchor": 0.0, "init": "presets", "sdf_silhouette": "trace", **d}
    old = {k: d.pop(k) for k in ("memetic", "nlopt") if k in d}
    if old:
        d["search"] = {**old, **(d.get("search") or {})}
    unknown = sorted(set(d) - known)
    if unknown:
        raise InputError(f"settings: unknown key(s) {', '.join(unknown)}; expected keys among "
                         f"{', '.join(sorted(known))}")
    return FitSettings(**d)  # nested dicts become settings objects


@one_by_default
def fit(generator=None, *, masks: str | Path | None = None, target_mesh: str | Path | None = None, up: str = "y",
        depth: str | Path | None = None, depth_scale: float = 0.001, parts: str | Path | None = None,
        image: str | Path | None = None, mask: str | Path | None = None, box=None,
        intrinsics: str | Path | None = None, photo_size: int = 128, ground: bool = True,
        run_dir: str | Path | None = None, resume: bool = False, library: list[str] | None = None,
        progress: Callable | None = None, device=None, **settings) -> FitResult:
    """Fit ``generator`` (a name, tree file or Generator) to a target; see :class:`FitSettings` for
    ``settings`` (budget, seed, discrete, camera, loss, local, lr, preset, free, fix, depth_weight, ...).

    Targets (:mod:`ipm.io.fit_targets`): ``masks`` (a mask-set folder) with optional ``depth`` and ``parts``
    folders; a photo ``image`` with its ``mask`` or a ``box`` around the object, optional ``depth`` (a file)
    and ``intrinsics`` (the camera is fitted: with intrinsics its pose only; with depth too, ``ground`` holds
    its elevation at the plane the object stands on, :mod:`ipm.io.ground`); or ``target_mesh``.

    The run folder's ``settings.json`` records what the run needs to resume from any working folder: the
    target's files and the generator's file and ``library`` folders as absolute paths, resolved when the
    run starts. ``resume=True`` reads it (``generator`` may then be left out: the run's own is built again;
    a given one must have the run's generator's name), checks ``settings.json`` and every record of
    ``trajectory.jsonl`` against their schema (:mod:`ipm.io.runs`) and replays the records; the replay
    re-evaluates a few of them (:class:`~ipm.optim.evaluator.Evaluator`) and refuses records whose loss
    differs. Every refusal is an :class:`~ipm.errors.InputError` naming the file.

    A first run that fails on bad input (a full disk included) leaves no run folder behind
    (:func:`ipm.io.runs.first_run`; an interruption keeps the records, a run to resume); a resume that
    fails keeps the folder's run resumable. The final files are written all together or not at all."""
    from ipm.io.fit_targets import TargetFiles, load_target
    from ipm.io.runs import SETTINGS, TRAJECTORY, Trajectory, final_files, first_run, write_json
    from ipm.optim.evaluator import ReplayMismatch
    from ipm.optim.fit import check_proposals, hard_scores, init_mode, run_fit
    from ipm.optim.problem import Problem

    replay: list[dict] = []
    run_dir = Path(run_dir) if run_dir is not None else None
    if resume:
        gen, source, library, cfg, files, replay = _resumed(run_dir, generator, library)
    else:
        if generator is None:
            raise InputError("expected a generator: a name, a tree file or a Generator")
        gen = _generator(generator, library)
        source = _source(generator) if isinstance(generator, str) else None
        library = [str(Path(d).resolve()) for d in library] if library else None

        files = TargetFiles(masks=_absolute(masks), target_mesh=_absolute(target_mesh), up=up,
                            depth=_absolute(depth), depth_scale=depth_scale, parts=_absolute(parts),
                            image=_absolute(image), mask=_absolute(mask), intrinsics=_absolute(intrinsics),
                            box=None if box is None else tuple(int(v) for v in box), size=photo_size, ground=ground)
        cfg = _new_settings(settings, files)
        cfg = replace(cfg, init=init_mode(gen, cfg))  # where it started, not "the default" a later version may change
    cfg.check()
    target, photo = load_target(files, camera=cfg.camera, device=device)
    Problem(gen, target, cfg)  # settings that do not suit this generator fail here, before any file is written
    check_proposals(gen, target, cfg)  # and proposal weights that cannot be read
    sink = None
    with first_run(run_dir, resume=resume):
        if run_dir is not None:
            run_dir.mkdir(parents=True, exist_ok=True)
            if not resume:  # a resume keeps the run's own settings.json
                write_json(run_dir / SETTINGS, {"generator": gen.name, "source": source, "library": library,
                                                "settings": cfg.to_json(), "target": files.to_json()})
            sink = Trajectory(run_dir / TRAJECTORY, keep=len(replay))
        try:
            result, prob, best = run_fit(gen, target, cfg, sink=sink, replay=replay, progress=progress)
        except ReplayMismatch as e:
            raise InputError(f"--resume {run_dir}: the run does not match its recorded trajectory "
                             f"{run_dir / TRAJECTORY}: {e}") from e
        finally:
            if sink is not None:
                sink.close()
        scores = hard_scores(prob, best)
        if photo is not None:
            scores.update(photo_scores(prob, best, photo))
        mesh = prob.mesh_world(best["x"].to(torch.float64), best["discrete"]).detach()
        if run_dir is not None:
            with final_files(run_dir) as staged:  # the final files all at once, or none of them
                out = save_run(staged, prob, best, result, cfg, scores, photo, trajectory=run_dir / TRAJECTORY,
                               mesh=mesh)
            scores, pose = out["scores"], out["pose"]
        else:
            pose = prob.pose_json(best["x"].to(torch.float64), best["discrete"], symmetry=True, mesh=mesh)
    return replace(result, scores=scores, pose=pose, run_dir=None if run_dir is None else str(run_dir), shape=mesh)


def _new_settings(settings: dict, files):
    """The FitSettings of a new run: a proposals file kept absolute (a resume from elsewhere finds it), and a
    photo's camera fitted (a photo has no cameras.json)."""
    from ipm.optim.fit import FitSettings

    if settings.get("proposals") is not None:
        settings = {**settings, "proposals": _absolute(settings["proposals"])}
    if files.image is not None and settings.get("camera", "known") != "fit":
        settings = {**settings, "camera": "fit"}
    return FitSettings(**settings)


def _resumed(run_dir: Path | None, generator, library: list[str] | None):
    """What a resumed fit needs from its run folder: ``(generator, source, library, settings, target files,
    the records to replay)``, each checked (:mod:`ipm.io.runs`); :class:`InputError` names the file."""
    from ipm.io.fit_targets import TargetFiles
    from ipm.io.runs import SETTINGS, TRAJECTORY, read_run_file, read_trajectory

    if run_dir is None:
        raise InputError("--resume: expected a run folder, got none")
    saved = read_run_file(run_dir)
    where = f"--resume: run settings {run_dir / SETTINGS}"
    library = library or saved.library
    if generator is None:
        generator = saved.source or saved.generator
    gen = _generator(generator, library)
    if gen.name != saved.generator:
        raise InputError(f"--resume {run_dir}: expected the run's generator {saved.generator!r}, got {gen.name!r}")
    try:
        cfg = _settings_from_json(saved.settings)
        cfg.check()
    except InputError as e:
        raise InputError(f"{where}: settings: {e}") from None
    saved_files = saved.target if saved.target is not None else {
        k: getattr(saved, k) for k in ("masks", "target_mesh", "up") if getattr(saved, k) is not None}
    try:
        files = TargetFiles.from_json(saved_files)
    except InputError as e:
        raise InputError(f"{where}: target: {e}") from None
    try:
        replay = read_trajectory(run_dir / TRAJECTORY)
    except InputError as e:
        raise InputError(f"--resume: {e}") from None
    return gen, saved.source, library, cfg, files, replay


def _generator(generator, library: list[str] | None):
    """``generator`` itself, or the generator a name or file names (:func:`ipm.generators.get_generator`)."""
    from ipm.generators import get_generator

    return get_generator(generator, library=library) if isinstance(generator, str) else generator


def _source(name: str) -> str:
    """What builds the generator ``name`` again from any working folder: a generator file's absolute path,
    else the name (a registered generator or a named shape)."""
    from ipm.generators.base import GENERATORS

    if name not in GENERATORS and Path(name).is_file():
        return str(Path(name).resolve())
    return name


def photo_scores(prob, best: dict, photo) -> dict:
    """Scores of a photo fit at the photo's full resolution: mask IoU against the photo's mask, where each
    part of the fitted shape is seen (``parts_px``: a mug's handle right of its body has the larger x), the
    camera elevation held at the ground (``ground_elevation_deg``, where measured), and where the photo has
    depth, the median and mean absolute depth error in millimetres on the object's pixels
    that both see (``depth_px``: how many; millimetres assume the depth map reads in metres, as with the
    default ``depth_scale``)."""
    from ipm.io.fit_targets import uncrop_camera
    from ipm.metrics import mask_iou
    from ipm.render import deferred as R

    x = best["x"].to(torch.float64)
    mesh = prob.mesh_world(x, best["discrete"]).detach()
    cam = uncrop_camera(prob.cameras(x)[0], photo)
    rast = R.rasterize(mesh.verts, mesh.faces, cam)
    fg = photo.mask > 0.5
    out = {"photo_iou": round(float(mask_iou(rast.mask.numpy(), fg)), 5), "parts_px": _parts_px(mesh, rast)}
    if photo.ground is not None:
        out["ground_elevation_deg"] = round(photo.ground.elevation_deg, 2)
    if photo.depth is not None:
        import numpy as np

        d = R.depth(mesh.verts, mesh.faces, cam, rast).numpy() * photo.unit
        both = fg & rast.mask.numpy() & np.isfinite(photo.depth)
        err = np.abs(d[both] - photo.depth[both]) * 1000.0
        out.update({"depth_median_mm": round(float(np.median(err)), 3) if err.size else None,
                    "depth_mean_mm": round(float(err.mean()), 3) if err.size else None,
                    "depth_px": int(both.sum())})
    return out


def _parts_px(mesh, rast) -> dict:
    """Where each named part of ``mesh`` is seen in a raster: ``{name: [mean x, mean y, pixels]}`` (pixel
    centers), for the parts seen at all; a mesh without groups counts as one part, ``"all"``."""
    import numpy as np

    face = rast.face.cpu().numpy()
    seen = face >= 0
    named = mesh.groups is not None and bool(mesh.group_names)
    names = list(mesh.group_names) if named else ["all"]
    group = mesh.groups.cpu().numpy() if named else np.zeros(len(mesh.faces), dtype=np.int64)
    label = np.where(seen, group[np.where(seen, face, 0)], -1)
    out = {}
    for k, name in enumerate(names):
        ys, xs = np.nonzero(label == k)
        if xs.size:
            out[name] = [round(float(xs.mean()) + 0.5, 1), round(float(ys.mean()) + 0.5, 1), int(xs.size)]
    return out


def save_run(run_dir: Path, prob, best: dict, result: FitResult, settings,
             scores: dict, photo=None, *, trajectory: Path | None = None, mesh=None) -> dict:
    """Write params.json, mesh.glb, mesh.obj, result.json and pictures into ``run_dir`` (with a photo
    target, ``overlay_photo.png``: the fit's outline over the photo); the loss plot reads ``trajectory``
    (default: the one in ``run_dir``); ``mesh``: the posed mesh of ``best`` if already made."""
    import numpy as np

    import ipm
    from ipm.io.export import export_mesh
    from ipm.io.runs import RESULT, write_json
    from ipm.optim.targets import MaskTarget

    run_dir = Path(run_dir)
    x = best["x"].to(torch.float64)
    mesh = prob.mesh_world(x, best["discrete"]).detach() if mesh is None else mesh
    pose = prob.pose_json(x, best["discrete"], symmetry=True, mesh=mesh)
    meta = {"generator": prob.gen.name, "params": result.params, "pose": pose}
    write_json(run_dir / "params.json", meta)
    export_mesh(mesh, run_dir / "mesh.glb", meta, sidecar=False)
    export_mesh(mesh, run_dir / "mesh.obj", meta, sidecar=False)
    files = {"params": "params.json", "mesh": ["mesh.glb", "mesh.obj"]}
    if isinstance(prob.target, MaskTarget):
        from ipm.files import atomic_path
        from ipm.render.raster import rasterize_mesh
        from ipm.viz.overlay import overlay

        overlays = []
        for i, (cam, tgt) in enumerate(zip(prob.cameras(x), prob.target.masks)):
            pred = rasterize_mesh(mesh, cam).mask.cpu().numpy()
            path = run_dir / f"overlay_{i:03d}.png"
            with atomic_path(path) as tmp:
                overlay(tgt.cpu().numpy() > 0.5, pred, title=f"view {i}: target red, fit green").save(tmp, "PNG")
            overlays.append(path.name)
        files["overlays"] = overlays
    if photo is not None:
        files["photo_overlay"] = _photo_overlay(run_dir / "overlay_photo.png", prob, best, photo)
    from ipm.io.runs import TRAJECTORY, read_trajectory
    from ipm.viz.plots import plot_losses

    losses = [r["loss"] for r in read_trajectory(trajectory or run_dir / TRAJECTORY)]
    if losses:
        plot_losses({"loss": losses, "best so far": list(np.minimum.accumulate(losses))}, run_dir / "loss.png",
                    title=f"{prob.gen.name}: loss per evaluation")
        files["loss_plot"] = "loss.png"
    out = {
        "generator": prob.gen.name, "loss": result.loss, "evaluations": result.evaluations,
        "wall_time_s": round(result.wall_time_s, 3), "seed": settings.seed, "settings": settings.to_json(),
        "scores": scores, "params": result.params, "pose": pose,
        "discrete": best["discrete"], "tied": list(result.tied),
        "dropped": list(result.dropped), "start": result.start,
        "files": files,
        "versions": {"ipm": ipm.__version__, "torch": torch.__version__, "numpy": np.__version__},
    }
    write_json(run_dir / RESULT, out)
    return out


def _photo_overlay(path: Path, prob, best: dict, photo) -> str:
    """The photo with the fit's silhouette tinted green and its outline and the mask's drawn (fit: green,
    mask: red)."""
    import cv2
    import numpy as np

    from ipm.files import atomic_path
    from ipm.io.fit_targets import uncrop_camera
    from ipm.render.raster import rasterize_mesh

    x = best["x"].to(torch.float64)
    mesh = prob.mesh_world(x, best["discrete"]).detach()
    pred = rasterize_mesh(mesh, uncrop_camera(prob.cameras(x)[0], photo)).mask.cpu().numpy()
    out = photo.image.astype(np.float64)
    out[pred] = 0.7 * out[pred] + 0.3 * np.array([0.0, 255.0, 0.0])
    out = np.ascontiguousarray(out.round().astype(np.uint8))
    for m, color in ((photo.mask > 0.5, (255, 0, 0)), (pred, (0, 255, 0))):
        contours, _ = cv2.findContours(m.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        cv2.drawContours(out, contours, -1, color, 2)
    from PIL import Image

    with atomic_path(path) as tmp:
        Image.fromarray(out).save(tmp, "PNG")
    return path.name


STRUCTURE_CHECKPOINT = "checkpoint.json"
STRUCTURE_TRAJECTORY = "structures.jsonl"
STRUCTURE_RESOLUTION = 128   # mesh.obj: what `ipm generate tree.json` meshes at by default


@one_by_default
def fit_structure(*, target_mesh: str | Path | None = None, up: str = "y", masks: str | Path | None = None,
                  start: str | Path | None = None, run_dir: str | Path | None = None, resume: bool = False,
                  progress: Callable | None = None, device=None, **settings) -> FitResult:
    """Recover a tree's structure and parameters (:mod:`ipm.optim.structure`) from a mesh (normalized to
    DESIGN.md's unit sphere, as ``ipm fit --target-mesh``) or a mask set of K >= 2 views; ``start``: a tree
    file to begin from. ``settings``: :class:`~ipm.optim.structure.StructureSettings` fields.

    The run folder holds ``settings.json``, ``checkpoint.json`` (after every round), ``structures.jsonl``
    (every tree tried: its edit, structure, nodes, IoU, score, evaluations, the tree, in the search's frame),
    ``tree.json`` (the recovered tree, nested, which ``ipm generate`` loads, placed in the target's own frame:
    for a mesh target the search's unit-sphere tree under an outer ``place`` node, :func:`framed`),
    ``mesh.obj`` (that tree meshed as ``ipm generate`` does, lying on the target) and ``result.json``.
    ``resume=True`` continues after the last finished round and ends
    where an uninterrupted run would; it checks ``settings.json`` and ``checkpoint.json`` against their
    schema (:class:`~ipm.io.runs.StructureRunFile`, :class:`~ipm.optim.structure.search.State`) and scores
    the checkpoint's trees again (:func:`~ipm.optim.structure.search.verify_state`): a damaged or edited
    file is an :class:`~ipm.errors.InputError` naming it and the field. Paths are kept absolute (a run
    resumes from any working folder); a first run that fails on bad input leaves no run folder behind, and
    the final files are written all together or not at all. Returns a :class:`~ipm.types.FitResult` of kind
    "structure": its ``tree`` (placed), ``scores`` (``result.json``'s: structure, nodes, primitives, fit_iou,
    score, rounds, frame, ...) and :meth:`~ipm.types.FitResult.mesh`."""
    from ipm.io.runs import SETTINGS, Trajectory, first_run, write_json
    from ipm.optim.structure import StructureSettings, count_nodes, primitive_counts
    from ipm.optim.structure import search as run_search
    from ipm.optim.structure.program import signature, structure
    from ipm.optim.structure.search import verify_state
    from ipm.sdf.tree import load_tree, tree_to_json

    run_dir = Path(run_dir) if run_dir is not None else None
    state = None
    ckpt = None if run_dir is None else run_dir / STRUCTURE_CHECKPOINT
    if resume:
        cfg, target_mesh, up, masks, start, state = _structure_resumed(run_dir)
    else:
        cfg = StructureSettings(**settings)
        target_mesh, masks, start = _absolute(target_mesh), _absolute(masks), _absolute(start)
    cfg.check()
    if (target_mesh is None) == (masks is None):
        raise InputError("structure search: expected one target, a mesh or a mask set of K >= 2 views")
    start_tree = None
    if start is not None and state is None:  # a checkpoint's beam replaces the start
        start_tree = tree_to_json(load_tree(start))["tree"]
    samples, frame = _structure_samples(target_mesh, up, masks, cfg)
    samples = samples.to(device=device, dtype=torch.float32)
    if state is not None:
        try:
            verify_state(state, samples, cfg)
        except InputError as e:
            raise InputError(f"--resume: structure search checkpoint {ckpt}: {e}") from None
    sink = checkpoint = None
    with first_run(run_dir, resume=resume):
        if run_dir is not None:
            run_dir.mkdir(parents=True, exist_ok=True)
            if not resume:  # a resume keeps the run's own settings.json
                write_json(run_dir / SETTINGS, {"structure": cfg.to_json(), "start": start,
                                                "target": {"target_mesh": target_mesh, "up": up, "masks": masks}})
            sink = Trajectory(run_dir / STRUCTURE_TRAJECTORY, keep=int(state["records"]) if state else 0)
            checkpoint = _checkpoint_writer(ckpt)
        try:
            res = run_search(samples, cfg, start=start_tree, state=state, checkpoint=checkpoint, record=sink,
                             progress=progress)
        finally:
            if sink is not None:
                sink.close()
        # the tree in the target's own frame: the search ran in DESIGN.md's unit sphere (a mesh target),
        # and an outer place node takes it back, so that tree.json and mesh.obj lie on the target
        placed = res.tree if frame is None else framed(res.tree, frame)
        out = {"structure": structure(res.tree), "nodes": count_nodes(res.tree),
               "primitives": primitive_counts(res.tree), "adds": list(signature(res.tree)[0]),
               "cuts": list(signature(res.tree)[1]), "fit_iou": res.iou,
               "fit_iou_of": "occupancy on the sample grid" if masks is None else "silhouettes at the mask rays",
               "score": res.score, "evaluations": res.evaluations, "wall_time_s": round(res.wall_time_s, 3),
               "rounds": res.rounds, "stopped": res.stopped, "frame": frame}
        result = _structure_result(res, placed, out, run_dir)
    return result


def _structure_samples(target_mesh: str | None, up: str, masks: str | None, cfg):
    """``(samples, frame)``: the structure search's target samples (:mod:`ipm.optim.structure.samples`) and,
    for a mesh target, the frame that took it to DESIGN.md's unit sphere (``{"center", "scale"}``; None for
    masks, whose cameras' frame is the target's own)."""
    from ipm.optim.structure import mask_samples, mesh_samples

    if target_mesh is not None:
        from ipm.io.meshes import load_mesh
        from ipm.metrics import mesh_arrays, unit_sphere_frame

        raw = load_mesh(Path(target_mesh), up=up, normalize=False)
        center, scale = unit_sphere_frame(mesh_arrays(raw)[0])
        mesh = load_mesh(Path(target_mesh), up=up, normalize=True)
        samples = mesh_samples(mesh, surface=cfg.surface, volume=cfg.volume, grid=cfg.grid, seed=cfg.seed)
        return samples, {"center": [float(c) for c in center], "scale": float(scale)}
    from ipm.io.fit_targets import TargetFiles, load_target

    target, _ = load_target(TargetFiles(masks=str(masks)))
    return mask_samples(target.masks.cpu().numpy(), target.cameras, volume=cfg.volume, grid=cfg.grid,
                        seed=cfg.seed, rays=cfg.rays, fine_rays=cfg.fine_rays), None


def _structure_result(res, placed: dict, out: dict, run_dir: Path | None) -> FitResult:
    """The structure search's result (its tree ``placed`` in the target's frame, meshed) as a FitResult, and
    with ``run_dir`` its final files (tree.json, mesh.obj, result.json: all at once, or none)."""
    from ipm.generators.sdftree import SdfTreeGenerator
    from ipm.io.runs import RESULT, final_files, write_json
    from ipm.sdf.tree import tree_from_json

    gen = SdfTreeGenerator(tree_from_json({"tree": placed}))
    values = gen.spec.defaults()
    shape = gen.to_mesh(values, resolution=STRUCTURE_RESOLUTION)
    if run_dir is not None:
        from ipm.io.export import export_mesh

        out["run"] = str(run_dir)
        with final_files(run_dir) as staged:  # the final files all at once, or none of them
            write_json(staged / "tree.json", {"tree": placed})
            export_mesh(shape, staged / "mesh.obj", gen.metadata(values), sidecar=False)
            write_json(staged / RESULT, out)
    scores = {k: v for k, v in out.items() if k not in ("evaluations", "wall_time_s", "run")}
    return FitResult(generator=gen.name, params=values, loss=float(res.score), evaluations=res.evaluations,
                     wall_time_s=res.wall_time_s, scores=scores, run_dir=out.get("run"), kind="structure",
                     tree=placed, shape=shape)


def _absolute(p) -> str | None:
    """A path given to a fit as an absolute string (None stays None), so that its run resumes from any working
    folder."""
    return None if p is None else str(Path(p).resolve())


def _checkpoint_writer(path: Path):
    """``write(state)``: the structure search's checkpoint written to ``path`` atomically; a refusal of the OS
    (a full disk) names the file."""
    from ipm.files import refused, write_text

    def write(state: dict) -> None:
        try:
            write_text(path, json.dumps(state) + "\n")
        except OSError as e:
            raise refused(path, e) from None

    return write


def _structure_resumed(run_dir: Path | None):
    """What a resumed structure search needs from its run folder: ``(settings, target mesh, up, masks, start,
    the checkpoint's state or None)``, each checked against its schema; :class:`InputError` names the file."""
    from ipm.io.runs import SETTINGS, StructureRunFile, checked, read_json_file, read_json_lines, read_run_file
    from ipm.optim.structure import StructureSettings
    from ipm.optim.structure.search import State

    if run_dir is None:
        raise InputError("--resume: expected a run folder, got none")
    saved = read_run_file(run_dir, StructureRunFile)
    try:
        cfg = StructureSettings.from_json(saved.structure)
    except InputError as e:
        raise InputError(f"--resume: run settings {run_dir / SETTINGS}: {e}") from None
    state = None
    ckpt = run_dir / STRUCTURE_CHECKPOINT
    if ckpt.is_file():
        where = f"--resume: structure search checkpoint {ckpt}"
        try:
            state = read_json_file(ckpt, "structure search checkpoint")
        except InputError as e:
            raise InputError(f"--resume: {e}") from None
        checked(state, State, where)
        try:
            records = read_json_lines(run_dir / STRUCTURE_TRAJECTORY, "structure search records")
        except InputError as e:
            raise InputError(f"--resume: {e}") from None
        if len(records) < state["records"]:
            raise InputError(f"{where}: records: expected at most the {len(records)} records of "
                             f"{STRUCTURE_TRAJECTORY}, got {state['records']}")
    t = saved.target
    return cfg, t.target_mesh, t.up, t.masks, saved.start, state


def framed(tree: dict, frame: dict) -> dict:
    """The nested tree ``tree`` of the unit-sphere frame placed back in a target's frame ``{"center", "scale"}``
    (:func:`ipm.metrics.unit_sphere_frame`: unit = (target - center) * scale): an outer ``place`` node (its unit
    1 / scale, moved to the center; exact, so distances stay true; its values held by fits)."""
    cx, cy, cz = (float(c) for c in frame["center"])
    return {"node": "place", "params": {"x": cx, "y": cy, "z": cz, "unit": 1.0 / float(frame["scale"])},
            "children": [tree]}


def fit_shape(tree, image, *, run_dir: str | Path | None = None, profile: bool = False, extrude: float | None = None,
              steps: int = 400, loss: str = "iou", transport: dict | None = None, seed: int = 0) -> FitResult:
    """A 2D tree (``tree``: a file or :class:`~ipm.sdf.tree.Tree` with a 2D root) fitted to a binary ``image``
    (a file or an (H, W) array) (:func:`ipm.optim.fit2d.fit_2d`): as the shape itself in a similarity pose,
    or with ``profile`` as the profile of a body of revolution seen from the side; a profile is lifted by
    revolve and a shape by ``extrude`` (a height) into a 3D tree.

    The run folder (``run_dir``, written all at once) holds ``tree.json`` (the fitted 2D tree), ``result.json``,
    ``overlay.png`` and, for a lifted fit, ``lifted.json`` (the 3D tree ``ipm generate`` loads) and ``mesh.obj``.
    Returns a :class:`~ipm.types.FitResult` of kind "2d": its ``tree`` (the lifted tree where lifted, else the
    2D one), ``scores`` (mode, pose, iou, steps, seconds) and, where lifted, :meth:`~ipm.types.FitResult.mesh`."""
    import numpy as np

    from ipm.files import staged_directory, write_text
    from ipm.losses import TransportSettings
    from ipm.optim.fit2d import Fit2DSettings, fit_2d, lifted
    from ipm.sdf.tree import Tree, load_tree, tree_from_json, tree_to_json

    if profile and extrude is not None:
        raise InputError("profile and extrude: a profile is lifted by revolve; give one of them")
    if extrude is not None and not (0 < extrude < float("inf")):
        raise InputError(f"extrude: expected a positive height, got {extrude}")
    run_dir = Path(run_dir) if run_dir is not None else None
    if run_dir is not None and run_dir.exists() and (not run_dir.is_dir() or any(run_dir.iterdir())):
        raise InputError(f"run folder {run_dir} exists and is not an empty folder; choose a new folder")
    tree = tree if isinstance(tree, Tree) else load_tree(tree, dim=None)
    if tree.dim != 2:
        raise InputError(f"2D fit: expected a tree with a 2D root, got a 3D {tree.root.type_name}; 3D trees fit "
                         "to masks, a photo or a mesh")
    if isinstance(image, (str, Path)):
        from ipm.io.masks import read_mask

        name, mask = str(image), read_mask(image)
    else:
        name, mask = "image", np.asarray(image)
    torch.manual_seed(seed)
    try:
        settings = Fit2DSettings(mode="profile" if profile else "shape", steps=steps, loss=loss,
                                 transport=TransportSettings(**(transport or {}))).check()
    except TypeError as e:
        raise InputError(f"2D fit settings: {e}") from None
    try:
        res = fit_2d(tree, mask, settings)
    except InputError as e:
        raise InputError(f"2D fit of {name}: {e}") from None
    out = {"run": None if run_dir is None else str(run_dir), **res.to_json()}
    out["settings"] = {"mode": settings.mode, "steps": settings.steps, "loss": settings.loss, "seed": seed}
    lift = lifted(res, extrude) if profile or extrude is not None else None
    shape = None
    if lift is not None:
        from ipm.generators.sdftree import SdfTreeGenerator

        gen3 = SdfTreeGenerator(tree_from_json(lift), "sdftree", "lifted.json")
        shape = gen3.to_mesh(gen3.spec.defaults(), resolution=128)
    if run_dir is not None:
        with staged_directory(run_dir) as tmp:
            write_text(tmp / "tree.json", json.dumps(tree_to_json(res.tree), indent=1) + "\n")
            from ipm.viz.overlay import overlay

            overlay(mask, res.mask, title=f"2D fit ({res.mode}): target red, fit green").save(tmp / "overlay.png",
                                                                                            "PNG")
            files = {"tree": "tree.json", "overlay": "overlay.png"}
            if lift is not None:
                from ipm.io.export import export_mesh

                write_text(tmp / "lifted.json", json.dumps(lift, indent=1) + "\n")
                export_mesh(shape, tmp / "mesh.obj", sidecar=False)
                files.update(lifted="lifted.json", mesh="mesh.obj")
            out["files"] = files
            write_text(tmp / "result.json", json.dumps(out, indent=1) + "\n")
    scores = {k: out[k] for k in ("mode", "pose", "iou", "steps", "seconds")}
    return FitResult(generator="sdftree", params=res.tree.values(), loss=float(res.loss), evaluations=res.steps,
                     wall_time_s=res.seconds, scores=scores, run_dir=out["run"], kind="2d",
                     tree=(lift or tree_to_json(res.tree))["tree"], shape=shape)
