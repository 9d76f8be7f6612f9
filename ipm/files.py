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
parent that is a file), the error names the *target* path, never the hidden temporary one. A failed write
leaves nothing: its temporary file is removed, and so are the folders made for it.

A command with several outputs writes them all or none: :func:`all_or_nothing` (files: an existing output
is replaced only when every output is written) and :func:`staged_directory` (a folder of outputs, which
may replace an earlier run's files as a whole). :func:`check_distinct` refuses, before any work, two
outputs that are the same file.
"""

from __future__ import annotations

import contextlib
import contextvars
import errno
import json
import math
import os
import re
import tempfile
from collections.abc import Callable, Iterator
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
    import tokenize

    try:
        arr = np.load(path, allow_pickle=False)
    except (ValueError, OSError, EOFError, SyntaxError, tokenize.TokenError, RecursionError) as e:  # a bad header
        raise InputError(f"{what} {path}: expected a .npy array, got an unreadable file ({type(e).__name__})") from None
    if not isinstance(arr, np.ndarray) or arr.dtype.kind not in "fiub":
        raise InputError(f"{what} {path}: expected an array of numbers, got {getattr(arr, 'dtype', type(arr))}")
    return arr


def read_npz(path: str | Path, what: str, expected: str, max_bytes: int) -> dict:
    """The arrays of an ``.npz`` of plain arrays (no pickles) as ``{name: np.ndarray}``, read whole.

    :class:`InputError` naming the file and saying what was ``expected`` for a file that is missing, not a zip,
    a single ``.npy`` array, holds pickled objects, or whose arrays declare more than ``max_bytes`` in their
    headers (a small compressed file can declare gigabytes: checked before anything is read)."""
    import numpy as np

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{what}: expected an existing .npz file, got {path}")
    with open(path, "rb") as f:
        magic = f.read(6)
    if not (magic.startswith(b"PK") or magic == b"\x93NUMPY"):
        raise InputError(f"{what} {path}: expected {expected}, got a file that is no .npz (not a zip)")
    total = _npz_declared_bytes(path)
    if total > max_bytes:
        raise InputError(f"{what} {path}: expected arrays of at most {max_bytes / 2**30:.3g} GB in all (the limit), "
                         f"got arrays declaring {total / 2**30:.1f} GB")
    import zipfile
    import zlib

    try:
        z = np.load(path, allow_pickle=False, mmap_mode="r")  # a .npy is mapped, not read
        if not isinstance(z, np.lib.npyio.NpzFile):
            raise InputError(f"{what} {path}: expected {expected}, got a single array ({z.dtype} {tuple(z.shape)}: "
                             "a .npy file)")
        with z:
            return {k: z[k] for k in z.files}
    except (ValueError, OSError, EOFError, zipfile.BadZipFile, zlib.error) as e:  # pickles, not a zip, truncated
        if isinstance(e, InputError):
            raise
        raise InputError(f"{what} {path}: expected an .npz of plain arrays, got an error: "
                         f"{str(e).splitlines()[0] if str(e) else type(e).__name__}") from None


def _npz_declared_bytes(path: Path) -> int:
    """The bytes the arrays of the ``.npz`` at ``path`` declare in their headers (0 for a file that is not a zip of
    arrays: :func:`numpy.load`'s error then names the problem)."""
    import zipfile

    import numpy as np

    total = 0
    try:
        with zipfile.ZipFile(path) as zf:
            for info in zf.infolist():
                if not info.filename.endswith(".npy"):
                    continue
                with zf.open(info) as f:
                    version = np.lib.format.read_magic(f)
                    read_header = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                                   else np.lib.format.read_array_header_2_0)
                    shape, _, dtype = read_header(f)
                total += int(np.prod(shape, dtype=object)) * dtype.itemsize
    except (zipfile.BadZipFile, ValueError, OSError, EOFError, TypeError):
        return 0
    return total


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


_WHY = {errno.ENOSPC: "no space left on the device", errno.EROFS: "read-only file system",
        errno.EDQUOT: "disk quota exceeded", errno.EFBIG: "file too large for the file system",
        errno.ENOTDIR: "a parent is a file, not a folder", errno.EEXIST: "a parent is a file, not a folder",
        errno.EACCES: "no permission", errno.EPERM: "not permitted", errno.ENAMETOOLONG: "file name too long",
        errno.EISDIR: "a folder is in the way"}


def why(e: OSError) -> str:
    """The OS refusal ``e`` in a few words ("no space left on the device")."""
    if e.errno in _WHY:
        return _WHY[e.errno]
    return e.strerror or (str(e).splitlines()[0] if str(e) else type(e).__name__)


class Refused(InputError):
    """An OS refusal to write ``path``: ``cannot write PATH: WHY``; ``error`` is the OS's error."""

    def __init__(self, path: str | Path, error: OSError):
        self.path, self.error = Path(path), error
        super().__init__(f"cannot write {path}: {why(error)}")


def refused(path: str | Path, e: OSError) -> Refused:
    """The one-line error for an OS refusal to write ``path``: ``cannot write PATH: WHY``. It names the
    output the user asked for, never the temporary file or staging folder the refusal came from."""
    return Refused(path, e)


def make_parent(path: Path) -> list[Path]:
    """Create ``path``'s folder; returns the folders made (outermost first) so that a failed write can
    take them back (:func:`remove_made`). An OS refusal becomes an :class:`InputError` naming ``path``."""
    missing = []
    d = Path(path).parent
    while not os.path.lexists(d) and d != d.parent:
        missing.append(d)
        d = d.parent
    try:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        remove_made(missing)
        raise refused(path, e) from None
    return missing[::-1]


def remove_made(folders) -> None:
    """Remove the folders a failed command made (innermost first), each only if it is empty."""
    for d in sorted(map(Path, folders), key=lambda p: len(p.parts), reverse=True):
        with contextlib.suppress(OSError):
            d.rmdir()


def _unlink(path: Path) -> None:
    with contextlib.suppress(OSError):
        os.unlink(path)


def same_file(a: str | Path, b: str | Path) -> bool:
    """Whether paths ``a`` and ``b`` name one file: the same path once symlinks and ``..`` are resolved,
    or, when both exist, hard links of one file."""
    with contextlib.suppress(OSError):
        if os.path.exists(a) and os.path.exists(b):
            return os.path.samefile(a, b)
    return os.path.realpath(a) == os.path.realpath(b)


def check_distinct(outputs: dict[str, str | Path | None]) -> None:
    """Refuse (:class:`InputError`, before any work) two outputs of one command that are the same file:
    the second write would silently replace the first (``ipm mask --overlay m.png -o m.png``).
    ``outputs`` maps each output's name in messages (``-o/--output``, ``--overlay``, "the parameter file
    beside -o") to its path; ``None`` is an output not asked for."""
    given = [(k, Path(v)) for k, v in outputs.items() if v is not None]
    for i, (ka, a) in enumerate(given):
        for kb, b in given[i + 1:]:
            if same_file(a, b):
                raise InputError(f"{ka} and {kb}: expected different files, got {b} for both")


class _Outputs:
    """The outputs of one :func:`all_or_nothing` block: their finished temporary files wait here for the
    block to succeed, with the folders made for them."""

    def __init__(self, paths: list[Path]):
        self.paths = list(paths)
        self.pending: list[tuple[Path, Path]] = []   # (temporary file, output)
        self.made: list[Path] = []

    def covers(self, path: Path) -> bool:
        """True if ``path`` is one of the block's outputs (the same file, however spelled)."""
        return any(same_file(path, p) for p in self.paths)

    def commit(self) -> None:
        """Rename every temporary file into place. An existing output is kept as a hard link until all are
        in place, so that a rename refused half way puts every earlier output back as it was."""
        done: list[tuple[Path, Path | None]] = []
        try:
            for tmp, path in self.pending:
                backup = None
                if os.path.lexists(path):
                    backup = tmp.with_name(tmp.name + ".old")
                    try:
                        os.link(path, backup, follow_symlinks=False)
                    except OSError:  # a file system without hard links: this one cannot be undone
                        backup = None
                try:
                    os.chmod(tmp, FILE_MODE)
                    os.replace(tmp, path)
                except OSError as e:
                    if backup is not None:
                        _unlink(backup)
                    raise refused(path, e) from None
                done.append((path, backup))
        except BaseException:
            for path, backup in reversed(done):
                with contextlib.suppress(OSError):
                    if backup is not None:
                        os.replace(backup, path)
                    else:
                        os.unlink(path)
            raise
        finally:
            for _, backup in done:
                if backup is not None:
                    _unlink(backup)
        self.pending.clear()

    def discard(self) -> None:
        """Remove the temporary files not yet renamed and the folders made for them; outputs stay as they were."""
        for tmp, _ in self.pending:
            _unlink(tmp)
        self.pending.clear()
        remove_made(self.made)


_OUTPUTS: contextvars.ContextVar[_Outputs | None] = contextvars.ContextVar("ipm_outputs", default=None)


@contextlib.contextmanager
def atomic_path(path: str | Path, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path in the target's folder; on success rename it to ``path``.

    On any exception the temporary file is removed, the folders made for ``path`` are removed again and
    ``path`` is left untouched. OS errors on the temporary file (creating, writing, renaming it; an error
    that names no file, as a full disk's when a writer flushes, is taken to be the write's) are reported
    as :class:`InputError` on ``path``. Inside an :func:`all_or_nothing` block that lists ``path`` the
    rename waits for the block's end.
    """
    path = Path(path)
    if path.is_dir():
        raise InputError(f"output {path} is a folder; expected a file path")
    outputs = _OUTPUTS.get()
    deferred = outputs is not None and outputs.covers(path)
    made = make_parent(path)
    tmp = None
    ok = False
    try:
        try:
            fd, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix or path.suffix + ".tmp",
                                        dir=path.parent)
        except OSError as e:
            raise refused(path, e) from None
        os.close(fd)
        tmp = Path(name)
        try:
            yield tmp
        except OSError as e:
            if e.filename is None or Path(e.filename) == tmp:
                raise refused(path, e) from None
            raise
        if deferred:
            outputs.pending.append((tmp, path))
            outputs.made += made
        else:
            try:
                os.chmod(tmp, FILE_MODE)
                os.replace(tmp, path)
            except OSError as e:
                raise refused(path, e) from None
        ok = True
    finally:
        if not ok:
            if tmp is not None:
                _unlink(tmp)
            remove_made(made)


def write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` to ``path`` atomically (:func:`atomic_path`); returns ``path``."""
    with atomic_path(path) as tmp:
        tmp.write_text(text)
    return Path(path)


def write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (:func:`atomic_path`); returns ``path``."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


@contextlib.contextmanager
def staged_directory(out: str | Path, *, replace: Callable[[str], bool] | None = None) -> Iterator[Path]:
    """Yield an empty temporary folder beside ``out``; on success its entries move into ``out`` (created
    if needed), on error it is removed and ``out`` is left as it was, with the folders made above it
    removed again.

    Into an existing ``out``: entries of the new names are replaced, and with ``replace`` (a test on
    names) every existing entry it accepts is replaced as well, even when the new content has no entry of
    that name (an earlier render's ``view_007.png`` when the new one has 4 views); other entries are
    kept. The old entries wait in a hidden folder inside ``out`` until the new ones are all in place, so
    that a rename refused half way puts ``out`` back as it was."""
    import shutil

    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(f"output {out}: expected a folder, got a file")
    made = make_parent(out)
    ok = False
    tmp = None
    try:
        try:
            tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent))
        except OSError as e:
            raise refused(out, e) from None
        try:
            yield tmp
        except OSError as e:
            if e.filename is None or Path(e.filename) == tmp:
                raise refused(out, e) from None
            if tmp in Path(e.filename).parents:
                raise refused(out / Path(e.filename).relative_to(tmp), e) from None
            raise
        except Refused as e:  # a file of the staging folder: named as the output it was to become
            if tmp in e.path.parents:
                raise refused(out / e.path.relative_to(tmp), e.error) from None
            raise
        try:
            _move_in(tmp, out, replace)
        except OSError as e:
            raise refused(out, e) from None
        ok = True
    finally:
        if tmp is not None and tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
        if not ok:
            remove_made(made)


def _move_in(tmp: Path, out: Path, replace: Callable[[str], bool] | None) -> None:
    """:func:`staged_directory`'s commit: the entries of ``tmp`` into ``out`` (module docstring)."""
    import shutil

    for p in tmp.iterdir():
        os.chmod(p, DIR_MODE if p.is_dir() else FILE_MODE)
    if not out.exists():
        os.chmod(tmp, DIR_MODE)
        os.replace(tmp, out)
        return
    new = sorted(p.name for p in tmp.iterdir())
    old = [n for n in sorted(os.listdir(out)) if n in new or (replace is not None and replace(n))]
    backup = Path(tempfile.mkdtemp(prefix=".replaced.", suffix=".tmp", dir=out)) if old else None
    moved: list[str] = []
    placed: list[str] = []
    try:
        for n in old:
            os.replace(out / n, backup / n)
            moved.append(n)
        for n in new:
            os.replace(tmp / n, out / n)
            placed.append(n)
    except BaseException:
        restored = True
        for n in placed:
            try:
                os.replace(out / n, tmp / n)
            except OSError:
                restored = False
        for n in moved:
            try:
                os.replace(backup / n, out / n)
            except OSError:
                restored = False
        if backup is not None and restored:
            shutil.rmtree(backup, ignore_errors=True)
        raise
    if backup is not None:
        shutil.rmtree(backup, ignore_errors=True)


@contextlib.contextmanager
def all_or_nothing(*paths: str | Path | None) -> Iterator[None]:
    """Several outputs of one command (a mesh, its sidecar, a preview), written all or none.

    Every write to one of ``paths`` through :func:`atomic_path` inside the block (``write_text``,
    ``export_mesh``, ``save_png``, ...) goes to its temporary file, and the renames into place wait for the
    block to succeed: if anything inside fails, no output is replaced or created, the temporary files are
    removed and so are the folders made for them. Paths that are the same file are refused
    (:func:`check_distinct`; commands call it before their work). ``None`` entries are skipped. A block
    inside another joins the outer one."""
    targets = [Path(p) for p in paths if p is not None]
    for i, a in enumerate(targets):
        for b in targets[i + 1:]:
            if same_file(a, b):
                raise InputError(f"outputs: expected different files, got {b} twice")
    outer = _OUTPUTS.get()
    if outer is not None:
        outer.paths += targets
        yield
        return
    outputs = _Outputs(targets)
    before = {p: os.path.lexists(p) for p in targets}
    token = _OUTPUTS.set(outputs)
    try:
        try:
            yield
        finally:
            _OUTPUTS.reset(token)
        outputs.commit()
    except BaseException:
        outputs.discard()
        for p, existed in before.items():  # written by other means than atomic_path: taken back
            if not existed and p.is_file():
                p.unlink()
        raise


def check_writable(path: str | Path) -> Path:
    """Refuse up front (:class:`InputError`) an output under a file or in a folder this process may not
    write, so that a command fails before its work, not after. (A full disk shows only when writing; the
    writers above take back what they wrote.)"""
    path = Path(path)
    anc = path.parent
    while not anc.exists() and anc != anc.parent:
        anc = anc.parent
    if anc.exists() and not anc.is_dir():
        raise InputError(f"cannot write {path}: {anc} is a file, not a folder")
    if anc.exists() and not os.access(anc, os.W_OK | os.X_OK):
        raise InputError(f"cannot write {path}: no permission to write in {anc}")
    return path
