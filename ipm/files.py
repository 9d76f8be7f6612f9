"""Reading the user's files: one place that turns every way a file can be unreadable into one
:class:`~ipm.errors.InputError` line naming the file (missing, a folder, not UTF-8 text, not JSON)."""

from __future__ import annotations

import json
from pathlib import Path

from ipm.errors import InputError


def read_text(path: str | Path, what: str = "file") -> str:
    """The UTF-8 text of ``path``; ``what`` names the file's role in messages ("parameter file")."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{what} not found: {path}")
    if path.is_dir():
        raise InputError(f"{what} {path} is a folder; expected a file")
    try:
        return path.read_bytes().decode("utf-8")
    except UnicodeDecodeError:
        raise InputError(f"{what} {path}: expected UTF-8 text, got binary data") from None


def read_json(path: str | Path, what: str = "JSON file"):
    """The parsed JSON of ``path`` (any JSON value); errors name the file, line and column."""
    text = read_text(path, what)
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        raise InputError(f"{what} {path} is not valid JSON: {e.msg} at line {e.lineno}, column {e.colno}") from None
    except RecursionError:
        raise InputError(f"{what} {path}: nested too deeply") from None
