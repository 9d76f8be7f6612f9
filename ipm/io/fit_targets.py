"""A fit's target from files: a mask set with its depth maps and part labels, a photo with its mask (or a
box around the object), depth map and intrinsics, or a mesh.

:class:`TargetFiles` names the files (what a run's ``settings.json`` records, so that ``--resume`` reads
them again); :func:`load_target` reads and checks them into a :class:`~ipm.optim.targets.MaskTarget` or
:class:`~ipm.optim.targets.MeshTarget`. Every mismatch (a depth map of another size than its mask, a
missing view, a label file without names) is an :class:`~ipm.errors.InputError` naming the file.

Mask sets (:mod:`ipm.io.masks`): ``view_###.png`` and ``cameras.json``; ``depth`` is a folder of
``depth_###.npy`` (scene units) or ``depth_###.png`` (16-bit, ``depth_scale`` scene units a step) and
``parts`` a folder of ``part_###.png`` with ``parts.json`` (:mod:`ipm.io.cues`; ``ipm render`` writes
both beside its masks). Label values the JSON does not name are "none of the named parts": a window mask
that is 255 on windows and 0 elsewhere is ``{"labels": {"255": "windows"}}``.

Photos: one view. The fit sees a square crop around the mask (:data:`CROP_MARGIN` of the mask's larger
side on each side), resampled to ``size`` pixels a side, through the camera of that crop: the photo's
intrinsics (``--intrinsics``) or, without them, a camera whose field of view is fitted, with the principal
point at the photo's center. A depth map of the photo sets the scene's unit: depths are divided by
``unit`` so that the object's median depth is :data:`SCENE_DISTANCE` (the distance of the protocol's
cameras, where the fit's camera search starts), and results are reported back in metres. With depth and
intrinsics, the plane the object stands on (a table) is measured around it (:mod:`ipm.io.ground`) and
fixes the camera's elevation, which one silhouette hardly determines (``ground=False``: fitted instead).
"""

from __future__ import annotations

import logging
import math
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np
import torch

from ipm.errors import InputError
from ipm.io.ground import Plane
from ipm.types import Camera

log = logging.getLogger(__name__)

CROP_MARGIN = 0.3
ROLL_WARN_DEG = 5.0  # a photo rolled more than this against its ground plane is reported
SCENE_DISTANCE = 3.2


@dataclass(frozen=True)
class TargetFiles:
    """Where a fit's target comes from (see the module docstring); paths as strings."""

    masks: str | None = None
    target_mesh: str | None = None
    up: str = "y"
    depth: str | None = None
    depth_scale: float = 0.001
    parts: str | None = None
    image: str | None = None
    mask: str | None = None
    box: tuple[int, int, int, int] | None = None
    intrinsics: str | None = None
    size: int = 128
    ground: bool = True

    def __post_init__(self) -> None:
        kinds = [k for k in ("masks", "target_mesh", "image") if getattr(self, k) is not None]
        if len(kinds) != 1:
            raise InputError("expected exactly one target: masks (a folder), a target mesh or a photo (image); got "
                             + (" and ".join(kinds) if kinds else "none"))
        if self.image is not None and (self.mask is None) == (self.box is None):
            raise InputError("a photo target needs its mask (--mask MASK.png) or a box around the object "
                             "(--box X0,Y0,X1,Y1), one of them; got " + ("both" if self.mask else "neither"))
        if self.image is None:
            for name in ("mask", "box", "intrinsics"):
                if getattr(self, name) is not None:
                    raise InputError(f"{name}: expected only with a photo target (--image PHOTO), got it with "
                                     f"{kinds[0].replace('_', ' ')}")
        if self.target_mesh is not None and (self.depth or self.parts):
            raise InputError("depth and part labels: expected with masks or a photo, got them with a target mesh")
        if self.image is not None and self.parts is not None:
            raise InputError("part labels: expected with a mask set (--masks DIR), got them with a photo")
        if self.up not in ("y", "z"):
            raise InputError(f"up axis: expected y or z, got {self.up!r}")
        if not (isinstance(self.size, int) and 16 <= self.size <= 1024):
            raise InputError(f"photo size: expected an integer in [16, 1024] pixels, got {self.size!r}")
        if not (math.isfinite(self.depth_scale) and self.depth_scale > 0):
            raise InputError(f"depth scale: expected a positive number of scene units per PNG step, got "
                             f"{self.depth_scale!r}")

    def to_json(self) -> dict:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(self).items()}

    @staticmethod
    def from_json(d: dict) -> TargetFiles:
        """The files a run's ``settings.json`` records (:meth:`to_json`), checked against the fields' types:
        :class:`InputError` "field: expected ..., got ..." (keys this version does not know are ignored)."""
        import msgspec

        from ipm.settings_check import allowed, error_path, field_types

        if not isinstance(d, dict):
            raise InputError(f"expected an object of the target's files, got {type(d).__name__}")
        known = {f.name for f in fields(TargetFiles)}
        vals = {k: v for k, v in d.items() if k in known}
        vals.setdefault("ground", False)  # runs recorded before the ground plane was measured replay without it
        try:
            return msgspec.convert(vals, TargetFiles)
        except msgspec.ValidationError as e:
            path = error_path(str(e))
            types = field_types(TargetFiles)
            if path and path[0] in types:
                what = "4 integers" if path[0] == "box" else allowed(types[path[0]])
                raise InputError(f"{path[0]}: expected {what}, got {vals.get(path[0])!r:.60}") from None
            raise InputError(str(e).split(" - at ")[0]) from None


@dataclass(frozen=True)
class Photo:
    """A photo target as given (full resolution) and how the fit sees it.

    image: (H, W, 3) uint8; mask: (H, W) float32 in [0, 1]; depth: (H, W) metres (NaN: no reading) or
    None; camera: the full photo's camera at the fit's placeholder pose (intrinsics, or a guess
    without them); window: (x0, y0, side) of the square crop in photo pixels; scale: fit pixels per photo
    pixel; unit: metres per scene unit (1 without depth); ground: the plane the object stands on, where
    the depth and the intrinsics show one (:func:`ipm.io.ground.support_plane`), else None."""

    image: np.ndarray
    mask: np.ndarray
    depth: np.ndarray | None
    camera: Camera
    window: tuple[int, int, int]
    scale: float
    unit: float
    ground: Plane | None = None


def load_target(files: TargetFiles, *, camera: str = "known", device=None, dtype=torch.float32):
    """(target, :class:`Photo` or None) from ``files``; ``camera``: ``"known"`` or ``"fit"`` (a photo's camera
    is always fitted)."""
    from ipm.optim.targets import MaskTarget, MeshTarget

    if files.target_mesh is not None:
        from ipm.io.meshes import load_mesh

        mesh = load_mesh(Path(files.target_mesh), up=files.up, normalize=True)
        if mesh.n_faces == 0:
            raise InputError(f"target mesh {files.target_mesh}: expected faces, got none")
        return MeshTarget(mesh), None
    if files.image is not None:
        return _photo_target(files, device, dtype)
    folder = Path(files.masks)
    from ipm.io.masks import CAMERAS_FILE, load_mask_set

    if camera == "fit" and not (folder / CAMERAS_FILE).is_file():
        m, cams = _masks_without_cameras(folder)
    else:
        if not (folder / CAMERAS_FILE).is_file():
            raise InputError(f"--masks {folder}: expected {CAMERAS_FILE}, got no {CAMERAS_FILE}; give the "
                             "cameras, or recover them with --camera fit")
        ms = load_mask_set(folder, soft=True)
        m, cams = ms.masks.numpy(), list(ms.cameras)
        sizes = {(c.width, c.height) for c in cams}
        if len(sizes) > 1:
            raise InputError(f"--masks {folder}: expected masks of one size, got sizes {sorted(sizes)}")
    views = [folder / f"view_{i:03d}.png" for i in range(len(m))]
    depth = _depth_maps(Path(files.depth), views, m, files.depth_scale) if files.depth else None
    parts, names = _part_maps(Path(files.parts), views, m) if files.parts else (None, ())

    def t(a):
        return None if a is None else torch.as_tensor(a, device=device)

    target = MaskTarget(t(m).to(dtype), [c.to(dtype=dtype, device=device) for c in cams],
                        depth=None if depth is None else t(depth).to(dtype), parts=t(parts), part_names=names)
    return target, None


def _masks_without_cameras(folder: Path):
    """Masks ``view_*.png`` of one size and placeholder cameras (protocol pose) for ``camera="fit"``."""
    from ipm.io.masks import read_mask
    from ipm.render.camera import orbit_camera

    paths = sorted(folder.glob("view_*.png"))
    if len(paths) != 1:
        raise InputError(f"--camera fit: expected exactly one mask view_000.png in {folder}, got {len(paths)}")
    m = read_mask(paths[0], soft=True)
    H, W = m.shape
    return np.stack([m]), [orbit_camera(0.0, 25.0, SCENE_DISTANCE, fov_deg=40.0, width=W, height=H)]


def _same_size(path: Path, arr: np.ndarray, view: Path, mask: np.ndarray) -> None:
    if arr.shape != mask.shape:
        raise InputError(f"{path}: expected {mask.shape[1]}x{mask.shape[0]} pixels like the mask {view.name}, got "
                         f"{arr.shape[1]}x{arr.shape[0]} (depth, labels and masks must be of one size)")


def _view_file(folder: Path, stem: str, suffixes: tuple[str, ...], what: str) -> Path:
    found = [folder / f"{stem}{s}" for s in suffixes if (folder / f"{stem}{s}").is_file()]
    if not found:
        raise InputError(f"{what} {folder}: expected {' or '.join(stem + s for s in suffixes)}, got neither")
    return found[0]


def _depth_maps(folder: Path, views: list[Path], masks: np.ndarray, png_scale: float) -> np.ndarray:
    from ipm.io.cues import depth_name, read_depth

    if not folder.is_dir():
        raise InputError(f"--depth: expected a folder of depth_000.npy (or .png) ..., got {folder} "
                         f"({'a file' if folder.exists() else 'missing'})")
    out = []
    for i, (view, m) in enumerate(zip(views, masks)):
        path = _view_file(folder, depth_name(i, ""), (".npy", ".png"), "depth maps")
        d = read_depth(path, png_scale=png_scale)
        _same_size(path, d, view, m)
        if not np.isfinite(d[m > 0.5]).any():
            raise InputError(f"{path}: expected a valid depth on some of the object's pixels (mask {view.name}), "
                             "got none")
        out.append(d)
    return np.stack(out)


def _part_maps(folder: Path, views: list[Path], masks: np.ndarray) -> tuple[np.ndarray, tuple[str, ...]]:
    """Labels (K, H, W) int64 as indices into the returned names (-1: none of them)."""
    from ipm.io.cues import part_name, read_part_names, read_parts

    if not folder.is_dir():
        raise InputError(f"--parts: expected a folder of part_000.png ... and parts.json, got {folder} "
                         f"({'a file' if folder.exists() else 'missing'})")
    named = read_part_names(folder)  # {png value - 1: name}
    names = tuple(named[k] for k in sorted(named))
    lut = np.full(256, -1, dtype=np.int64)
    for j, k in enumerate(sorted(named)):
        lut[k + 1] = j
    out = []
    for i, (view, m) in enumerate(zip(views, masks)):
        path = folder / part_name(i)
        raw = read_parts(path)
        _same_size(path, raw, view, m)
        out.append(lut[raw + 1])
    return np.stack(out), names


# -- photos ------------------------------------------------------------------------------------------

def _photo_mask(files: TargetFiles, image: np.ndarray) -> np.ndarray:
    """The photo's soft mask (H, W) float: read from ``--mask`` or segmented inside ``--box``; checked to
    have foreground and background."""
    from ipm.io.masks import read_mask
    from ipm.segment import box_mask, check_box

    H, W = image.shape[:2]
    if files.mask is not None:
        mask = read_mask(files.mask, soft=True)
        if mask.shape != (H, W):
            raise InputError(f"--mask {files.mask}: expected {W}x{H} pixels like the photo, got "
                             f"{mask.shape[1]}x{mask.shape[0]}")
    else:
        box = check_box(files.box, W, H)
        mask = box_mask(image, box).astype(np.float32)
        if not mask.any():
            raise InputError(f"--box {','.join(map(str, box))}: no foreground found in the box; draw the box "
                             "around the object")
    fg = mask > 0.5
    if not fg.any():
        raise InputError(f"--mask {files.mask}: expected some foreground pixels (> 127), got none")
    if fg.all():
        raise InputError(f"--mask {files.mask}: expected the object inside the photo, got no background")
    return mask


def _photo_depth(files: TargetFiles, fg: np.ndarray) -> np.ndarray | None:
    """The photo's depth map (H, W) float from ``--depth`` (None without one), checked against the
    foreground ``fg`` (H, W) bool."""
    from ipm.io.cues import read_depth

    if files.depth is None:
        return None
    H, W = fg.shape
    path = Path(files.depth)
    if path.is_dir():
        raise InputError(f"--depth {path}: expected the photo's depth map (.npy or 16-bit .png), got a folder")
    depth = read_depth(path, png_scale=files.depth_scale)
    if depth.shape != (H, W):
        raise InputError(f"--depth {path}: expected {W}x{H} pixels like the photo and its mask, got "
                         f"{depth.shape[1]}x{depth.shape[0]} (depth and mask must be of one size)")
    if not np.isfinite(depth[fg]).any():
        raise InputError(f"--depth {path}: expected a valid depth on some of the object's pixels, got none")
    return depth


def _crop(fg: np.ndarray) -> tuple[int, int, int]:
    """The square crop ``(x0, y0, side)`` around the foreground ``fg`` (H, W) bool, inside the photo."""
    H, W = fg.shape
    ys, xs = np.nonzero(fg)
    side = int(math.ceil(max(xs.max() - xs.min() + 1, ys.max() - ys.min() + 1) * (1 + 2 * CROP_MARGIN)))
    side = min(side, W, H)
    x0 = int(np.clip(round((xs.min() + xs.max() + 1) / 2 - side / 2), 0, W - side))
    y0 = int(np.clip(round((ys.min() + ys.max() + 1) / 2 - side / 2), 0, H - side))
    return x0, y0, side


def _photo_target(files: TargetFiles, device, dtype):
    """The fit's target for a photo (its crop, resampled) and the :class:`Photo` that maps results back."""
    import cv2

    from ipm.io.masks import read_photo
    from ipm.optim.targets import MaskTarget
    from ipm.render.camera import crop_camera, load_intrinsics, orbit_camera

    image = read_photo(files.image)
    H, W = image.shape[:2]
    mask = _photo_mask(files, image)
    fg = mask > 0.5
    depth = _photo_depth(files, fg)
    if files.intrinsics is not None:
        intr = load_intrinsics(files.intrinsics)
        if (intr.width, intr.height) != (W, H):
            raise InputError(f"--intrinsics {files.intrinsics}: expected a camera of the photo's size {W}x{H}, got "
                             f"{intr.width}x{intr.height}")
        fov, cx, cy = intr.fov_deg, intr.cx, intr.cy
    else:
        fov, cx, cy = 40.0, W / 2.0, H / 2.0
    unit = 1.0
    if depth is not None:
        unit = float(np.nanmedian(depth[fg])) / SCENE_DISTANCE
    full = orbit_camera(0.0, 25.0, SCENE_DISTANCE, fov_deg=fov, width=W, height=H, cx=cx, cy=cy)
    x0, y0, side = _crop(fg)
    n = files.size
    scale = n / side
    cam = crop_camera(full, x0, y0, side, side, scale)
    win = (slice(y0, y0 + side), slice(x0, x0 + side))

    def resample(a: np.ndarray) -> np.ndarray:
        return cv2.resize(a.astype(np.float32), (n, n), interpolation=cv2.INTER_AREA)

    m = np.clip(resample(mask[win]), 0.0, 1.0)
    grey = resample(image[win].astype(np.float32) @ np.array([0.299, 0.587, 0.114], dtype=np.float32) / 255.0)
    d_fit = None
    if depth is not None:
        ok = np.isfinite(depth[win])
        share = resample(ok.astype(np.float32))
        total = resample(np.where(ok, depth[win], 0.0))
        d_fit = np.where(share > 0.5, total / np.maximum(share, 1e-6), np.nan) / unit
        if not np.isfinite(d_fit[m > 0.5]).any():
            raise InputError(f"--depth {files.depth}: expected a valid depth on some of the object's pixels at "
                             f"the fit's resolution, got none")
    ground = _ground(files, depth, mask, intr) if files.intrinsics is not None else None
    photo = Photo(image, mask, depth, full, (x0, y0, side), scale, unit, ground)

    def t(a):
        return torch.as_tensor(a[None], device=device).to(dtype)

    target = MaskTarget(t(m), [cam.to(dtype=dtype, device=device)], depth=None if d_fit is None else t(d_fit),
                        image=t(grey), known_intrinsics=files.intrinsics is not None,
                        ground_elevation=None if ground is None else ground.elevation_deg,
                        outside_is_background=not _touches_edge(fg))
    log.info("photo %dx%d: fitting a %d px crop at (%d, %d) resampled to %d px%s", W, H, side, x0, y0, n,
             f", {unit:.4g} m per scene unit" if depth is not None else "")
    return target, photo


def _touches_edge(fg: np.ndarray) -> bool:
    """Whether the foreground reaches the photo's border (the object may go on beyond it)."""
    return bool(fg[0].any() or fg[-1].any() or fg[:, 0].any() or fg[:, -1].any())


def _ground(files: TargetFiles, depth: np.ndarray | None, mask: np.ndarray, intr) -> Plane | None:
    """The plane under the object where ``files.ground`` asks for it and the depth shows one whose
    elevation a fit's camera can take (:data:`ipm.optim.encoding.ELEV`); logged either way."""
    from ipm.io.ground import support_plane
    from ipm.optim.encoding import ELEV

    if not files.ground or depth is None:
        return None
    plane = support_plane(depth, mask, intr.fy, intr.fy, intr.cx, intr.cy)
    if plane is None:
        log.info("ground: no plane found around the object in the depth map; the camera's elevation is fitted")
        return None
    if not ELEV[0] <= plane.elevation_deg <= ELEV[1]:
        log.info("ground: the plane around the object gives an elevation of %.1f deg, outside the fit's "
                 "%g..%g; the camera's elevation is fitted", plane.elevation_deg, *ELEV)
        return None
    log.info("ground: the object stands on a plane (%.0f%% of %d points around it, median residual %.1f mm): "
             "camera elevation %.1f deg, held", 100 * plane.share, plane.points, 1000 * plane.residual,
             plane.elevation_deg)
    if abs(plane.roll_deg) > ROLL_WARN_DEG:
        log.warning("ground: the photo is rolled by %.1f deg against the plane; the fit's camera has no roll",
                    plane.roll_deg)
    return plane


def uncrop_camera(cam: Camera, photo: Photo) -> Camera:
    """The full photo's camera with the pose of ``cam``, a camera of the fit's crop (:func:`load_target`)."""
    from ipm.render.camera import focal_pixels

    s = photo.scale
    x0, y0, _ = photo.window
    H = photo.camera.height
    f = float(focal_pixels(cam)) / s
    fov = 2.0 * math.degrees(math.atan(H / (2.0 * f)))
    cx, cy = cam.principal_point
    return Camera(cam.eye, cam.target, cam.up, torch.tensor(fov, dtype=cam.eye.dtype), photo.camera.width, H,
                  float(cx) / s + x0, float(cy) / s + y0)
