"""``ipm train-subdivision -o WEIGHTS.npz``: train neural subdivision on procedural dish pairs.

A checkpoint (``WEIGHTS.ckpt.npz``: weights, Adam's state, the step, the settings) is rewritten every
``--checkpoint-every`` steps; ``--resume`` continues from it with the same settings. At the end the
weights alone are written to ``-o`` (atomically), the checkpoint is removed, and the mean distance of the
last level's vertices to their exact positions is reported on held-out pairs for the network, midpoint
and Loop subdivision."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated

import typer

from ipm.cli.common import JsonOpt, SeedOpt, UsageError, check_output, emit

HELD_OUT = 8


def register(app: typer.Typer) -> None:
    @app.command("train-subdivision")
    def train_subdivision(
        output: Annotated[Path, typer.Option("-o", "--output", help="weights file (.npz)")],
        pairs: Annotated[int, typer.Option(help="training pairs (dishes presets, parameters moved)")] = 32,
        steps: Annotated[int, typer.Option(help="Adam steps, one pair each")] = 1500,
        levels: Annotated[int, typer.Option(help="subdivision levels trained (1 to 3)")] = 2,
        lr: Annotated[float, typer.Option(help="Adam's learning rate (cosine down to a twentieth)")] = 2e-3,
        features: Annotated[int, typer.Option(help="feature size per vertex")] = 16,
        hidden: Annotated[int, typer.Option(help="hidden width of the three MLPs")] = 64,
        real: Annotated[list[Path] | None, typer.Option(help="a closed mesh to train on too (decimated by QEM, its "
                                                           "levels mapped back), repeatable")] = None,
        no_procedural: Annotated[bool, typer.Option("--no-procedural", help="train on --real meshes only")] = False,
        map_: Annotated[str, typer.Option("--map", help="how real pairs are mapped back: closest or "
                                                        "normal")] = "closest",
        checkpoint_every: Annotated[int, typer.Option("--checkpoint-every", help="steps between checkpoints")] = 100,
        resume: Annotated[bool, typer.Option(help="continue from OUTPUT.ckpt.npz")] = False,
        seed: SeedOpt = 0,
        json_out: JsonOpt = False,
    ) -> None:
        """Train neural subdivision (half-flap MLPs, Liu et al. 2020) on dish pairs with exact correspondences
        and, with --real, on decimated closed meshes mapped back."""
        from rich.console import Console
        from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

        from ipm.errors import InputError
        from ipm.subdiv.neural import save_weights
        from ipm.subdiv.train import TrainSettings, evaluate, make_pairs, train

        check_output(output, (".npz",))
        if checkpoint_every < 1:
            raise UsageError(f"--checkpoint-every: expected at least 1, got {checkpoint_every}")
        s = TrainSettings(pairs=pairs, steps=steps, lr=lr, levels=levels, seed=seed, features=features,
                          hidden=hidden, procedural=not no_procedural,
                          real=tuple(str(p) for p in real or ()), map=map_)
        try:
            s.check()
        except InputError as e:
            raise UsageError(f"--{e}") from None
        ckpt = output.with_suffix(".ckpt.npz")
        bar = Progress(TextColumn("train"), BarColumn(), TextColumn("{task.completed}/{task.total}"),
                       TextColumn("loss {task.fields[loss]:.4g}"), TimeElapsedColumn(), transient=True,
                       console=Console(stderr=True))
        task = bar.add_task("train", total=steps, loss=float("nan"))
        shown = []

        def progress(i: int, loss: float) -> None:
            if not shown:  # shown from the first step: bad input (a mesh, a checkpoint) is refused before,
                bar.start()  # on one line, without the bar's own line around it
                shown.append(True)
            bar.update(task, completed=i, loss=loss)

        try:
            net = train(s, checkpoint=ckpt, every=checkpoint_every, resume=resume, progress=progress)
        finally:
            if shown:
                bar.stop()
        save_weights(net, output)
        ckpt.unlink(missing_ok=True)
        scores = evaluate(net, make_pairs(HELD_OUT, levels, seed + 1000))
        emit({"output": str(output), "steps": steps, "pairs": pairs, "levels": levels,
              "held_out_distance": {k: round(v, 5) for k, v in scores.items()}}, json_out)
        sys.stdout.flush()
