"""The user's files, read and written with one kind of failure: an :class:`~ipm.errors.InputError` line
naming the file.

Reading: every way a file can be unreadable (missing, a folder, not UTF-8 text, not JSON) gives one line,
and so does hostile content: text files larger than :data:`MAX_TEXT_BYTES` are refused before they are
read whole, JSON nested deeper than its caller's limit before the parser recurses into it, and JSON
numbers beyond the range of a double (``1e400``, which Python's parser reads as infinity, or an integer of
hundreds of digits) when they are parsed.

Writing is atomic: a temporary file beside the target, then a rename into place, so no reader ever sees a
half-written file. Files get the permissions an ordinary ``open(path, "w")`` would give (0666 less the
umask), not the 0600 of a temporary file. When the OS refuses (read-only or full disk, no permission, a
parent that is a file), the error names the *target* path, never the hidden temporary one.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import re
import tempfile
from collections.abc import Iterator
from pathlib import Path

from ipm.errors import InputError

# the largest text file read (JSON, YAML, TOML): the project's own files are a few megabytes at most; a
# device or a runaway file is refused before it fills the memory
MAX_TEXT_BYTES = 256 * 2**20
# the most digits a JSON integer may have: more lie beyond the range of a double (about 1.8e308)
MAX_INT_DIGITS = 308


def read_text(path: str | Path, what: str = "file") -> str:
    """The UTF-8 text of ``path``; ``what`` names the file's role in messages ("parameter file"). Files
    larger than :data:`MAX_TEXT_BYTES` are refused (only that much is read)."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{what} not found: {path}")
    if path.is_dir():
        raise InputError(f"{what} {path} is a folder; expected a file")
    with open(path, "rb") as f:
        data = f.read(MAX_TEXT_BYTES + 1)
    if len(data) > MAX_TEXT_BYTES:
        raise InputError(f"{what} {path}: expected a text file of at most {MAX_TEXT_BYTES // 2**20} MB (the limit), "
                         "got a larger one")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        raise InputError(f"{what} {path}: expected UTF-8 text, got binary data") from None


def read_json(path: str | Path, what: str = "JSON file", *, max_nesting: int = 200, too_deep: str = ""):
    """The parsed JSON of ``path`` (any JSON value); errors name the file, line and column. Text whose
    objects and arrays nest deeper than ``max_nesting`` is refused before the parser recurses into it
    (``too_deep`` says what the limit means to the caller); so are numbers beyond the range of a double
    (``1e400``, an integer of more than :data:`MAX_INT_DIGITS` digits), naming the key they are given
    for."""
    text = read_text(path, what)
    nesting = json_nesting(text)
    if nesting > max_nesting:
        raise InputError(f"{what} {path}: {too_deep or f'expected JSON nested at most {max_nesting} deep'}, "
                         f"got JSON nested {nesting} deep")

    def too_large(literal: str) -> InputError:
        shown = literal if len(literal) <= 24 else f"{literal[:12]}...({len(literal)} characters)"
        key = _key_of(text, literal)
        return InputError(f"{what} {path}: {f'key {key!r}: ' if key else ''}expected a number of "
                          f"magnitude at most 1.8e308 (a double), got {shown}")

    def parse_float(literal: str) -> float:
        value = float(literal)
        if math.isinf(value):
            raise too_large(literal)
        return value

    def parse_int(literal: str) -> int:
        if len(literal.lstrip("-")) > MAX_INT_DIGITS:
            raise too_large(literal)
        return int(literal)

    try:
        return json.loads(text, parse_float=parse_float, parse_int=parse_int)
    except json.JSONDecodeError as e:
        raise InputError(f"{what} {path} is not valid JSON: {e.msg} at line {e.lineno}, column {e.colno}") from None


def _key_of(text: str, literal: str) -> str | None:
    """The object key that the number ``literal`` is the value of in JSON ``text`` (its first occurrence
    as a value), or None (a number in a list)."""
    m = re.search(r'"((?:\\.|[^"\\])*)"\s*:\s*' + re.escape(literal) + r"(?![0-9.eE+-])", text)
    return m.group(1) if m else None


def read_npy(path: str | Path, what: str = "array file"):
    """The numpy array in a ``.npy`` file (no pickles), numbers only; errors name the file."""
    import numpy as np

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{what} not found: {path}")
    try:
        arr = np.load(path, allow_pickle=False)
    except (ValueError, OSError, EOFError) as e:
        raise InputError(f"{what} {path}: expected a .npy array, got an unreadable file ({type(e).__name__})") from None
    if not isinstance(arr, np.ndarray) or arr.dtype.kind not in "fiub":
        raise InputError(f"{what} {path}: expected an array of numbers, got {getattr(arr, 'dtype', type(arr))}")
    return arr


def json_nesting(text: str) -> int:
    """How deeply objects and arrays nest in JSON ``text`` (strings skipped), without parsing it."""
    depth = deepest = 0
    for m in _BRACKETS.finditer(_STRINGS.sub('""', text)):
        depth += 1 if m.group() in "[{" else -1
        deepest = max(deepest, depth)
    return deepest


_STRINGS = re.compile(r'"(?:\\.|[^"\\])*"')
_BRACKETS = re.compile(r"[\[\]{}]")


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


FILE_MODE = 0o666 & ~_umask()
DIR_MODE = 0o777 & ~_umask()


def refused(path: Path, e: OSError) -> InputError:
    """The one-line error for an OS refusal to write ``path``."""
    import errno

    why = {errno.ENOSPC: "no space left on the device", errno.EROFS: "read-only file system",
           errno.EDQUOT: "disk quota exceeded", errno.ENOTDIR: "a parent is a file, not a folder",
           errno.EEXIST: "a parent is a file, not a folder"}.get(e.errno, e.strerror or str(e))
    return InputError(f"cannot write {path}: {why}")


def make_parent(path: Path) -> None:
    """Create ``path``'s folder; an OS refusal becomes an :class:`InputError` naming ``path``."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise refused(path, e) from None


@contextlib.contextmanager
def atomic_path(path: str | Path, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path in the target's folder; on success rename it to ``path``.

    On any exception the temporary file is removed and ``path`` is left untouched. OS errors on the
    temporary file (creating, writing, renaming it) are reported as :class:`InputError` on ``path``.
    """
    path = Path(path)
    if path.is_dir():
        raise InputError(f"output {path} is a folder; expected a file path")
    make_parent(path)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix or path.suffix + ".tmp",
                                   dir=path.parent)
    except OSError as e:
        raise refused(path, e) from None
    os.close(fd)
    tmp = Path(tmp)
    try:
        try:
            yield tmp
        except OSError as e:
            if e.filename is not None and Path(e.filename) == tmp:
                raise refused(path, e) from None
            raise
        try:
            os.chmod(tmp, FILE_MODE)
            os.replace(tmp, path)
        except OSError as e:
            raise refused(path, e) from None
    finally:
        if tmp.exists():
            tmp.unlink()


def write_text(path: str | Path, text: str) -> Path:
    with atomic_path(path) as tmp:
        tmp.write_text(text)
    return Path(path)


def write_bytes(path: str | Path, data: bytes) -> Path:
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


@contextlib.contextmanager
def staged_directory(out: str | Path) -> Iterator[Path]:
    """Yield an empty temporary folder beside ``out``; on success its files move into ``out`` (created
    if needed; existing files of the same names are replaced, each atomically); on error it is removed
    and ``out`` is left as it was."""
    import shutil

    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(f"output {out}: expected a folder, got a file")
    make_parent(out)
    try:
        tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent))
    except OSError as e:
        raise refused(out, e) from None
    try:
        try:
            yield tmp
        except OSError as e:
            if e.filename is not None and Path(tmp) in Path(e.filename).parents:
                raise refused(out, e) from None
            raise
        try:
            for p in tmp.iterdir():
                os.chmod(p, DIR_MODE if p.is_dir() else FILE_MODE)
            if not out.exists():
                os.chmod(tmp, DIR_MODE)
                os.replace(tmp, out)
            else:
                for p in sorted(tmp.iterdir()):
                    os.replace(p, out / p.name)
        except OSError as e:
            raise refused(out, e) from None
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


@contextlib.contextmanager
def all_or_nothing(*paths: str | Path) -> Iterator[None]:
    """Several outputs written one after another (a mesh, its sidecar, a preview): if anything inside
    fails, those of ``paths`` that did not exist before are removed again."""
    before = {Path(p): Path(p).exists() for p in paths}
    try:
        yield
    except BaseException:
        for p, existed in before.items():
            if not existed and p.is_file():
                p.unlink()
        raise


def check_writable(path: str | Path) -> Path:
    """Refuse up front (:class:`InputError`) an output under a file or in a folder this process may not
    write, so that a command fails before its work, not after."""
    import os

    path = Path(path)
    anc = path.parent
    while not anc.exists() and anc != anc.parent:
        anc = anc.parent
    if anc.exists() and not anc.is_dir():
        raise InputError(f"cannot write {path}: {anc} is a file, not a folder")
    if anc.exists() and not os.access(anc, os.W_OK | os.X_OK):
        raise InputError(f"cannot write {path}: no permission to write in {anc}")
    return path
