"""The ``ipm`` command line: one module per command, each with ``register(app)``.

Results go to stdout (paths, or JSON with ``--json``); progress and logs go to stderr (``-v`` for
debug messages, ``-q`` for errors only). Exit codes:

- 0: done;
- 2: bad input (:class:`ipm.errors.InputError`, a usage error, or a file the OS refuses: missing,
  unreadable, unwritable, disk full): one line ``ipm: error: ...`` on stderr, nothing left behind;
- 1: an internal error (a bug): ``ipm: internal error: ...`` and, with ``--debug``, the traceback;
- 130: interrupted (Ctrl-C).

Importing this module must stay cheap (``ipm --help`` in a fraction of a second): command modules
import torch and the library inside their command functions, never at the top.
"""

from __future__ import annotations

import importlib
import sys
from typing import Annotated

import typer

# Command modules, in the order of `ipm --help`.
COMMANDS = ["list_cmd", "generate", "jacobian", "render", "mask", "fit", "convert", "subdivide", "train_subdivision",
            "train_proposals", "vectorize", "bench", "demo"]

app = typer.Typer(
    name="ipm",
    help="Inverse procedural modeling: differentiable generators, Jacobians, silhouettes, fitting.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
)

# --debug of the current invocation (read by main's error handler)
_STATE: dict = {"debug": False, "argv": []}


@app.callback()
def _options(
    verbose: Annotated[bool, typer.Option("-v", "--verbose", help="log debug messages on stderr")] = False,
    quiet: Annotated[bool, typer.Option("-q", "--quiet", help="log errors only")] = False,
    debug: Annotated[bool, typer.Option("--debug", help="show the traceback of internal errors")] = False,
    threads: Annotated[int | None, typer.Option("--threads", min=1, max=256, help=(
        "torch CPU threads (default: $IPM_THREADS, else 1), used as far as cores are idle. With one thread a "
        "run is bit-identical for the same inputs, seed and settings (also across --resume); more threads "
        "change results within the fits' tolerance, not bit for bit"), show_default=False)] = None,
    plugin: Annotated[list[str] | None, typer.Option("--plugin", metavar="FILE.py", help=(
        "load generators from a Python file of yours (repeatable; also $IPM_PLUGINS): every command can then "
        "use them by name. docs/plugins.md shows how to write one"), show_default=False)] = None,
) -> None:
    """Inverse procedural modeling: differentiable generators, Jacobians, silhouettes, fitting."""
    from ipm import threads as T
    from ipm.cli.common import setup_logging

    _STATE["debug"] = debug
    setup_logging("debug" if verbose else "error" if quiet else "info")
    T.ask(threads)
    if plugin:
        from ipm.generators.plugins import add_files

        add_files(plugin)


for _name in COMMANDS:
    importlib.import_module(f"ipm.cli.{_name}").register(app)


def _click_exceptions(attr: str) -> tuple[type, ...]:
    """The click exception classes named ``attr``: typer >= 0.20 vendors click as ``typer._click``."""
    found = []
    for mod in ("typer._click.exceptions", "click.exceptions"):
        try:
            cls = getattr(importlib.import_module(mod), attr, None)
        except ImportError:
            continue
        if cls is not None and cls not in found:
            found.append(cls)
    return tuple(found)


_GLOBAL_FLAGS = {"-v", "--verbose", "-q", "--quiet", "--debug"}
_GLOBAL_OPTIONS = ("--threads", "--plugin")  # global options that take a value


def _global_first(argv: list[str]) -> list[str]:
    """Move the global options (``-v``, ``-q``, ``--debug``, ``--threads N``, ``--plugin FILE``) in front of the
    command, so they may be written anywhere on the line (``ipm fit ... -v``); ``--`` ends the scan."""
    front, rest, i = [], [], 0
    while i < len(argv):
        a = argv[i]
        if a == "--":
            rest += argv[i:]
            break
        if a in _GLOBAL_FLAGS or a.startswith(tuple(o + "=" for o in _GLOBAL_OPTIONS)):
            front.append(a)
        elif a in _GLOBAL_OPTIONS and i + 1 < len(argv):
            front += argv[i:i + 2]
            i += 1
        else:
            rest.append(a)
        i += 1
    return front + rest


def main(argv: list[str] | None = None) -> None:
    """Console entry point: run the app and map its outcome to an exit code (module docstring)."""
    from ipm.cli.common import error_line, os_error_line
    from ipm.errors import InputError

    argv = _global_first(list(sys.argv[1:] if argv is None else argv))
    _STATE["debug"] = "--debug" in argv
    _STATE["argv"] = argv
    interrupted = False
    try:
        rc = app(args=argv, prog_name="ipm", standalone_mode=False)
    except _click_exceptions("NoArgsIsHelpError"):
        rc = 0
    except _click_exceptions("Exit") as e:
        rc = e.exit_code
    except (*_click_exceptions("Abort"), KeyboardInterrupt):
        error_line("interrupted")
        rc, interrupted = 130, True
    except _click_exceptions("UsageError") as e:
        msg = e.format_message() if hasattr(e, "format_message") else str(e)
        error_line(msg.splitlines()[0] if msg else "invalid usage; see ipm --help")
        rc = 2
    except InputError as e:
        error_line(str(e).splitlines()[0] if str(e) else "bad input")
        rc = 2
    except OSError as e:  # missing, unreadable or unwritable files, a full disk: the environment, not a bug
        error_line(os_error_line(e))
        rc = 2
    except MemoryError:
        error_line("out of memory; reduce the sizes asked for")
        rc = 2
    except Exception as e:  # anything else is a bug: loud, exit 1
        if _STATE["debug"]:
            import traceback

            traceback.print_exc()
        first = str(e).splitlines()[0] if str(e) else ""
        sys.stderr.write(f"ipm: internal error: {type(e).__name__}: {first}"
                         f"{'' if _STATE['debug'] else ' (run with --debug for the traceback)'}\n")
        rc = 1
    rc = rc if isinstance(rc, int) else 0
    if rc == 130 and not interrupted:  # typer turns Ctrl-C into a quiet exit code 130
        error_line("interrupted")
    sys.exit(rc)
