"""Helpers shared by the commands: errors, devices, parameter options, output."""

from __future__ import annotations

import json
import logging
import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from ipm.errors import InputError

if TYPE_CHECKING:
    import numpy as np
    import torch

log = logging.getLogger("ipm")

# Bad input from the user (the CLI's name for it): one line, exit code 2.
UsageError = InputError

_LEVELS = {"debug": logging.DEBUG, "info": logging.INFO, "warning": logging.WARNING, "error": logging.ERROR}


def error_line(msg: str) -> None:
    sys.stderr.write(f"ipm: error: {msg}\n")
    sys.stderr.flush()


def os_error_line(e: OSError) -> str:
    """One line for an OS refusal that reached the CLI: what happened and to which file (both files of a
    refused rename). Writes through :mod:`ipm.files` come as :class:`InputError` ``cannot write PATH: ...``;
    this is for the rest. An error that names no file says so rather than guess."""
    from ipm.files import why

    what = why(e)
    where = " -> ".join(str(f) for f in (e.filename, getattr(e, "filename2", None)) if f is not None)
    return f"{where}: {what}" if where else f"{what} (the system named no file)"


class _StderrHandler(logging.Handler):
    """``ipm: warning: ...`` lines on stderr (the CLI owns the console; results stay on stdout)."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            level = record.levelname.lower()
            sys.stderr.write(f"ipm: {level}: {record.getMessage()}\n" if record.levelno >= logging.WARNING
                             else f"{record.getMessage()}\n")
        except Exception:  # logging must never raise into the program
            self.handleError(record)


def setup_logging(level: str = "info") -> None:
    """Route the library's log records (logger ``ipm`` and below) to stderr at ``level``."""
    root = logging.getLogger("ipm")
    for h in list(root.handlers):
        if isinstance(h, _StderrHandler):
            root.removeHandler(h)
    root.addHandler(_StderrHandler())
    root.setLevel(_LEVELS[level])
    logging.captureWarnings(True)
    pyw = logging.getLogger("py.warnings")
    if not any(isinstance(h, _StderrHandler) for h in pyw.handlers):
        pyw.addHandler(_StderrHandler())
    pyw.setLevel(logging.ERROR if level == "error" else logging.WARNING)


def resolve_device(name: str) -> torch.device:
    """``auto`` -> cuda if available else cpu; ``cpu``; ``cuda`` (error if unavailable)."""
    import torch

    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cpu":
        return torch.device("cpu")
    if name == "cuda":
        if not torch.cuda.is_available():
            raise UsageError("--device cuda: no CUDA device is available here; use --device cpu or auto")
        return torch.device("cuda")
    raise UsageError(f"--device: expected auto, cpu or cuda, got {name!r}")


def seed_everything(seed: int) -> np.random.Generator:
    """Seed Python, NumPy (returned Generator), torch and nlopt."""
    import random

    import nlopt
    import numpy as np
    import torch

    random.seed(seed)
    np.random.seed(seed % (2**32))
    torch.manual_seed(seed)
    nlopt.srand(seed)
    return np.random.default_rng(seed)


# Typer option types shared by generate / jacobian / render / fit.
PresetOpt = Annotated[str | None, typer.Option("--preset", help="start from a named preset of the generator")]
ParamsOpt = Annotated[Path | None, typer.Option("--params", help="parameter file (JSON: {generator, params})")]
SetOpt = Annotated[list[str] | None, typer.Option("--set", help="NAME=VALUE, repeatable")]
RandomOpt = Annotated[bool, typer.Option("--random", help="sample parameters uniformly within their bounds")]
def _seed(value: int) -> int:
    """``--seed`` at most :data:`ipm.params.MAX_SEED` (the most every seeded generator takes; ``min=0``
    refuses negative seeds first)."""
    from ipm.params import MAX_SEED

    if value > MAX_SEED:
        raise typer.BadParameter(f"expected a seed from 0 to {MAX_SEED}, got {value}")
    return value


SeedOpt = Annotated[int, typer.Option("--seed", min=0, callback=_seed, help="random seed, 0 to 2147483647")]
LibraryOpt = Annotated[list[Path] | None, typer.Option("--library", help="folder of macro node JSON files")]
DeviceOpt = Annotated[str, typer.Option("--device", help="auto, cpu or cuda")]
JsonOpt = Annotated[bool, typer.Option("--json", help="print JSON on stdout")]


def resolve_params(gen, preset: str | None, params_file: Path | None, sets: list[str] | None,
                   random: bool, seed: int, base: dict | None = None) -> dict:
    """Full validated parameter dict: defaults < preset < ``base`` (a run folder's fitted values) < random <
    file < --set."""
    from ipm.params import load_param_file, parse_assignment

    values = gen.values(preset, base)
    if random:
        rng = seed_everything(seed)
        values.update(gen.spec.random(rng))
    if params_file is not None:
        name, raw = load_param_file(params_file)
        same = name in (None, gen.name, getattr(gen, "file_format", None))
        if not same:
            raise UsageError(f"parameter file {params_file} is for generator {name!r}, not {gen.name!r}")
        values.update(raw)
    for s in sets or []:
        k, v = parse_assignment(s)
        values[k] = v
    return gen.spec.validate(values)


def command_line() -> str:
    """The command being run, as typed (``ipm generate ...``), for the headers of the files it writes."""
    import shlex

    from ipm.cli import _STATE

    return shlex.join(["ipm", *_STATE["argv"]])


def open_generator(gen: str, library: list[Path] | None):
    """``(generator, values or None)`` of a GEN argument: a finished run folder of ``ipm fit`` (its shape at
    the fitted values, :func:`ipm.io.runs.run_generator`), else a generator name, preset or file."""
    from ipm.generators import get_generator

    folders = [str(p) for p in library] if library else None
    if Path(gen).is_dir():
        from ipm.io.runs import run_generator

        return run_generator(gen, folders)
    return get_generator(gen, library=folders), None


def check_output(path: Path, allowed: tuple[str, ...]) -> Path:
    if path.suffix.lower() not in allowed:
        raise UsageError(f"output {path}: expected a suffix among {', '.join(allowed)}, got {path.suffix or '(none)'}")
    if path.exists() and path.is_dir():
        raise UsageError(f"output {path} is a folder; expected a file path")
    from ipm.files import check_writable

    return check_writable(path)


def resolve_subdivision(option: str, method: str, levels: int):
    """The subdivision scheme named ``method`` (given as ``option``) once ``levels`` is checked; a
    :class:`UsageError` names the option and what is allowed."""
    from ipm.errors import InputError
    from ipm.subdiv import SCHEMES, check_levels

    if method not in SCHEMES.names():
        raise UsageError(f"{option}: expected one of {', '.join(SCHEMES.names())}, got {method!r}")
    try:
        check_levels(levels)
    except InputError as e:
        raise UsageError(f"--{e}") from None
    return SCHEMES.get(method)


def _finite(obj):
    """``obj`` with every float that is not finite (inf, NaN) replaced by None, in nested dicts and lists."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    return obj


def emit(obj, as_json: bool) -> None:
    """Print a result on stdout: JSON (strict: a number that is not finite is written as null) or plain lines."""
    if as_json:
        sys.stdout.write(json.dumps(_finite(obj), indent=2, default=str, allow_nan=False) + "\n")
    elif isinstance(obj, dict):
        for k, v in obj.items():
            sys.stdout.write(f"{k}: {v}\n")
    else:
        sys.stdout.write(f"{obj}\n")
