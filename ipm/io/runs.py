"""Run folders: settings, the trajectory (one JSON line per evaluation, flushed as it is written, which
is also the checkpoint), and the final files.

What a resume reads is checked before anything runs: ``settings.json`` (:class:`RunFile`) and every
line of ``trajectory.jsonl`` (:class:`Record`) against a schema (msgspec), so that a damaged file (not
UTF-8, not JSON, a line that is not an object, a field of the wrong type or missing) is an
:class:`~ipm.errors.InputError` naming the file, the line and the field ("expected ..., got ..."), never
a crash. A torn last line (a kill while it was written: no newline after it) is dropped.

Writes: :func:`write_json` is atomic; :class:`Trajectory` appends. An OS refusal (a full disk, no
permission) is an :class:`~ipm.errors.InputError` naming the file. :func:`first_run` removes what a
first run wrote when it fails on bad input, so that it leaves no run folder behind.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import re
import shutil
from collections.abc import Iterator
from pathlib import Path
from typing import Annotated, Any, Literal

import msgspec
from msgspec import Meta

from ipm.errors import InputError
from ipm.files import read_text, refused, write_text

SETTINGS = "settings.json"
TRAJECTORY = "trajectory.jsonl"
RESULT = "result.json"


class RunFile(msgspec.Struct):
    """``settings.json`` of a fit's run folder.

    generator: the generator's name; source: what builds it again, as given to the fit (a registry or
    preset name, or the absolute path of a generator file) and library: the absolute paths of the macro
    folders it used (both absent in runs recorded before they were kept: the generator's name is used);
    settings: :class:`~ipm.optim.settings.FitSettings` as JSON; target: :class:`~ipm.io.fit_targets.TargetFiles`
    as JSON, absolute paths (older runs: ``masks``, ``target_mesh`` and ``up`` at the top level)."""

    generator: str
    settings: dict[str, Any]
    target: dict[str, Any] | None = None
    source: str | None = None
    library: list[str] | None = None
    masks: str | None = None
    target_mesh: str | None = None
    up: str | None = None


class StructureTarget(msgspec.Struct):
    """The target of a structure search: a mesh (with its up axis) or a mask set; absolute paths."""

    target_mesh: str | None = None
    up: Literal["y", "z"] = "y"
    masks: str | None = None


class StructureRunFile(msgspec.Struct):
    """``settings.json`` of a structure search's run folder: its settings
    (:class:`~ipm.optim.structure.StructureSettings` as JSON), target and start tree (absolute paths)."""

    structure: dict[str, Any]
    target: StructureTarget = msgspec.field(default_factory=StructureTarget)
    start: str | None = None


class Record(msgspec.Struct):
    """One evaluation of ``trajectory.jsonl`` (the objective's extras, per-view IoU and so on, follow as
    further fields). ``i`` counts from 0, line by line; ``x`` is the search vector in [0, 1]; ``grad`` is
    None for an evaluation without a gradient; ``t``: seconds since the run's start, over all its runs."""

    i: Annotated[int, Meta(ge=0)]
    loss: float
    x: list[float]
    discrete: dict[str, int]
    grad: list[float] | None = None
    phase: str = ""
    t: Annotated[float, Meta(ge=0)] = 0.0


def checked(data, schema: type, where: str):
    """``data`` converted to ``schema`` (a msgspec Struct or dataclass) or :class:`InputError`
    "``where``: field.path: expected ..., got ..."."""
    try:
        return msgspec.convert(data, schema)
    except msgspec.ValidationError as e:
        raise InputError(f"{where}: {schema_message(data, schema, str(e))}") from None


_AT = re.compile(r" - at `\$([^`]*)`$")
_STEP = re.compile(r"\.([^.\[\]]+)|\[([^\]]*)\]")
_MISSING = re.compile(r"missing required field `([^`]*)`")


def schema_message(data, schema: type, error: str) -> str:
    """msgspec's ValidationError ``error`` for ``data`` against ``schema`` as one line: the field's path
    ("beam[0].score"), what the schema allows there and what the data has."""
    import msgspec.inspect as mi

    from ipm.settings_check import allowed

    m = _AT.search(error)
    steps: list[str | int | None] = []
    for name, index in _STEP.findall(m.group(1) if m else ""):
        steps.append(name if name else int(index) if index.isdigit() else None)
    missing = _MISSING.search(error)
    if missing:
        steps.append(missing.group(1))
    t, value, path, known = mi.type_info(schema), data, "", True
    for s in steps:
        if isinstance(t, mi.Metadata):
            t = t.type
        if isinstance(t, mi.UnionType):
            t = next((k for k in t.types if not isinstance(k, mi.NoneType)), t)
        if isinstance(s, str):
            fields = {f.name: f.type for f in getattr(t, "fields", ())}
            t = fields.get(s, getattr(t, "value_type", None))
            known = known and isinstance(value, dict)
            value = value.get(s) if known else None
            path += f".{s}" if path else s
        else:
            t = getattr(t, "item_type", None) or getattr(t, "value_type", None)
            known = known and isinstance(s, int) and isinstance(value, list) and s < len(value)
            value = value[s] if known else None
            path += f"[{s if s is not None else '...'}]"
    if isinstance(t, mi.UnionType):  # None, the default "unset", is not spelt out
        t = next((k for k in t.types if not isinstance(k, mi.NoneType)), t)
    inner = t.type if isinstance(t, mi.Metadata) else t
    if isinstance(inner, (mi.StructType, mi.DataclassType, mi.DictType)):
        what = "an object"
    elif isinstance(inner, (mi.ListType, mi.TupleType, mi.VarTupleType)):
        some = getattr(inner, "min_length", None) or getattr(t, "min_length", None)
        what = "a list" + (" of at least one item" if some else "")
    elif t is not None:
        what = allowed(t)
    else:
        what = error.split(" - at ")[0]
    if missing:
        got = "nothing"
    elif known:
        got = _describe(value)
    else:  # a value under a key msgspec does not name: its type
        kind = re.search(r"got `([^`]*)`", error)
        got = {"str": "a string", "int": "an integer", "float": "a number", "bool": "true or false",
               "null": "null", "array": "a list", "object": "an object"}.get(kind.group(1), kind.group(1)) \
            if kind else "another value"
    return f"{path or 'the file'}: expected {what}, got {got}"


def _describe(v) -> str:
    if isinstance(v, dict):
        return "an object"
    if isinstance(v, list):
        return "an empty list" if not v else "a list"
    text = repr(v)
    return text if len(text) <= 60 else text[:57] + "..."


MAX_NESTING = 200  # resume files nest a few levels (a structure search's trees a few dozen)


def read_json_file(path: Path, what: str):
    """The JSON value of a resume file; :class:`InputError` "``what`` PATH: expected JSON, got ..." for a
    missing, binary, invalid or absurdly nested one."""
    text = read_text(path, what)
    _check_nesting(text, f"{what} {path}")
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        raise InputError(f"{what} {path}: expected JSON, got {e.msg} at line {e.lineno}, column {e.colno}") from None


def _check_nesting(text: str, where: str) -> None:
    from ipm.files import json_nesting

    depth = json_nesting(text)
    if depth > MAX_NESTING:
        raise InputError(f"{where}: expected JSON nested at most {MAX_NESTING} deep, got {depth}")


def read_json_lines(path: Path, what: str, schema: type | None = None) -> list[dict]:
    """The objects of a JSON-lines file (a missing file has none), each checked against ``schema``;
    a torn last line (no newline after it, not JSON) is dropped. :class:`InputError` names the file
    and the line: text that is not UTF-8, a line that is not a JSON object, a field the schema refuses."""
    path = Path(path)
    if not path.exists():
        return []
    text = read_text(path, what)
    lines = text.split("\n")
    torn = lines.pop()  # after the last newline: "" for a complete file, else a line cut short
    out = []
    for n, line in enumerate([*lines, torn] if torn.strip() else lines, 1):
        if not line.strip():
            continue
        _check_nesting(line, f"{what} {path}: line {n}")
        try:
            data = json.loads(line)
        except json.JSONDecodeError as e:
            if n == len(lines) + 1:
                break  # the torn last line of an interrupted run
            raise InputError(f"{what} {path}: line {n}: expected a JSON object, got invalid JSON ({e.msg})") from None
        if not isinstance(data, dict):
            raise InputError(f"{what} {path}: line {n}: expected a JSON object, got {_describe(data)}")
        if schema is not None:
            checked(data, schema, f"{what} {path}: line {n}")
        out.append(data)
    return out


def read_trajectory(path: Path) -> list[dict]:
    """The records of a trajectory file (:class:`Record`, checked; a torn last line is dropped):
    :class:`InputError` naming the file, the line and the field for anything else, and for records out
    of order or with non-finite numbers."""
    path = Path(path)
    records = read_json_lines(path, "trajectory", Record)
    for n, r in enumerate(records):
        where = f"trajectory {path}: line {n + 1}"
        if r["i"] != n:
            raise InputError(f"{where}: i: expected {n} (the records in order), got {r['i']!r}")
        if not math.isfinite(r["loss"]):
            raise InputError(f"{where}: loss: expected a finite number, got {r['loss']!r}")
        if not all(math.isfinite(v) and 0.0 <= v <= 1.0 for v in r["x"]):
            raise InputError(f"{where}: x: expected numbers in [0, 1], got {_describe(r['x'])}")
        if r.get("grad") is not None and not all(math.isfinite(v) for v in r["grad"]):
            raise InputError(f"{where}: grad: expected finite numbers, got a non-finite one")
        if r.get("grad") is not None and len(r["grad"]) != len(r["x"]):
            raise InputError(f"{where}: grad: expected {len(r['x'])} numbers (one per x), got {len(r['grad'])}")
    return records


def read_run_file(run_dir: Path, schema: type = RunFile, *, what: str = "--resume"):
    """A run folder's ``settings.json``, checked against ``schema``; :class:`InputError` names the file
    ("--resume: FILE: ...", ``what`` first) for a missing, unreadable or damaged one."""
    path = Path(run_dir) / SETTINGS
    if not path.is_file():
        raise InputError(f"{what}: expected a run folder with {SETTINGS}, got {run_dir}")
    try:
        data = read_json_file(path, "run settings")
    except InputError as e:
        raise InputError(f"{what}: {e}") from None
    return checked(data, schema, f"{what}: run settings {path}")


def run_generator(run_dir: str | Path, library: list[str] | None = None):
    """``(generator, values)``: the shape a finished run folder holds, to generate it again (``ipm generate
    RUN``). A structure search's is its ``tree.json`` (placed in the target's frame) at its values, a 2D shape
    fit's its ``lifted.json`` (revolved or extruded); a fit's is its generator (``settings.json``: source and
    macro folders, or ``library``) at the fitted parameters of ``result.json``, in the generator's own frame
    (the fitted pose is not applied). :class:`InputError` (one line, naming the folder) for a folder that is
    not a finished run."""
    from ipm.generators import get_generator

    run_dir = Path(run_dir)
    where = f"run folder {run_dir}"
    if not (run_dir / RESULT).is_file():
        raise InputError(f"{where}: expected a finished run of ipm fit (with {RESULT}), got a folder without it")
    for name in ("lifted.json", "tree.json"):  # a 2D shape fit's lifted tree; a structure search's tree
        if (run_dir / name).is_file():  # (a 2D shape fit without a lift is refused: its tree is not 3D)
            gen = get_generator(str(run_dir / name), library=library)
            return gen, gen.spec.defaults()
    saved = read_run_file(run_dir, what=where)
    result = read_json_file(run_dir / RESULT, "run result")
    params = result.get("params") if isinstance(result, dict) else None
    if not isinstance(params, dict):
        raise InputError(f"{where}: {RESULT}: expected the fitted parameters under \"params\", got none")
    gen = get_generator(saved.source or saved.generator, library=library or saved.library)
    try:
        return gen, gen.spec.validate({**gen.spec.defaults(), **params})
    except InputError as e:
        raise InputError(f"{where}: {RESULT}: {e}") from None


class Trajectory:
    """Append-only JSON lines; every record is flushed to disk so a kill loses at most one line. An OS
    refusal (a full disk) is an :class:`InputError` naming the file."""

    def __init__(self, path: Path, *, keep: int = 0):
        self.path = Path(path)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            if keep == 0 or not self.path.exists():
                write_text(self.path, "")
            else:  # rewrite only the first `keep` complete records (drop a torn last line)
                lines = [line for line in read_text(self.path, "run file").split("\n")[:-1] if line.strip()]
                if len(lines) < keep:
                    raise InputError(f"{self.path}: expected {keep} complete records, got {len(lines)}")
                write_text(self.path, "".join(line + "\n" for line in lines[:keep]))
            self._f = open(self.path, "a", buffering=1)
        except OSError as e:
            raise refused(self.path, e) from None

    def __call__(self, record: dict) -> None:
        try:
            self._f.write(json.dumps(record, separators=(",", ":")) + "\n")
            self._f.flush()
            os.fsync(self._f.fileno())
        except OSError as e:
            raise refused(self.path, e) from None

    def close(self) -> None:
        """Close the log file; an OS error here is ignored (a failed write was reported already)."""
        with contextlib.suppress(OSError):  # a full disk: the refusal was reported by the write
            self._f.close()


def write_json(path: Path, data: dict) -> Path:
    """``data`` as indented JSON, atomically; an OS refusal is an :class:`InputError` naming ``path``."""
    try:
        return write_text(path, json.dumps(data, indent=2, default=_default) + "\n")
    except OSError as e:
        raise refused(Path(path), e) from None


def _default(o):
    if hasattr(o, "tolist"):
        return o.tolist()
    return str(o)


@contextlib.contextmanager
def final_files(run_dir: Path) -> Iterator[Path]:
    """A staging folder for a run's final files (:func:`ipm.files.staged_directory`): they move into
    ``run_dir`` together at the end, or, on an error, none of them does. Refusals name the file in
    ``run_dir``, not in the hidden staging folder."""
    from ipm.files import staged_directory

    run_dir = Path(run_dir)
    with staged_directory(run_dir) as tmp:
        try:
            yield tmp
        except InputError as e:
            raise InputError(str(e).replace(str(tmp), str(run_dir))) from None
        except OSError as e:
            raise refused(run_dir / Path(e.filename).name if e.filename else run_dir, e) from None


@contextlib.contextmanager
def first_run(run_dir: Path | None, *, resume: bool) -> Iterator[None]:
    """Guard a run's writes into ``run_dir``. A first run (``resume=False``) that fails on bad input (an
    :class:`InputError`, an OS refusal such as a full disk, memory) leaves nothing behind: the folder is
    removed, or where it existed before, the files the run added are. Other exceptions (Ctrl-C, a
    progress callback that stops the run, a bug) keep what was recorded, a run to resume. A resume's
    folder keeps its content: its records stay resumable, and the final files are written all at once
    or not at all (:func:`final_files`). OS refusals inside come out as :class:`InputError` naming the
    file, or the run folder."""
    if run_dir is None:
        yield
        return
    run_dir = Path(run_dir)
    existed = run_dir.exists()
    before = set(run_dir.iterdir()) if existed and run_dir.is_dir() else set()
    try:
        try:
            yield
        except OSError as e:
            raise refused(run_dir if e.filename is None else Path(e.filename), e) from None
    except (InputError, MemoryError):
        if not resume:
            if not existed:
                shutil.rmtree(run_dir, ignore_errors=True)
            elif run_dir.is_dir():
                for p in set(run_dir.iterdir()) - before:
                    if p.is_dir() and not p.is_symlink():
                        shutil.rmtree(p, ignore_errors=True)
                    else:
                        p.unlink(missing_ok=True)
        raise
