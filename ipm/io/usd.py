"""Meshes as USD stages (``.usda`` text, ``.usdc`` binary) through ``usd-core`` (``pxr``, imported lazily).

The stage holds one ``UsdGeom.Mesh`` at ``/<generator>/mesh`` (Y up, as ipm; triangles, no subdivision):
its points, faceVertexCounts and faceVertexIndices. The generator's name, its parameters and ipm's version
are the mesh prim's ``customData`` (``generator``, ``params``, ``ipm_version``), readable in any USD tool;
``ipm_metadata`` holds everything the export was given as JSON (a tree, a pose), which :func:`read_usd`
gives back as it was.

pxr picks a layer's format by its file name; the atomic writer's temporary file ends in ``.tmp``, so the
stage is exported under its real suffix in a private folder beside the target and then moved onto the
temporary file.
"""

from __future__ import annotations

import json
import os
import re
import tempfile
from pathlib import Path

import numpy as np

from ipm.errors import InputError

FORMATS = ("usda", "usdc")


def write_usd(verts: np.ndarray, faces: np.ndarray, path: str | Path, metadata: dict, fmt: str) -> Path:
    """Write a triangle mesh (``verts: (V, 3) float``, ``faces: (F, 3) int``) with ``metadata``
    (``{generator, params, ipm_version, ...}``, JSON values) as a USD stage in format ``fmt`` (usda, usdc)
    to ``path`` (any name: the temporary file of an atomic write too)."""
    from pxr import Usd, UsdGeom, Vt

    if fmt not in FORMATS:
        raise InputError(f"USD: expected a format among {', '.join(FORMATS)}, got {fmt!r}")
    verts, faces = np.asarray(verts, np.float64), np.asarray(faces, np.int64)
    stage = Usd.Stage.CreateInMemory(f"mesh.{fmt}")
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    root = UsdGeom.Xform.Define(stage, "/" + prim_name(str(metadata.get("generator") or "ipm")))
    stage.SetDefaultPrim(root.GetPrim())
    mesh = UsdGeom.Mesh.Define(stage, root.GetPath().AppendChild("mesh"))
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(verts.astype(np.float32)))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(faces), 3, np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(faces.reshape(-1).astype(np.int32)))
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    mesh.CreateExtentAttr(Vt.Vec3fArray.FromNumpy(np.stack([verts.min(0), verts.max(0)]).astype(np.float32)))
    mesh.GetPrim().SetCustomData(_custom_data(metadata))
    path = Path(path)
    with tempfile.TemporaryDirectory(prefix=".usd.", dir=path.parent) as folder:
        staged = Path(folder) / f"mesh.{fmt}"
        if not stage.GetRootLayer().Export(str(staged)):
            raise InputError(f"output {path}: USD could not write the stage")
        os.replace(staged, path)
    return path


def prim_name(text: str) -> str:
    """``text`` as a USD prim name (letters, digits and ``_``, not starting with a digit)."""
    out = re.sub(r"\W", "_", text, flags=re.ASCII) or "ipm"
    return "_" + out if out[0].isdigit() else out


def _custom_data(metadata: dict) -> dict:
    """The prim's customData: generator, params (numbers, booleans, strings), ipm_version, and the whole
    metadata as JSON."""
    params = {str(k): v for k, v in dict(metadata.get("params") or {}).items()
              if isinstance(v, (bool, int, float, str))}
    out = {"params": params, "ipm_metadata": json.dumps(metadata, sort_keys=True)}
    for key in ("generator", "ipm_version"):
        if metadata.get(key) is not None:
            out[key] = str(metadata[key])
    return out


def read_usd(path: str | Path) -> tuple[np.ndarray, np.ndarray, dict]:
    """``(verts (V, 3) float64, faces (F, 3) int64, metadata)`` of the first mesh of a USD stage written by
    :func:`write_usd` (its faces must be triangles); :class:`InputError` names the file when it is not."""
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(path))
    if stage is None:
        raise InputError(f"USD file {path}: cannot be opened")
    prim = next((p for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)), None)
    if prim is None:
        raise InputError(f"USD file {path}: expected a mesh, got none")
    mesh = UsdGeom.Mesh(prim)
    counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get(), np.int64)
    if counts.size and not (counts == 3).all():
        raise InputError(f"USD file {path}: expected triangles, got faces of {sorted(set(counts.tolist()))} corners")
    verts = np.asarray(mesh.GetPointsAttr().Get(), np.float64).reshape(-1, 3)
    faces = np.asarray(mesh.GetFaceVertexIndicesAttr().Get(), np.int64).reshape(-1, 3)
    data = prim.GetCustomData()
    meta = json.loads(data["ipm_metadata"]) if "ipm_metadata" in data else {
        k: data[k] for k in ("generator", "params", "ipm_version") if k in data}
    return verts, faces, meta


__all__ = ["FORMATS", "prim_name", "read_usd", "write_usd"]
