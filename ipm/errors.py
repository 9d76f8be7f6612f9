"""The one error class for bad input.

``InputError`` is raised wherever a value that came from the user (a file, an option, a parameter dict,
an experiment file) is wrong; its message names the problem and what is allowed ("expected ..., got
...") in one line. The CLI and the bench map it, and only it (with missing files), to exit code 2. Any
other exception is a bug: the CLI exits 1 with a short message and shows the traceback under ``--debug``.

It subclasses ``ValueError`` so that library callers who catch ``ValueError`` keep working.
"""

from __future__ import annotations


class InputError(ValueError):
    """Bad input: the message says what was wrong and what is allowed."""


def check(condition: bool, message: str) -> None:
    """Raise :class:`InputError` with ``message`` unless ``condition`` holds."""
    if not condition:
        raise InputError(message)


class MethodFailed(RuntimeError):
    """A method ran as designed and could not produce a result for this input (a bench method whose
    visual hull is empty, a conversion that found no surface). The bench records the cell as failed
    with this message; any other exception is a bug and stops the run."""
