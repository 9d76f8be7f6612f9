"""SDF trees written as editable CAD programs: OpenSCAD (``.scad``) and CadQuery (Python, ``.py``).

A tree is first lowered to parts and variables (:mod:`ipm.io.programs.lower`); a :class:`ProgramFormat`,
registered under its file suffix in :data:`PROGRAMS` by its own module in this package, writes them as
one statement per node, the parameters as variables at the top and a header naming the generator, ipm's
version and the command that wrote the file. Nodes a language has no exact counterpart for (smooth
booleans, rounding and shells in 3D, elongation) refuse the whole export with one line naming the node.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

from ipm.errors import InputError
from ipm.registry import Registry

PROGRAMS: Registry[ProgramFormat] = Registry("program format", packages=["ipm.io.programs"])
DEFAULT_SEGMENTS = 64  # as ipm.sdf.exact's meshes


@dataclass(frozen=True)
class ProgramFormat:
    """One language: its name, its line-comment marker, the node types it writes (``nodes``: type name ->
    the writer of that node's statement, used by ``write``) and ``write(program, segments, header)``, the
    whole file's text."""

    language: str
    comment: str
    nodes: Mapping[str, Callable]
    write: Callable

    @property
    def summary(self) -> str:
        """What ``ipm list programs`` says of it."""
        return f"{self.language} program of an SDF tree ({len(self.nodes)} node types)"


def program_format(path: str | Path) -> ProgramFormat:
    """The format of a program file by its suffix; :class:`InputError` lists the known suffixes."""
    suffix = Path(path).suffix.lower()
    if suffix not in PROGRAMS:
        raise InputError(f"output {path}: expected a program suffix among {', '.join(PROGRAMS.names())}, "
                         f"got {suffix or '(none)'}")
    return PROGRAMS[suffix]


def program_text(tree, fmt: ProgramFormat, metadata: Mapping | None = None, *,
                 segments: int = DEFAULT_SEGMENTS, command: str | None = None) -> str:
    """The program of an SDF ``tree`` (:class:`~ipm.sdf.tree.Tree`, its stored values) in ``fmt``.

    metadata: ``{generator, ...}`` for the header; segments: the count of straight pieces a full circle is
    cut into where the language needs one (OpenSCAD's ``$fn``; :func:`ipm.sdf.exact.exact_mesh` cuts circles
    alike); command: the command line for the header.
    :class:`InputError` (one line) when a node has no counterpart in the language, naming it and what is
    written.
    """
    from ipm.io.programs.lower import first_unmapped, lower
    from ipm.sdf.exact import check_segments
    from ipm.version import __version__

    check_segments(segments)
    program = lower(tree)
    bad = first_unmapped(program, fmt.nodes)
    if bad is not None:
        raise InputError(f"node {bad.note or bad.label} ({bad.kind}) has no {fmt.language} counterpart; "
                         f"{fmt.language} programs take the nodes {', '.join(sorted(fmt.nodes))}")
    meta = dict(metadata or {})
    header = [f"{fmt.language} program of an ipm SDF tree, written by ipm {__version__}",
              f"generator: {meta.get('generator', 'sdftree')}"]
    if command:
        header.append(f"command: {command}")
    header.append("The parameters are the variables below: edit them and run the program again.")
    return fmt.write(program, segments, header)


def export_program(tree, path: str | Path, metadata: Mapping | None = None, *, segments: int = DEFAULT_SEGMENTS,
                   command: str | None = None, sidecar: bool = True) -> Path:
    """Write the program of an SDF ``tree`` to ``path`` (its suffix picks the language, :data:`PROGRAMS`),
    atomically, with the ``.params.json`` sidecar of mesh exports (``metadata`` and ipm's version).
    See :func:`program_text` for the rest."""
    from ipm.files import write_text
    from ipm.io.export import sidecar_path
    from ipm.version import __version__

    path = Path(path)
    text = program_text(tree, program_format(path), metadata, segments=segments, command=command)
    write_text(path, text)
    if sidecar:
        meta = {**dict(metadata or {}), "ipm_version": __version__}
        write_text(sidecar_path(path), json.dumps(meta, indent=2) + "\n")
    return path


__all__ = ["DEFAULT_SEGMENTS", "PROGRAMS", "ProgramFormat", "export_program", "program_format", "program_text"]
