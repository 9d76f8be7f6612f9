"""Mask sets: a folder with ``view_000.png``, ``view_001.png``, ... and ``cameras.json`` (DESIGN.md).

Masks are 8-bit PNG, foreground > 127. ``cameras.json`` is a JSON list with one entry per view:
``{eye, target, up, fov_deg, width, height}`` (optionally ``cx, cy``, the principal point in pixels).
:func:`load_mask_set` checks everything a fitter relies on and raises ``ValueError`` with the file at
fault ("expected ..., got ..."); :func:`save_mask_set` writes atomically, and :func:`staged_directory`
makes a whole folder of outputs appear at once or not at all.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ipm.errors import InputError
from ipm.files import atomic_path, write_text
from ipm.render.camera import cameras_to_json, load_cameras
from ipm.types import Camera

CAMERAS_FILE = "cameras.json"
VIEW_RE = re.compile(r"^view_(\d{3,})\.png$")


def view_name(i: int) -> str:
    """File name of view ``i``'s mask in a mask-set folder, ``view_###.png`` (three digits at least)."""
    return f"view_{i:03d}.png"


@dataclass(frozen=True)
class MaskSet:
    """Masks (N, H, W) bool (float32 in [0, 1] when read soft) with their cameras (N entries); ``paths`` are
    the mask files."""

    masks: torch.Tensor
    cameras: tuple[Camera, ...]
    paths: tuple[Path, ...] = ()

    def __len__(self) -> int:
        return len(self.cameras)


def decode_image(path: Path, what: str, expected: str, convert: Callable) -> np.ndarray:
    """``convert(image)`` of the image file at ``path``, read by Pillow; one-line :class:`InputError`
    naming it as ``what`` for a file that is not an image (``expected`` says what is) and for an image of
    more than ``PIL.Image.MAX_IMAGE_PIXELS`` pixels (Pillow's decompression-bomb limit, about 89
    megapixels): refused from its header, before it is decoded."""
    import warnings

    from PIL import Image, UnidentifiedImageError

    try:
        with warnings.catch_warnings():
            # Pillow warns from the limit and raises from twice the limit: both refused here
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            with Image.open(path) as im:
                im.load()
                return convert(im)
    except (Image.DecompressionBombError, Image.DecompressionBombWarning) as e:
        size = re.search(r"\((\d+) pixels\)", str(e))
        raise InputError(f"{what} {path}: expected an image of at most {Image.MAX_IMAGE_PIXELS:,} pixels (the "
                         f"limit), got {f'{int(size.group(1)):,} pixels' if size else 'a larger one'}") from None
    except (UnidentifiedImageError, OSError, SyntaxError, ValueError) as e:
        raise InputError(f"{what} {path}: expected {expected}, got an unreadable file ({type(e).__name__})") from None


def read_mask(path: str | Path, soft: bool = False) -> np.ndarray:
    """A mask PNG as (H, W) bool (foreground: value > 127; color images are converted to luminance,
    images with alpha use the alpha channel), or with ``soft`` as (H, W) float32 ``value / 255`` (soft
    masks: 0..255 is the foreground's share of the pixel). ``InputError`` if the file is not an image or
    has more pixels than Pillow's decompression-bomb limit (:func:`read_image`)."""
    def grey(im) -> np.ndarray:
        if im.mode in ("RGBA", "LA") or (im.mode == "P" and "transparency" in im.info):
            return np.asarray(im.convert("RGBA"))[..., 3]
        return np.asarray(im.convert("L"))

    arr = decode_image(Path(path), "mask", "a PNG image", grey)
    if soft:
        return arr.astype(np.float32) / 255.0
    return arr > 127


def read_image(path: str | Path, what: str, mode: str) -> np.ndarray:
    """The image at ``path`` converted to Pillow ``mode`` ("RGB", "RGBA", "L") as a uint8 array; one-line
    :class:`InputError` naming it as ``what`` if it is missing, not an image, or larger than Pillow's
    decompression-bomb limit (``PIL.Image.MAX_IMAGE_PIXELS``, about 89 megapixels: refused from the
    file's header, before anything is decoded). Photos (``ipm mask``, ``ipm fit --image``) and drawings
    (``ipm vectorize``) are read here."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{what} not found: {path}")
    return decode_image(path, what, "an image file (PNG, JPEG)", lambda im: np.asarray(im.convert(mode)))


def read_photo(path: str | Path) -> np.ndarray:
    """A photo (JPEG, PNG, ...) as ``(H, W, 3)`` uint8 RGB (alpha and palettes are converted)."""
    return read_image(path, "photo", "RGB")


def write_mask(path: str | Path, mask) -> Path:
    """Write a (H, W) bool mask as an 8-bit PNG (0 / 255), atomically."""
    from PIL import Image

    arr = np.asarray(mask.detach().cpu() if torch.is_tensor(mask) else mask)
    if arr.ndim != 2:
        raise InputError(f"mask: expected a (H, W) array, got shape {arr.shape}")
    img = Image.fromarray(np.where(arr > (0.5 if arr.dtype.kind == "f" else 0), 255, 0).astype(np.uint8), "L")
    with atomic_path(path) as tmp:
        img.save(tmp, format="PNG")
    return Path(path)


def save_mask_set(folder: str | Path, masks, cameras: Sequence[Camera]) -> list[Path]:
    """Write ``view_###.png`` for each mask (N, H, W) and ``cameras.json``; returns the paths written."""
    folder = Path(folder)
    if len(masks) != len(cameras):
        raise InputError(f"mask set: expected one camera per mask, got {len(masks)} masks and "
                         f"{len(cameras)} cameras")
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for i, (m, cam) in enumerate(zip(masks, cameras)):
        h, w = (m.shape[0], m.shape[1])
        if (w, h) != (cam.width, cam.height):
            raise InputError(f"mask {i}: expected {cam.width}x{cam.height} like its camera, got {w}x{h}")
        paths.append(write_mask(folder / view_name(i), m))
    paths.append(write_text(folder / CAMERAS_FILE, cameras_to_json(cameras)))
    return paths


def load_mask_set(folder: str | Path, soft: bool = False) -> MaskSet:
    """Read and validate a mask set.

    Checks: the folder exists; ``cameras.json`` is there and every entry has eye, target, up, fov_deg,
    width and height; masks are named ``view_000.png`` ... without gaps; there are as many masks as
    cameras; every mask is a readable image of its camera's size. Returns masks (N, H, W) bool
    (views of different sizes are not stacked: then ``masks`` is padded to the largest size and the
    cameras tell each view's size). ``soft``: masks as float32 in [0, 1] (:func:`read_mask`).
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"mask set: expected a folder with view_000.png ... and {CAMERAS_FILE}, got "
                         f"{folder} ({'a file' if folder.exists() else 'missing'})")
    cam_path = folder / CAMERAS_FILE
    if not cam_path.is_file():
        raise InputError(f"mask set {folder}: expected {CAMERAS_FILE} in the folder, got none")
    cameras = load_cameras(cam_path)
    found = {}
    for p in folder.iterdir():
        m = VIEW_RE.match(p.name)
        if m:
            found[int(m.group(1))] = p
    if not found:
        raise InputError(f"mask set {folder}: expected masks view_000.png ..., got none")
    expected = list(range(len(found)))
    if sorted(found) != expected:
        missing = sorted(set(range(max(found) + 1)) - set(found))
        raise InputError(f"mask set {folder}: expected consecutive views from view_000.png, got a gap at "
                         f"{view_name(missing[0])}")
    if len(found) != len(cameras):
        raise InputError(f"mask set {folder}: expected as many masks as cameras, got {len(found)} masks and "
                         f"{len(cameras)} entries in {CAMERAS_FILE}")
    arrays = []
    for i, cam in enumerate(cameras):
        arr = read_mask(found[i], soft)
        if arr.shape != (cam.height, cam.width):
            raise InputError(f"mask {found[i]}: expected {cam.width}x{cam.height} pixels (from "
                             f"{CAMERAS_FILE}), got {arr.shape[1]}x{arr.shape[0]}")
        arrays.append(arr)
    H = max(a.shape[0] for a in arrays)
    W = max(a.shape[1] for a in arrays)
    stack = np.zeros((len(arrays), H, W), dtype=np.float32 if soft else bool)
    for i, a in enumerate(arrays):
        stack[i, : a.shape[0], : a.shape[1]] = a
    return MaskSet(torch.from_numpy(stack), tuple(cameras), tuple(found[i] for i in expected))
