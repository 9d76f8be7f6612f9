"""The ``ipm`` command line: one module per command, each with ``register(app)``.

Results go to stdout (paths, or JSON with ``--json``); progress and logs go to stderr. Input and usage
errors print one line ``ipm: error: ...`` on stderr and exit with code 2.
"""

from __future__ import annotations

import importlib
import sys

import typer

# Command modules, in the order of `ipm --help`.
COMMANDS = ["list_cmd", "generate", "jacobian", "render", "fit", "convert", "bench"]

app = typer.Typer(
    name="ipm",
    help="Inverse procedural modeling: differentiable generators, Jacobians, silhouettes, fitting.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
)

for _name in COMMANDS:
    try:
        importlib.import_module(f"ipm.cli.{_name}").register(app)
    except ModuleNotFoundError as _e:  # a command whose module is not written yet
        if _e.name != f"ipm.cli.{_name}":
            raise


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


def main(argv: list[str] | None = None) -> None:
    """Console entry point: run the app and turn usage and input errors into exit code 2."""
    from ipm.cli.common import UsageError, error_line

    try:
        app(args=argv, prog_name="ipm", standalone_mode=False)
    except _click_exceptions("NoArgsIsHelpError"):
        sys.exit(0)
    except _click_exceptions("Exit") as e:
        sys.exit(e.exit_code)
    except _click_exceptions("Abort"):
        error_line("interrupted")
        sys.exit(130)
    except _click_exceptions("UsageError") as e:
        msg = e.format_message() if hasattr(e, "format_message") else str(e)
        error_line(msg.splitlines()[0] if msg else "invalid usage; see ipm --help")
        sys.exit(2)
    except (UsageError, ValueError, FileNotFoundError, IsADirectoryError, PermissionError) as e:
        error_line(str(e).splitlines()[0] if str(e) else type(e).__name__)
        sys.exit(2)
    except KeyboardInterrupt:
        error_line("interrupted")
        sys.exit(130)
    sys.exit(0)
