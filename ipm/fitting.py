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
from ipm.types import FitResult

log = logging.getLogger(__name__)


def _settings_from_json(d: dict):
    """FitSettings from a run's settings.json (fields this version does not know are ignored)."""
    from ipm.optim.fit import FitSettings

    if not isinstance(d, dict):
        raise InputError(f"settings: expected an object, got {type(d).__name__}")
    known = {f.name for f in fields(FitSettings)}
    return FitSettings(**{k: v for k, v in d.items() if k in known})  # nested dicts become settings objects


def load_target(*, masks: str | Path | None = None, target_mesh: str | Path | None = None, up: str = "y",
                camera: str = "known", device=None, dtype=torch.float32):
    """A MaskTarget from a mask folder, or a MeshTarget from a mesh file (normalized as in DESIGN.md)."""
    from ipm.optim.targets import MaskTarget, MeshTarget

    if (masks is None) == (target_mesh is None):
        raise InputError("expected exactly one target, masks (a folder) or a target mesh; got "
                         + ("both" if masks is not None else "neither"))
    if masks is not None:
        from ipm.io.masks import CAMERAS_FILE, load_mask_set

        folder = Path(masks)
        if camera == "fit" and not (folder / CAMERAS_FILE).is_file():
            m, cams = _masks_without_cameras(folder)
        else:
            if not (folder / CAMERAS_FILE).is_file():
                raise InputError(f"--masks {folder}: expected {CAMERAS_FILE}, got no {CAMERAS_FILE}; give the "
                                 "cameras, or recover them with --camera fit")
            ms = load_mask_set(folder)
            m, cams = ms.masks, list(ms.cameras)
            sizes = {(c.width, c.height) for c in cams}
            if len(sizes) > 1:
                raise InputError(f"--masks {folder}: expected masks of one size, got sizes {sorted(sizes)}")
        t = torch.as_tensor(m, device=device).to(dtype)
        return MaskTarget(t, [c.to(dtype=dtype, device=device) for c in cams])
    from ipm.io.meshes import load_mesh

    mesh = load_mesh(Path(target_mesh), up=up, normalize=True)
    if mesh.n_faces == 0:
        raise InputError(f"target mesh {target_mesh}: expected faces, got none")
    return MeshTarget(mesh)


def _masks_without_cameras(folder: Path):
    """Masks ``view_*.png`` of one size and placeholder cameras (protocol pose) for ``camera="fit"``."""
    import numpy as np

    from ipm.io.masks import read_mask
    from ipm.render.camera import orbit_camera

    paths = sorted(folder.glob("view_*.png"))
    if len(paths) != 1:
        raise InputError(f"--camera fit: expected exactly one mask view_000.png in {folder}, got {len(paths)}")
    m = read_mask(paths[0])
    H, W = m.shape
    return np.stack([m]), [orbit_camera(0.0, 25.0, 3.2, fov_deg=40.0, width=W, height=H)]


def fit(generator, *, masks: str | Path | None = None, target_mesh: str | Path | None = None, up: str = "y",
        run_dir: str | Path | None = None, resume: bool = False, library: list[str] | None = None,
        progress: Callable | None = None, device=None, **settings) -> FitResult:
    """Fit ``generator`` (a name, tree file or Generator) to masks or a mesh; see :class:`FitSettings`
    for ``settings`` (budget, seed, discrete, camera, loss, local, lr, preset, free, fix, ...)."""
    from ipm.generators import get_generator
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
        masks, target_mesh, up = saved.get("masks"), saved.get("target_mesh"), saved.get("up", "y")
        replay = read_trajectory(run_dir / TRAJECTORY)
    else:
        cfg = FitSettings(**settings)
    cfg.check()
    target = load_target(masks=masks, target_mesh=target_mesh, up=up, camera=cfg.camera, device=device)
    Problem(gen, target, cfg)  # settings that do not suit this generator fail here, before any file is written
    sink = None
    if run_dir is not None:
        run_dir.mkdir(parents=True, exist_ok=True)
        write_json(run_dir / SETTINGS, {"generator": gen.name, "settings": cfg.to_json(),
                                        "masks": None if masks is None else str(masks),
                                        "target_mesh": None if target_mesh is None else str(target_mesh),
                                        "up": up})
        sink = Trajectory(run_dir / TRAJECTORY, keep=len(replay))
    try:
        result, prob, best = run_fit(gen, target, cfg, sink=sink, replay=replay, progress=progress)
    except ReplayMismatch as e:
        raise InputError(f"--resume {run_dir}: the run does not match its recorded trajectory: {e}") from e
    finally:
        if sink is not None:
            sink.close()
    scores = hard_scores(prob, best)
    if run_dir is not None:
        out = save_run(run_dir, prob, best, result, cfg, scores)
        scores = out["scores"]
    return replace(result, scores=scores, run_dir=None if run_dir is None else str(run_dir))


def save_run(run_dir: Path, prob, best: dict, result: FitResult, settings,
             scores: dict) -> dict:
    """Write params.json, mesh.glb, mesh.obj, result.json and pictures into ``run_dir``."""
    import numpy as np

    import ipm
    from ipm.io.export import export_mesh
    from ipm.io.runs import RESULT, write_json
    from ipm.optim.targets import MaskTarget

    run_dir = Path(run_dir)
    x = best["x"].to(torch.float64)
    mesh = prob.mesh_world(x, best["discrete"]).detach()
    meta = {"generator": prob.gen.name, "params": result.params, "pose": prob.pose_json(x, best["discrete"])}
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
        "scores": scores, "params": result.params, "pose": prob.pose_json(x, best["discrete"]),
        "discrete": best["discrete"], "tied": list(result.tied),
        "files": files,
        "versions": {"ipm": ipm.__version__, "torch": torch.__version__, "numpy": np.__version__},
    }
    write_json(run_dir / RESULT, out)
    return out
