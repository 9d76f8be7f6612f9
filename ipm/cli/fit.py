"""``ipm fit GEN (--target-mesh MESH | --masks DIR) ... -o RUN_DIR``."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated

import typer

from ipm.cli.common import DeviceOpt, JsonOpt, LibraryOpt, PresetOpt, SeedOpt, UsageError, emit, resolve_device


def register(app: typer.Typer) -> None:
    @app.command()
    def fit(
        gen: Annotated[str | None, typer.Argument(help="generator name, tree preset, or tree file (.json); "
                                                  "with --resume, the run's own")] = None,
        output: Annotated[Path | None, typer.Option("-o", "--output", help="run folder")] = None,
        masks: Annotated[Path | None, typer.Option(help="mask folder: view_000.png ... + cameras.json")] = None,
        target_mesh: Annotated[Path | None, typer.Option("--target-mesh", help="mesh to match (Chamfer)")] = None,
        up: Annotated[str, typer.Option(help="up axis of --target-mesh: y or z")] = "y",
        camera: Annotated[str, typer.Option(help="known (cameras.json) or fit (recover elevation, "
                                                 "distance, FOV)")] = "known",
        discrete: Annotated[str, typer.Option(help="discrete search strategy (ipm list strategies)")] = "memetic",
        budget: Annotated[int, typer.Option(help="function evaluations (one render + loss each)")] = 1500,
        seed: SeedOpt = 0,
        preset: PresetOpt = None,
        loss: Annotated[str, typer.Option(help="mask loss (ipm list losses)")] = "iou",
        local: Annotated[str, typer.Option(help="gradient refinement: adam, mma or lbfgs (nlopt)")] = "adam",
        lr: Annotated[float | None, typer.Option(help="Adam learning rate in normalized parameter space "
                                                 "(default: the generator's, 0.005 for dishes, else 0.02)")] = None,
        nlopt_algorithm: Annotated[str, typer.Option("--nlopt-algorithm",
                                                     help="GN_CRS2_LM, GN_ESCH or GN_ISRES")] = "GN_CRS2_LM",
        fix: Annotated[list[str] | None, typer.Option(help="NAME=VALUE held fixed, repeatable")] = None,
        range_: Annotated[list[str] | None, typer.Option(
            "--range", help="NAME=LO:HI search a discrete parameter only in [LO, HI], repeatable")] = None,
        no_pose: Annotated[bool, typer.Option("--no-pose", help="keep the object pose fixed")] = False,
        prior: Annotated[float, typer.Option(help="weight of a pull towards the starting preset")] = 0.0,
        resume: Annotated[Path | None, typer.Option(help="continue an interrupted run folder")] = None,
        library: LibraryOpt = None,
        device: DeviceOpt = "auto",
        json_out: JsonOpt = False,
    ) -> None:
        """Recover continuous and discrete parameters from masks or a mesh."""
        from ipm.fitting import fit as run
        from ipm.optim import discrete as D
        from ipm.params import parse_assignment

        if resume is None and output is None:
            raise UsageError("expected -o RUN_DIR (or --resume RUN_DIR)")
        if resume is not None and output is not None and output != resume:
            raise UsageError("--resume RUN_DIR continues that folder; leave out -o or give the same folder")
        if gen is None:
            if resume is None:
                raise UsageError("expected a generator: ipm fit GEN ... (see ipm list generators)")
            gen = _run_generator(resume)
        if resume is None and (masks is None) == (target_mesh is None):
            raise UsageError("expected exactly one target: --masks DIR or --target-mesh MESH")
        if budget < 1:
            raise UsageError(f"--budget: expected at least 1 evaluation, got {budget}")
        if up not in ("y", "z"):
            raise UsageError(f"--up: expected y or z, got {up!r}")
        if nlopt_algorithm not in D.NLOPT_GLOBAL:
            raise UsageError(f"--nlopt-algorithm: expected one of {', '.join(D.NLOPT_GLOBAL)}, got {nlopt_algorithm!r}")
        if masks is not None and not masks.is_dir():
            raise UsageError(f"--masks: folder not found: {masks}")
        if target_mesh is not None and not target_mesh.is_file():
            raise UsageError(f"--target-mesh: file not found: {target_mesh}")
        if output is not None and output.exists() and not output.is_dir():
            raise UsageError(f"run folder {output} is a file; expected a new or empty folder")
        if output is not None and output.exists() and resume is None and any(output.iterdir()):
            raise UsageError(f"run folder {output} exists and is not empty; choose a new folder or --resume it")
        fixed = dict(parse_assignment(s) for s in fix or [])
        ranges = {}
        for item in range_ or []:
            name, _, span = item.partition("=")
            lo, _, hi = span.partition(":")
            try:
                ranges[name.strip()] = [int(lo), int(hi)]
            except ValueError:
                raise UsageError(f"--range: expected NAME=LO:HI with integers, got {item!r}") from None
        dev = resolve_device(device)
        from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

        bar = Progress(TextColumn("{task.fields[phase]:<18}"), BarColumn(), TextColumn("{task.completed}/{task.total}"),
                       TextColumn("loss {task.fields[loss]:.4f}  IoU {task.fields[iou]}"), TimeElapsedColumn(),
                       transient=True, console=__import__("rich.console").console.Console(stderr=True))
        task = bar.add_task("fit", total=budget, phase="start", loss=float("nan"), iou="-")

        started = []

        def progress(ev):
            if not started:  # shown from the first evaluation: bad input fails before, with one line
                bar.start()
                started.append(True)
            iou = ev.last.get("iou")
            bar.update(task, completed=ev.count, total=ev.budget, phase=ev.phase[:18], loss=min(ev.best.loss, 9e9),
                       iou="-" if iou is None else f"{min(iou):.3f}")

        try:
            result = run(gen, masks=masks, target_mesh=target_mesh, up=up, run_dir=resume or output,
                         resume=resume is not None, library=[str(p) for p in library] if library else None,
                         progress=progress, device=dev, budget=budget, seed=seed, discrete=discrete, camera=camera,
                         loss=loss, local=local, lr=lr, preset=preset, fix=fixed, ranges=ranges,
                         pose=not no_pose,
                         prior_weight=prior, nlopt=D.NloptSettings(algorithm=nlopt_algorithm))
        finally:
            if started:
                bar.stop()
        out = {"run": result.run_dir, "loss": result.loss, "evaluations": result.evaluations,
               "wall_time_s": round(result.wall_time_s, 2), **{k: v for k, v in result.scores.items()}}
        emit(out, json_out)
        sys.stdout.flush()


def _run_generator(run_dir: Path) -> str:
    """The generator a run folder was fitted with (its ``settings.json``), for ``--resume`` alone."""
    settings = run_dir / "settings.json"
    if not settings.is_file():
        raise UsageError(f"--resume: {run_dir} is not a run folder (no settings.json)")
    try:
        saved = json.loads(settings.read_text())
        return str(saved.get("source") or saved["generator"])
    except (UnicodeDecodeError, json.JSONDecodeError, KeyError, TypeError, AttributeError):
        raise UsageError(f"--resume: {settings} is not a run's settings file (expected JSON with a "
                         "generator)") from None
