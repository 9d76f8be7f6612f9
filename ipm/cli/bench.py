"""``ipm bench EXPERIMENT.toml [-o DIR] [--split NAME] [--workers N] [--scheduler ADDRESS] [--resume] [--dry-run]``."""

from __future__ import annotations

import datetime as dt
import platform
from pathlib import Path
from typing import Annotated

import typer

from ipm.cli.common import JsonOpt, UsageError, emit


def register(app: typer.Typer) -> None:
    @app.command()
    def bench(
        experiment: Annotated[Path, typer.Argument(help="experiment file (TOML)")],
        output: Annotated[Path | None, typer.Option("-o", "--output", help="results folder "
                                                    "(default results/<experiment name>)")] = None,
        split: Annotated[str | None, typer.Option(help="run only the targets whose split key is this (for "
                                                  "example tune or validation)")] = None,
        workers: Annotated[int, typer.Option(help="local worker processes")] = 1,
        scheduler: Annotated[str | None, typer.Option(help="Dask scheduler address (runs cells there)")] = None,
        resume: Annotated[bool, typer.Option(help=(
            "skip cells already in rows.jsonl (a folder of the same experiment: new cells may be added, "
            "rows of other or changed cells are refused)"))] = False,
        dry_run: Annotated[bool, typer.Option("--dry-run", help="list the cells to run and stop")] = False,
        json_out: JsonOpt = False,
    ) -> None:
        """Run an experiment grid and write rows, tables and a README."""
        import ipm
        from ipm.bench.config import load_experiment
        from ipm.bench.harness import run_experiment
        from ipm.bench.tables import class_markdown, class_summary, csv_text, latex, markdown
        from ipm.files import write_text

        if workers < 1:
            raise UsageError(f"--workers: expected at least 1, got {workers}")
        exp = load_experiment(experiment, split)
        out = output or Path("results") / exp.name
        from rich.console import Console

        err = Console(stderr=True)

        def progress(row, i, n):
            err.print(f"[{i}/{n}] {row['key']}: {row.get('status')} "
                      f"held-out IoU {row.get('heldout_iou', float('nan')):.3f} in {row.get('wall_time_s', 0)} s")

        rows = run_experiment(experiment, out, workers=workers, scheduler=scheduler, resume=resume,
                              dry_run=dry_run, split=split, progress=progress)
        if dry_run:
            emit({"todo": [r["key"] for r in rows]}, json_out)
            return
        from ipm.bench.figures import write_contact_sheets

        sheets = write_contact_sheets(experiment, exp, rows, out, warn=lambda line: err.print(line))
        write_text(out / "table.md", markdown(rows))
        write_text(out / "table.csv", csv_text(rows))
        write_text(out / "table.tex", latex(rows))
        import torch

        classes = {t.name: t.cls for t in exp.targets if t.cls}
        fits = {m.name for m in exp.methods if m.method == "ipm"}
        summary = class_summary(rows, classes, fits, reference_views=max(c.views for c in exp.cells()))
        by_class = class_markdown(rows, classes)
        readme = "\n".join([
            f"# {exp.name}", "",
            f"Command: `ipm bench {experiment}{' -o ' + str(output) if output else ''}"
            f"{' --split ' + split if split else ''}`  ",
            f"Date: {dt.datetime.now(dt.UTC).isoformat(timespec='seconds')}  ",
            f"Machine: {platform.processor() or platform.machine()}, {__import__('os').cpu_count()} cores  ",
            f"Versions: ipm {ipm.__version__}, torch {torch.__version__}, Python {platform.python_version()}", "",
            f"Protocol: DESIGN.md v2 (targets in the unit bounding sphere, inputs {exp.size} px, 16 held-out "
            f"views at {exp.heldout_size} px, camera distance {exp.distance:g}, predictions scored where the "
            f"method placed them, K = 1 scaled about the eye; budget {exp.budget} evaluations"
            + "".join(f", {m.name} {m.budget}" for m in exp.methods if m.budget is not None)
            + f", seeds {list(exp.seeds)}).", "",
            "Contact sheets (target, then each method's result from held-out view 1, as scored): "
            + (", ".join(f"[{p.name}]({p.name})" for p in sheets) or "none") + ".", "",
            *([exp.notes, ""] if exp.notes else []),
            *(["## Per class", "", "Held-out IoU of the generator fits against the best other method "
               "(classes: " + ", ".join(f"{c}: {', '.join(sorted(t for t, k in classes.items() if k == c))}"
                                        for c in sorted(set(classes.values()))) + ").", "", summary]
              if summary else []),
            *([by_class, ""] if by_class else []),
            *(["## Per target", ""] if by_class else []),
            markdown(rows)])
        write_text(out / "README.md", readme + "\n")
        if not json_out:
            _print_table(rows)
        emit({"rows": str(out / "rows.jsonl"), "table": str(out / "table.md"), "cells": len(rows),
              "sheets": [str(p) for p in sheets]}, json_out)


def _print_table(rows: list[dict]) -> None:
    """The held-out IoU table (rows method x views, columns targets) as a rich table on stdout."""
    from rich.console import Console
    from rich.table import Table

    from ipm.bench.tables import table

    header, body, _ = table(rows, "heldout_iou")
    if not body:
        return
    t = Table(title="held-out silhouette IoU (mean ± std over seeds)")
    for h in header:
        t.add_column(h, justify="left" if h in ("method", "views") else "right")
    for b in body:
        t.add_row(*b)
    Console().print(t)
