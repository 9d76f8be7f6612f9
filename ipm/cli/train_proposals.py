"""``ipm train-proposals GEN -o WEIGHTS.npz``: train the network whose proposals start a fit (issue #29).

A checkpoint (``WEIGHTS.ckpt.npz``: weights, Adam's state, the step, the settings) is rewritten every
``--checkpoint-every`` steps; ``--resume`` continues from it with the same settings and ends bit-identical to an
uninterrupted run. At the end the weights alone (and the settings) are written to ``-o`` (atomically), the
checkpoint is removed, and the heads are scored on held-out samples that no training seed draws."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated

import typer

from ipm.cli.common import JsonOpt, SeedOpt, UsageError, check_output, emit

HELD_OUT = 200

GenArg = Annotated[str, typer.Argument(help="generator name (ipm list generators) or tree file")]
OutputOpt = Annotated[Path, typer.Option("-o", "--output", help="weights file (.npz)")]
SamplesOpt = Annotated[int, typer.Option(help="training renders, drawn once from the seed")]
StepsOpt = Annotated[int, typer.Option(help="Adam steps")]
BatchOpt = Annotated[int, typer.Option(help="masks per step")]
LrOpt = Annotated[float, typer.Option(help="Adam's learning rate (cosine down to a twentieth)")]
EveryOpt = Annotated[int, typer.Option("--checkpoint-every", help="steps between checkpoints")]
ResumeOpt = Annotated[bool, typer.Option(help="continue from OUTPUT.ckpt.npz")]
WorkersOpt = Annotated[int, typer.Option(help="processes drawing the training renders (the data are the same for any "
                                         "count); training itself runs on one thread")]


def register(app: typer.Typer) -> None:
    @app.command("train-proposals")
    def train_proposals(
        gen: GenArg,
        output: OutputOpt,
        samples: SamplesOpt = 6000,
        steps: StepsOpt = 4000,
        batch: BatchOpt = 64,
        lr: LrOpt = 2e-3,
        checkpoint_every: EveryOpt = 200,
        resume: ResumeOpt = False,
        workers: WorkersOpt = 1,
        seed: SeedOpt = 0,
        json_out: JsonOpt = False,
    ) -> None:
        """Train a proposal network on the generator's own samples (masks from one view -> parameters, discrete
        values, yaw); a fit with --init learned or both starts from its proposals."""
        from ipm.errors import InputError
        from ipm.generators import get_generator
        from ipm.proposals.data import make_samples
        from ipm.proposals.train import HELDOUT_SEED, TrainSettings, evaluate, strip_checkpoint, train

        check_output(output, (".npz",))
        if checkpoint_every < 1:
            raise UsageError(f"--checkpoint-every: expected at least 1, got {checkpoint_every}")
        if not 1 <= workers <= 256:
            raise UsageError(f"--workers: expected 1 to 256 processes, got {workers}")
        s = TrainSettings(samples=samples, steps=steps, batch=batch, lr=lr, seed=seed)
        try:
            s.check()
        except InputError as e:
            raise UsageError(f"--{e}") from None
        g = get_generator(gen)
        if not g.spec.continuous:
            raise UsageError(f"{gen}: expected a generator with continuous parameters, got none")
        ckpt = output.with_suffix(".ckpt.npz")
        with _bar() as progress:
            net = train(g, s, checkpoint=ckpt, every=checkpoint_every, resume=resume, progress=progress,
                        workers=workers)
        strip_checkpoint(ckpt, output)
        ckpt.unlink(missing_ok=True)
        scores = evaluate(net, make_samples(g, HELD_OUT, HELDOUT_SEED))
        emit({"output": str(output), "generator": g.name, "steps": steps, "samples": samples, **scores}, json_out)
        sys.stdout.flush()


class _bar:
    """A progress bar on stderr, shown from the first report (bad input is refused before, on one line)."""

    def __enter__(self):
        from rich.console import Console
        from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

        self.bar = Progress(TextColumn("{task.fields[stage]:<5}"), BarColumn(), TextColumn("{task.completed}/"
                            "{task.total}"), TextColumn("loss {task.fields[loss]:.4g}"), TimeElapsedColumn(),
                            transient=True, console=Console(stderr=True))
        self.task = self.bar.add_task("train", total=1, stage="", loss=float("nan"))
        self.shown = False
        return self.update

    def update(self, stage: str, done: int, total: int, loss: float) -> None:
        if not self.shown:
            self.bar.start()
            self.shown = True
        self.bar.update(self.task, completed=done, total=total, stage=stage, loss=loss)

    def __exit__(self, *exc):
        if self.shown:
            self.bar.stop()
        return False
