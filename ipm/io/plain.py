"""The two mesh files every fit writes, without trimesh: Wavefront OBJ and binary glTF (GLB).

A run folder holds ``mesh.obj`` and ``mesh.glb``; importing trimesh for them cost 0.45 s of a 60-evaluation
``ipm fit`` process (issue #30), so they are written here: the vertices in their order (the Jacobian's row
order), the faces as given. Readers are trimesh's, in the tests (``tests/test_export.py``).

GLB (glTF 2.0, Khronos): a 12-byte header (``glTF``, version 2, length), a JSON chunk padded with spaces and a
binary chunk padded with zeros, each 4-byte aligned; one mesh of one triangle primitive, positions as float32
``VEC3`` (with their min and max, which the format requires) and indices as uint32, in one buffer. The
metadata goes into the scene's ``extras``, where trimesh reads it as ``scene.metadata``.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np

FLOAT, UINT = 5126, 5125
ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER = 34962, 34963


def write_obj(verts: np.ndarray, faces: np.ndarray, path: str | Path) -> None:
    """``verts (V, 3)`` and ``faces (F, 3)`` (0-based) as an OBJ file: ``v`` lines, then 1-based ``f`` lines."""
    v = "\n".join(f"v {x:.10g} {y:.10g} {z:.10g}" for x, y, z in np.asarray(verts, dtype=np.float64).tolist())
    f = "\n".join(f"f {a} {b} {c}" for a, b, c in (np.asarray(faces, dtype=np.int64) + 1).tolist())
    Path(path).write_text(f"# ipm\n{v}\n{f}\n")


def _json_value(v):
    """numpy scalars and arrays in the metadata as JSON numbers and lists."""
    if isinstance(v, np.generic | np.ndarray):
        return v.tolist()
    raise TypeError(f"metadata value of type {type(v).__name__} is not JSON")


def _pad(data: bytes, fill: bytes) -> bytes:
    return data + fill * (-len(data) % 4)


def write_glb(verts: np.ndarray, faces: np.ndarray, path: str | Path, extras: dict | None = None) -> None:
    """``verts (V, 3)`` (stored as float32) and ``faces (F, 3)`` (uint32) as a GLB file, ``extras`` (JSON
    values) in the scene's extras."""
    pos = np.ascontiguousarray(verts, dtype="<f4")
    idx = np.ascontiguousarray(faces, dtype="<u4")
    binary = pos.tobytes() + idx.tobytes()
    scene: dict = {"nodes": [0]}
    if extras:
        scene["extras"] = extras
    doc = {
        "asset": {"version": "2.0", "generator": "ipm"},
        "scene": 0, "scenes": [scene], "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "mode": 4}]}],
        "accessors": [
            {"bufferView": 0, "componentType": FLOAT, "count": len(pos), "type": "VEC3",
             "min": pos.min(0).tolist(), "max": pos.max(0).tolist()},
            {"bufferView": 1, "componentType": UINT, "count": idx.size, "type": "SCALAR"}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": pos.nbytes, "target": ARRAY_BUFFER},
            {"buffer": 0, "byteOffset": pos.nbytes, "byteLength": idx.nbytes, "target": ELEMENT_ARRAY_BUFFER}],
        "buffers": [{"byteLength": len(binary)}],
    }
    js = _pad(json.dumps(doc, separators=(",", ":"), default=_json_value).encode(), b" ")
    bin_chunk = _pad(binary, b"\0")
    total = 12 + 8 + len(js) + 8 + len(bin_chunk)
    Path(path).write_bytes(struct.pack("<4sII", b"glTF", 2, total) + struct.pack("<I4s", len(js), b"JSON") + js
                           + struct.pack("<I4s", len(bin_chunk), b"BIN\0") + bin_chunk)
