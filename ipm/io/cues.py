"""Cues beyond silhouettes, as files beside a mask set: depth maps, normal maps and part labels.

In a mask-set folder (see :mod:`ipm.io.masks`), view ``i`` may have

- ``depth_###.npy``: float depth in scene units, the distance along the camera's view axis (what RGB-D
  sensors give), NaN where there is no surface; or ``depth_###.png``: 16-bit depth in millimetres, 0 where
  there is no measurement (the convention of RGB-D datasets such as ClearGrasp and OCRTOC), read in metres
  unless another scale is given;
- ``normal_###.png``: world-space unit normals as RGB, ``(n + 1) / 2 * 255``, black where empty (for
  looking at; fits use depth);
- ``part_###.png``: 8-bit labels, 0 for background and ``k + 1`` for part ``k``, with ``parts.json``
  naming the parts: ``{"labels": {"1": "walls", "2": "windows", ...}}``.

Readers raise :class:`~ipm.errors.InputError` naming the file; writers are atomic (:mod:`ipm.files`).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ipm.errors import InputError
from ipm.files import atomic_path, read_json, read_npy, write_text

PARTS_FILE = "parts.json"
MAX_DEPTH_MM = 65535          # the largest depth a 16-bit millimetre PNG holds
MAX_PARTS = 255               # labels 1..255 in an 8-bit PNG


def depth_name(i: int, suffix: str = ".npy") -> str:
    """File name of view ``i``'s depth map: ``depth_###.npy`` (scene units) or, with ``suffix=".png"``, millimetres."""
    return f"depth_{i:03d}{suffix}"


def normal_name(i: int) -> str:
    """File name of view ``i``'s normal map, ``normal_###.png``."""
    return f"normal_{i:03d}.png"


def part_name(i: int) -> str:
    """File name of view ``i``'s part labels, ``part_###.png``."""
    return f"part_{i:03d}.png"


def _array(x) -> np.ndarray:
    import torch

    return np.asarray(x.detach().cpu() if torch.is_tensor(x) else x)


def _save_png(path: Path, arr: np.ndarray) -> Path:
    """``arr``: (H, W) uint8 (grey), (H, W) uint16 (16-bit grey) or (H, W, 3) uint8 (RGB)."""
    from PIL import Image

    with atomic_path(path) as tmp:
        Image.fromarray(arr).save(tmp, format="PNG")
    return path


def _open_png(path: Path, what: str) -> np.ndarray:
    from ipm.io.masks import decode_image  # refuses decompression bombs too

    if not path.is_file():
        raise InputError(f"{what} not found: {path}")
    return decode_image(path, what, "a PNG image", np.asarray)


# -- depth ---------------------------------------------------------------------------------------------
def write_depth(path: str | Path, depth, *, png_scale: float = 0.001) -> Path:
    """Write a depth map ``(H, W)`` (non-finite where empty). ``.npy``: float32 in scene units, NaN where
    empty. ``.png``: 16-bit, ``round(depth / png_scale)`` (millimetres for metres), 0 where empty; depths
    beyond 65535 steps are refused."""
    path = Path(path)
    d = _array(depth).astype(np.float64)
    if d.ndim != 2:
        raise InputError(f"depth: expected a (H, W) array, got shape {d.shape}")
    ok = np.isfinite(d)
    if path.suffix == ".npy":
        import io

        buf = io.BytesIO()
        np.save(buf, np.where(ok, d, np.nan).astype(np.float32))
        with atomic_path(path) as tmp:
            tmp.write_bytes(buf.getvalue())
        return path
    if path.suffix != ".png":
        raise InputError(f"depth {path}: expected a .npy or .png file, got {path.suffix or '(none)'}")
    steps = np.where(ok, np.round(d / png_scale), 0)
    if (steps < 0).any() or (steps > MAX_DEPTH_MM).any():
        raise InputError(f"depth {path}: expected depths in [0, {MAX_DEPTH_MM * png_scale:g}] for a 16-bit PNG at "
                         f"{png_scale:g} a step, got up to {np.nanmax(np.where(ok, d, np.nan)):.4g}")
    return _save_png(path, steps.astype(np.uint16))


def read_depth(path: str | Path, *, png_scale: float = 0.001) -> np.ndarray:
    """A depth map ``(H, W)`` float64 in scene units, NaN where there is no measurement (``.npy``: non-finite
    or <= 0; ``.png``: 0). ``png_scale``: scene units per PNG step (0.001: millimetres to metres)."""
    path = Path(path)
    if path.suffix == ".npy":
        d = read_npy(path, "depth map")
        if d.ndim != 2 or d.dtype.kind not in "fiu":
            raise InputError(f"depth map {path}: expected a (H, W) array of numbers, got {d.dtype} {d.shape}")
        d = d.astype(np.float64)
        d[~np.isfinite(d) | (d <= 0)] = np.nan
    elif path.suffix == ".png":
        raw = _open_png(path, "depth map")
        if raw.ndim != 2:
            raise InputError(f"depth map {path}: expected a single-channel 16-bit PNG, got shape {raw.shape}")
        d = np.where(raw > 0, raw.astype(np.float64) * png_scale, np.nan)
    else:
        raise InputError(f"depth map {path}: expected a .npy or .png file, got {path.suffix or '(none)'}")
    if not np.isfinite(d).any():
        raise InputError(f"depth map {path}: expected some valid depth, got none")
    return d


# -- normals -------------------------------------------------------------------------------------------
def write_normals(path: str | Path, normal, mask) -> Path:
    """Write world-space unit normals ``(H, W, 3)`` as RGB ``(n + 1) / 2 * 255``, black outside ``mask``."""
    n = _array(normal).astype(np.float64)
    m = _array(mask).astype(bool)
    if n.ndim != 3 or n.shape[2] != 3 or m.shape != n.shape[:2]:
        raise InputError(f"normals: expected (H, W, 3) and a (H, W) mask, got {n.shape} and {m.shape}")
    rgb = np.where(m[..., None], np.clip(np.round((n + 1) * 127.5), 0, 255), 0).astype(np.uint8)
    return _save_png(Path(path), rgb)


# -- parts ---------------------------------------------------------------------------------------------
def write_parts(path: str | Path, labels) -> Path:
    """Write part labels ``(H, W)`` int (-1 background, ``k`` for part k) as an 8-bit PNG of ``k + 1``."""
    lab = _array(labels).astype(np.int64)
    if lab.ndim != 2:
        raise InputError(f"part labels: expected a (H, W) array, got shape {lab.shape}")
    if lab.min(initial=-1) < -1 or lab.max(initial=-1) >= MAX_PARTS:
        raise InputError(f"part labels: expected values in [-1, {MAX_PARTS - 1}], got [{lab.min()}, {lab.max()}]")
    return _save_png(Path(path), (lab + 1).astype(np.uint8))


def read_parts(path: str | Path) -> np.ndarray:
    """Part labels ``(H, W)`` int64: -1 background, ``k`` for the PNG value ``k + 1``."""
    raw = _open_png(Path(path), "part labels")
    if raw.ndim != 2:
        raise InputError(f"part labels {path}: expected a single-channel 8-bit PNG, got shape {raw.shape}")
    return raw.astype(np.int64) - 1


def write_part_names(folder: str | Path, names: Sequence[str]) -> Path:
    """Write ``parts.json`` naming label ``k + 1`` as ``names[k]``."""
    import json

    if len(names) > MAX_PARTS:
        raise InputError(f"parts: expected at most {MAX_PARTS} part names, got {len(names)}")
    doc = {"labels": {str(k + 1): str(n) for k, n in enumerate(names)}}
    return write_text(Path(folder) / PARTS_FILE, json.dumps(doc, indent=2) + "\n")


def read_part_names(folder: str | Path) -> dict[int, str]:
    """``{part index k: name}`` from ``parts.json`` (label ``k + 1`` in the PNGs)."""
    path = Path(folder) / PARTS_FILE
    doc = read_json(path, "part names file")
    labels = doc.get("labels") if isinstance(doc, dict) else None
    if not isinstance(labels, dict) or not labels:
        raise InputError(f"part names file {path}: expected {{\"labels\": {{\"1\": \"name\", ...}}}}, got {doc!r:.60}")
    out = {}
    for key, name in labels.items():
        if not (isinstance(key, str) and key.isdigit() and 1 <= int(key) <= MAX_PARTS and isinstance(name, str)):
            raise InputError(f"part names file {path}: expected labels 1..{MAX_PARTS} mapped to names, "
                             f"got {key!r}: {name!r}")
        out[int(key) - 1] = name
    if len(set(out.values())) != len(out):
        raise InputError(f"part names file {path}: expected distinct names, got {sorted(out.values())}")
    return out
