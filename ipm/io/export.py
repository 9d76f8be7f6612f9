"""Mesh export through trimesh (``process=False`` keeps vertex order = Jacobian row order), and USD.

Formats are chosen by suffix from a registry. GLB files carry ``{generator, params, ipm_version}`` in
their extras, USD files (``.usda``, ``.usdc``: :mod:`ipm.io.usd`) in the mesh's customData; every export
also writes ``<name>.params.json`` beside the mesh.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

from ipm.errors import InputError
from ipm.files import atomic_path, write_text
from ipm.registry import Registry
from ipm.types import TriMesh

EXPORTERS: Registry[Callable] = Registry("mesh format")


def exporter(*suffixes: str):
    """Register ``fn(mesh: TriMesh, path, meta)`` as the writer of files with these suffixes."""
    def deco(fn):
        for s in suffixes:
            EXPORTERS.add(s, fn)
        return fn
    return deco


@exporter(".ply", ".stl")
def _export_trimesh(mesh: TriMesh, path: Path, meta: dict) -> None:
    """PLY or STL through trimesh (the metadata goes to the .params.json sidecar only)."""
    mesh.to_trimesh().export(str(path), file_type=_kind(path))


@exporter(".obj")
def _export_obj(mesh: TriMesh, path: Path, meta: dict) -> None:
    """Wavefront OBJ (:mod:`ipm.io.plain`; the metadata goes to the .params.json sidecar only)."""
    from ipm.io.plain import write_obj

    write_obj(*_arrays(mesh), path)


@exporter(".glb")
def _export_glb(mesh: TriMesh, path: Path, meta: dict) -> None:
    """Binary glTF (:mod:`ipm.io.plain`), the metadata ({generator, params, ipm_version}) in the scene's extras."""
    from ipm.io.plain import write_glb

    write_glb(*_arrays(mesh), path, meta)


@exporter(".usda", ".usdc")
def _export_usd(mesh: TriMesh, path: Path, meta: dict) -> None:
    """USD, text (.usda) or binary (.usdc): one UsdGeom.Mesh, the metadata as its customData (:mod:`ipm.io.usd`)."""
    from ipm.io.usd import write_usd

    write_usd(*_arrays(mesh), path, meta, _kind(path))


def _arrays(mesh: TriMesh) -> tuple:
    """``(verts (V, 3) float64, faces (F, 3) int64)`` numpy arrays of a mesh."""
    return mesh.verts.detach().cpu().double().numpy(), mesh.faces.cpu().numpy()


def _kind(path: Path) -> str:
    # the temporary file ends in ".tmp"; the real format is the suffix before it
    return path.name.split(".")[-2] if path.name.endswith(".tmp") else path.suffix.lstrip(".")


def sidecar_path(path: str | Path) -> Path:
    """The ``.params.json`` file written beside an exported mesh (``chair.glb`` -> ``chair.params.json``)."""
    path = Path(path)
    return path.with_name(path.stem + ".params.json")


def export_mesh(mesh: TriMesh, path: str | Path, metadata: dict | None = None, *,
                sidecar: bool = True) -> Path:
    """Write ``mesh`` to ``path`` (suffix: .obj, .ply, .stl, .glb, .usda or .usdc), atomically.

    ``metadata`` (generator, params) goes into GLB extras, USD customData and the ``.params.json`` sidecar.
    """
    from ipm.version import __version__

    path = Path(path)
    fmt = path.suffix.lower()
    if fmt not in EXPORTERS:
        raise InputError(f"output {path}: expected a suffix among {', '.join(sorted(EXPORTERS))}, "
                         f"got {fmt or '(none)'}")
    if mesh.n_faces == 0:
        raise InputError("the mesh is empty (no faces): nothing to export")
    meta = dict(metadata or {})
    meta["ipm_version"] = __version__
    with atomic_path(path, suffix=fmt + ".tmp") as tmp:
        EXPORTERS[fmt](mesh, tmp, meta)
    if sidecar:
        write_text(sidecar_path(path), json.dumps(meta, indent=2) + "\n")
    return path
