"""``ipm.fit(...)``: the fit in a few lines, with a run folder, checkpoints and resume.

    import ipm
    result = ipm.fit("dishes", masks="out/mug_masks", preset="teacup", discrete="memetic",
                     budget=1500, seed=0, run_dir="runs/mug")
    result.params, result.scores["iou_mean"]

The run folder holds ``settings.json``, ``trajectory.jsonl`` (every evaluation; also the checkpoint),
``params.json``, ``mesh.glb``, ``mesh.obj``, ``result.json``, ``overlay_000.png`` ... and ``loss.png``.
``resume=True`` continues an interrupted run: the recorded evaluations are replayed, so with the same
seed the run ends where an uninterrupted one would (a replay that differs from its record raises
:class:`~ipm.errors.InputError` naming the folder), and ``wall_time_s`` counts the time of every run.
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
    """FitSettings from a run's settings.json (fields this version does not know are ignored)."""
    from ipm.optim.fit import FitSettings

    if not isinstance(d, dict):
        raise InputError(f"settings: expected an object, got {type(d).__name__}")
    known = {f.name for f in fields(FitSettings)}
    # runs recorded before the description length and the anchor replay without them
    d = {"part_cost": 0.0, "anchor": 0.0, **d}
    return FitSettings(**{k: v for k, v in d.items() if k in known})  # nested dicts become settings objects


@one_by_default
def fit(generator, *, masks: str | Path | None = None, target_mesh: str | Path | None = None, up: str = "y",
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
    its elevation at the plane the object stands on, :mod:`ipm.io.ground`); or ``target_mesh``."""
    from ipm.generators import get_generator
    from ipm.io.fit_targets import TargetFiles, load_target
    from ipm.io.runs import SETTINGS, TRAJECTORY, Trajectory, read_trajectory, write_json
    from ipm.optim.evaluator import ReplayMismatch
    from ipm.optim.fit import FitSettings, hard_scores, run_fit
    from ipm.optim.problem import Problem

    gen = get_generator(generator, library=library) if isinstance(generator, str) else generator
    replay: list[dict] = []
    run_dir = Path(run_dir) if run_dir is not None else None
    if resume:
        if run_dir is None or not (run_dir / SETTINGS).is_file():
            raise InputError(f"--resume: expected a run folder with {SETTINGS}, got {run_dir}")
        try:
            saved = json.loads((run_dir / SETTINGS).read_text())
        except json.JSONDecodeError as e:
            raise InputError(f"--resume {run_dir}: expected JSON in {SETTINGS}, got {e.msg} at line {e.lineno}"
                             ) from None
        if not isinstance(saved, dict) or "settings" not in saved:
            raise InputError(f"--resume {run_dir}: expected the settings of a run in {SETTINGS}, got none")
        if saved.get("generator") != gen.name:
            raise InputError(f"--resume {run_dir}: expected the run's generator {saved.get('generator')!r}, "
                             f"got {gen.name!r}")
        cfg = _settings_from_json(saved["settings"])
        saved_files = saved.get("target") or {k: saved.get(k) for k in ("masks", "target_mesh", "up") if saved.get(k)}
        if not isinstance(saved_files, dict):
            raise InputError(f"--resume {run_dir}: expected the target's files in {SETTINGS}, got {saved_files!r:.60}")
        files = TargetFiles.from_json(saved_files)
        replay = read_trajectory(run_dir / TRAJECTORY)
    else:
        def opt(p):
            return None if p is None else str(p)

        files = TargetFiles(masks=opt(masks), target_mesh=opt(target_mesh), up=up, depth=opt(depth),
                            depth_scale=depth_scale, parts=opt(parts), image=opt(image), mask=opt(mask),
                            box=None if box is None else tuple(int(v) for v in box), intrinsics=opt(intrinsics),
                            size=photo_size, ground=ground)
        if files.image is not None and settings.get("camera", "known") != "fit":
            settings = {**settings, "camera": "fit"}  # a photo has no cameras.json
        cfg = FitSettings(**settings)
    cfg.check()
    target, photo = load_target(files, camera=cfg.camera, device=device)
    Problem(gen, target, cfg)  # settings that do not suit this generator fail here, before any file is written
    sink = None
    if run_dir is not None:
        run_dir.mkdir(parents=True, exist_ok=True)
        write_json(run_dir / SETTINGS, {"generator": gen.name, "settings": cfg.to_json(), "target": files.to_json()})
        sink = Trajectory(run_dir / TRAJECTORY, keep=len(replay))
    try:
        result, prob, best = run_fit(gen, target, cfg, sink=sink, replay=replay, progress=progress)
    except ReplayMismatch as e:
        raise InputError(f"--resume {run_dir}: the run does not match its recorded trajectory: {e}") from e
    finally:
        if sink is not None:
            sink.close()
    scores = hard_scores(prob, best)
    if photo is not None:
        scores.update(photo_scores(prob, best, photo))
    if run_dir is not None:
        out = save_run(run_dir, prob, best, result, cfg, scores, photo)
        scores, pose = out["scores"], out["pose"]
    else:
        pose = prob.pose_json(best["x"].to(torch.float64), best["discrete"], symmetry=True)
    return replace(result, scores=scores, pose=pose, run_dir=None if run_dir is None else str(run_dir))


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
             scores: dict, photo=None) -> dict:
    """Write params.json, mesh.glb, mesh.obj, result.json and pictures into ``run_dir`` (with a photo
    target, ``overlay_photo.png``: the fit's outline over the photo)."""
    import numpy as np

    import ipm
    from ipm.io.export import export_mesh
    from ipm.io.runs import RESULT, write_json
    from ipm.optim.targets import MaskTarget

    run_dir = Path(run_dir)
    x = best["x"].to(torch.float64)
    mesh = prob.mesh_world(x, best["discrete"]).detach()
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

    losses = [r["loss"] for r in read_trajectory(run_dir / TRAJECTORY)]
    if losses:
        plot_losses({"loss": losses, "best so far": list(np.minimum.accumulate(losses))}, run_dir / "loss.png",
                    title=f"{prob.gen.name}: loss per evaluation")
        files["loss_plot"] = "loss.png"
    out = {
        "generator": prob.gen.name, "loss": result.loss, "evaluations": result.evaluations,
        "wall_time_s": round(result.wall_time_s, 3), "seed": settings.seed, "settings": settings.to_json(),
        "scores": scores, "params": result.params, "pose": pose,
        "discrete": best["discrete"], "tied": list(result.tied),
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
                  progress: Callable | None = None, device=None, **settings) -> dict:
    """Recover a tree's structure and parameters (:mod:`ipm.optim.structure`) from a mesh (normalized to
    DESIGN.md's unit sphere, as ``ipm fit --target-mesh``) or a mask set of K >= 2 views; ``start``: a tree
    file to begin from. ``settings``: :class:`~ipm.optim.structure.StructureSettings` fields.

    The run folder holds ``settings.json``, ``checkpoint.json`` (after every round), ``structures.jsonl``
    (every tree tried: its edit, structure, nodes, IoU, score, evaluations, the tree), ``tree.json`` (the
    recovered tree, nested, which ``ipm generate`` loads), ``mesh.obj`` (that tree meshed as ``ipm
    generate`` does) and ``result.json``. ``resume=True`` continues after the last finished round and ends
    where an uninterrupted run would. Returns ``result.json``'s content."""
    from ipm.files import write_text
    from ipm.io.runs import RESULT, SETTINGS, Trajectory, write_json
    from ipm.optim.structure import StructureSettings, count_nodes, mask_samples, mesh_samples, primitive_counts
    from ipm.optim.structure import search as run_search
    from ipm.optim.structure.program import signature, structure
    from ipm.sdf.tree import load_tree, tree_to_json

    run_dir = Path(run_dir) if run_dir is not None else None
    state = None
    if resume:
        if run_dir is None or not (run_dir / SETTINGS).is_file():
            raise InputError(f"--resume: expected a run folder with {SETTINGS}, got {run_dir}")
        saved = _read_run_json(run_dir / SETTINGS, run_dir)
        if not isinstance(saved, dict) or "structure" not in saved:
            raise InputError(f"--resume {run_dir}: expected the settings of a structure search in {SETTINGS}")
        cfg = StructureSettings.from_json(saved["structure"])
        files = saved.get("target") or {}
        target_mesh, up, masks, start = files.get("target_mesh"), files.get("up", "y"), files.get("masks"), \
            saved.get("start")
        if (run_dir / STRUCTURE_CHECKPOINT).is_file():
            state = _read_run_json(run_dir / STRUCTURE_CHECKPOINT, run_dir)
            need = ("round", "beam", "best", "stale", "used", "elapsed", "records")
            if not isinstance(state, dict) or any(k not in state for k in need) or not state["beam"]:
                raise InputError(f"--resume {run_dir}: expected a structure search's checkpoint in "
                                 f"{STRUCTURE_CHECKPOINT} (keys {', '.join(need)}), got another file")
    else:
        cfg = StructureSettings(**settings)
    cfg.check()
    if (target_mesh is None) == (masks is None):
        raise InputError("structure search: expected one target, a mesh or a mask set of K >= 2 views")
    start_tree = None
    if start is not None:
        start_tree = tree_to_json(load_tree(start))["tree"]
    frame = None
    if target_mesh is not None:
        from ipm.io.meshes import load_mesh
        from ipm.metrics import mesh_arrays, unit_sphere_frame

        raw = load_mesh(Path(target_mesh), up=up, normalize=False)
        center, scale = unit_sphere_frame(mesh_arrays(raw)[0])
        frame = {"center": [float(c) for c in center], "scale": float(scale)}
        mesh = load_mesh(Path(target_mesh), up=up, normalize=True)
        samples = mesh_samples(mesh, surface=cfg.surface, volume=cfg.volume, grid=cfg.grid, seed=cfg.seed)
    else:
        from ipm.io.fit_targets import TargetFiles, load_target

        target, _ = load_target(TargetFiles(masks=str(masks)))
        samples = mask_samples(target.masks.cpu().numpy(), target.cameras, volume=cfg.volume, grid=cfg.grid,
                               seed=cfg.seed)
    samples = samples.to(device=device, dtype=torch.float32)
    sink = checkpoint = None
    if run_dir is not None:
        run_dir.mkdir(parents=True, exist_ok=True)
        write_json(run_dir / SETTINGS, {"structure": cfg.to_json(), "start": None if start is None else str(start),
                                        "target": {"target_mesh": None if target_mesh is None else str(target_mesh),
                                                   "up": up, "masks": None if masks is None else str(masks)}})
        sink = Trajectory(run_dir / STRUCTURE_TRAJECTORY, keep=int(state["records"]) if state else 0)

        def checkpoint(st: dict) -> None:
            write_text(run_dir / STRUCTURE_CHECKPOINT, json.dumps(st) + "\n")
    try:
        res = run_search(samples, cfg, start=start_tree, state=state, checkpoint=checkpoint, record=sink,
                         progress=progress)
    finally:
        if sink is not None:
            sink.close()
    out = {"structure": structure(res.tree), "nodes": count_nodes(res.tree), "primitives": primitive_counts(res.tree),
           "adds": list(signature(res.tree)[0]), "cuts": list(signature(res.tree)[1]), "fit_iou": res.iou,
           "fit_iou_of": "occupancy on the sample grid" if masks is None else "silhouettes at the mask rays",
           "score": res.score, "evaluations": res.evaluations, "wall_time_s": round(res.wall_time_s, 3),
           "rounds": res.rounds, "stopped": res.stopped, "frame": frame}
    if run_dir is not None:
        from ipm.generators import get_generator
        from ipm.io.export import export_mesh

        write_json(run_dir / "tree.json", {"tree": res.tree})
        gen = get_generator(str(run_dir / "tree.json"))
        values = gen.spec.defaults()
        export_mesh(gen.to_mesh(values, resolution=STRUCTURE_RESOLUTION), run_dir / "mesh.obj", gen.metadata(values),
                    sidecar=False)
        out["run"] = str(run_dir)
        write_json(run_dir / RESULT, out)
    out["tree"] = res.tree
    return out


def _read_run_json(path: Path, run_dir: Path):
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise InputError(f"--resume {run_dir}: expected JSON in {path.name}, got {e.msg} at line {e.lineno}") from None
