"""Camera math as pure functions: look-at and orbit cameras, view and projection matrices, projection of
points to pixels, pixel rays, and the evaluation-protocol view sets of DESIGN.md.

Conventions (DESIGN.md): right-handed world, Y up; the camera looks down -Z in camera space (OpenGL);
vertical field of view in degrees; image row 0 is the top and pixel ``(col i, row j)`` has its center at
``(i + 0.5, j + 0.5)``. Screen coordinates are returned as ``(x, y)`` in pixels with x to the right and
y down; depth is the distance along the viewing axis (positive in front of the camera). The principal
point ``(cx, cy)`` (:attr:`Camera.principal_point`) is the image center unless the camera sets it; pixels
are square, with focal length ``height / (2 tan(fov / 2))`` pixels on both axes.

Known intrinsics (``fx, fy, cx, cy``) of a real camera come in as :class:`Intrinsics`
(:func:`load_intrinsics` reads JSON and ClearGrasp's YAML) and become cameras through
:func:`intrinsics_camera`, or ``orbit_camera(..., fov_deg=intr.fov_deg, width=intr.width,
height=intr.height, cx=intr.cx, cy=intr.cy)``. :func:`crop_camera` is the camera of a window of an image,
resized.

Everything is differentiable in every camera quantity (eye, target, up, fov) and follows the dtype and
device of the camera's tensors.

Orbit convention: ``eye = target + distance * (cos(el) sin(az), sin(el), cos(el) cos(az))``, so azimuth 0
looks from +Z towards the target, azimuth 90° from +X (a positive rotation about +Y, counterclockwise
seen from above), and positive elevation looks down from above.
"""

from __future__ import annotations

import json
import logging
import math
import numbers
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import torch

from ipm.errors import InputError
from ipm.registry import Registry
from ipm.types import Camera

# The evaluation protocol (DESIGN.md).
PROTOCOL_FOV_DEG = 40.0
PROTOCOL_DISTANCE = 3.2
PROTOCOL_ELEVATION_DEG = 25.0

log = logging.getLogger(__name__)


def _as_tensor(x, like: torch.Tensor | None = None, dtype=torch.float64) -> torch.Tensor:
    if torch.is_tensor(x):
        return x
    if like is not None:
        return torch.as_tensor(x, dtype=like.dtype, device=like.device)
    return torch.as_tensor(x, dtype=dtype)


def _normalize(v: torch.Tensor, eps: float = 1e-12) -> torch.Tensor:
    return v / torch.linalg.vector_norm(v, dim=-1, keepdim=True).clamp_min(eps)


def look_at_camera(eye, target, up=(0.0, 1.0, 0.0), fov_deg=PROTOCOL_FOV_DEG, width: int = 256,
                   height: int | None = None, *, cx: float | None = None, cy: float | None = None) -> Camera:
    """A :class:`~ipm.types.Camera` at ``eye`` looking at ``target``.

    eye, target, up: (3,) tensors or sequences (tensors keep their dtype, device and grad);
    fov_deg: vertical field of view in degrees; width, height: image size (height defaults to width);
    cx, cy: principal point in pixels (``None``: the image center).
    Raises ``InputError`` when eye == target or up is parallel to the viewing direction.
    """
    eye_t = _as_tensor(eye)
    target_t = _as_tensor(target, eye_t)
    up_t = _as_tensor(up, eye_t)
    fov_t = _as_tensor(fov_deg, eye_t)
    cam = Camera(eye_t, target_t, up_t, fov_t, int(width), int(height if height is not None else width), cx, cy)
    check_camera(cam)
    return cam


def check_camera(cam: Camera) -> None:
    """Raise ``InputError`` if the look-at frame is degenerate (eye == target, up parallel to the view)."""
    fwd = (cam.target - cam.eye).detach().double()
    n = float(torch.linalg.vector_norm(fwd))
    if not n > 1e-12:
        raise InputError(f"camera: expected eye != target, got eye = target = {cam.eye.tolist()}")
    up = cam.up.detach().double()
    nu = float(torch.linalg.vector_norm(up))
    if not nu > 1e-12:
        raise InputError("camera: expected a nonzero up vector, got (0, 0, 0)")
    s = float(torch.linalg.vector_norm(torch.linalg.cross(fwd / n, up / nu)))
    if s < 1e-6:
        raise InputError(f"camera: expected an up vector not parallel to the viewing direction, got up "
                         f"{up.tolist()} and direction {(fwd / n).tolist()}")


def orbit_eye(azimuth_deg, elevation_deg, distance, target=(0.0, 0.0, 0.0)) -> torch.Tensor:
    """Eye position (3,) on an orbit around ``target`` (see the module docstring for the convention)."""
    az = _as_tensor(azimuth_deg)
    el = _as_tensor(elevation_deg, az)
    dist = _as_tensor(distance, az)
    tgt = _as_tensor(target, az)
    az_r, el_r = torch.deg2rad(az), torch.deg2rad(el)
    d = torch.stack([torch.cos(el_r) * torch.sin(az_r), torch.sin(el_r), torch.cos(el_r) * torch.cos(az_r)])
    return tgt + dist * d.to(tgt.dtype)


def orbit_camera(azimuth_deg, elevation_deg, distance=PROTOCOL_DISTANCE, target=(0.0, 0.0, 0.0),
                 fov_deg=PROTOCOL_FOV_DEG, width: int = 256, height: int | None = None, *,
                 cx: float | None = None, cy: float | None = None) -> Camera:
    """A camera on an orbit around ``target``, Y up, looking at ``target``.

    azimuth_deg, elevation_deg, distance, fov_deg: floats or 0-dim tensors (differentiable);
    target: (3,); cx, cy: principal point in pixels (``None``: the image center). With known
    intrinsics: ``orbit_camera(az, el, d, fov_deg=intr.fov_deg, width=intr.width, height=intr.height,
    cx=intr.cx, cy=intr.cy)``. Raises ``InputError`` for |elevation| >= 90° or distance <= 0.
    """
    el = float(torch.as_tensor(elevation_deg).detach())
    if not abs(el) < 90.0:
        raise InputError(f"orbit camera elevation: expected a value in (-90, 90) degrees, got {el}")
    dist = float(torch.as_tensor(distance).detach())
    if not dist > 0:
        raise InputError(f"orbit camera distance: expected a positive value, got {dist}")
    eye = orbit_eye(azimuth_deg, elevation_deg, distance, target)
    tgt = _as_tensor(target, eye)
    up = torch.tensor([0.0, 1.0, 0.0], dtype=eye.dtype, device=eye.device)
    return look_at_camera(eye, tgt, up, _as_tensor(fov_deg, eye), width, height, cx=cx, cy=cy)


def detach_camera(cam: Camera) -> Camera:
    """The same camera with its tensors detached from any autograd graph."""
    return Camera(cam.eye.detach(), cam.target.detach(), cam.up.detach(), cam.fov_deg.detach(),
                  cam.width, cam.height, cam.cx, cam.cy)


def camera_frame(cam: Camera) -> torch.Tensor:
    """Rotation (3, 3) whose rows are the camera's right, up and backward (+Z) axes in world space."""
    fwd = _normalize(cam.target - cam.eye)
    right = _normalize(torch.linalg.cross(fwd, cam.up.to(fwd.dtype)))
    up = torch.linalg.cross(right, fwd)
    return torch.stack([right, up, -fwd])


def view_matrix(cam: Camera) -> torch.Tensor:
    """World-to-camera transform (4, 4), same dtype and device as ``cam.eye``."""
    R = camera_frame(cam)
    t = -(R @ cam.eye)
    top = torch.cat([R, t[:, None]], dim=1)
    bottom = torch.tensor([[0.0, 0.0, 0.0, 1.0]], dtype=R.dtype, device=R.device)
    return torch.cat([top, bottom], dim=0)


def projection(cam: Camera, near: float = 0.01, far: float = 100.0) -> torch.Tensor:
    """OpenGL perspective projection matrix (4, 4): camera space to clip space (NDC in [-1, 1]^3).

    NDC x = -1 is the left image edge and y = +1 the top one, so pixel ``x = (x_ndc + 1) W / 2``,
    ``y = (1 - y_ndc) H / 2``. An off-center principal point adds the usual third-column terms
    ``1 - 2 cx / W`` and ``2 cy / H - 1`` (zero for the image center).
    """
    if not 0 < near < far:
        raise InputError(f"projection: expected 0 < near < far, got near={near}, far={far}")
    f = 1.0 / torch.tan(torch.deg2rad(cam.fov_deg.to(cam.eye.dtype)) / 2)
    aspect = cam.width / cam.height
    cx, cy = cam.principal_point
    zero = torch.zeros((), dtype=f.dtype, device=f.device)
    one = zero + 1.0
    rows = [
        torch.stack([f / aspect, zero, zero + (1.0 - 2.0 * cx / cam.width), zero]),
        torch.stack([zero, f, zero + (2.0 * cy / cam.height - 1.0), zero]),
        torch.stack([zero, zero, zero + (far + near) / (near - far), zero + 2 * far * near / (near - far)]),
        torch.stack([zero, zero, -one, zero]),
    ]
    return torch.stack(rows)


def focal_pixels(cam: Camera) -> torch.Tensor:
    """Focal length in pixels, 0-dim: ``height / (2 tan(fov / 2))`` (square pixels)."""
    return cam.height / (2 * torch.tan(torch.deg2rad(cam.fov_deg.to(cam.eye.dtype)) / 2))


def to_camera_space(points: torch.Tensor, cam: Camera) -> torch.Tensor:
    """Points (..., 3) in camera coordinates (..., 3); the camera looks down -Z."""
    R = camera_frame(cam).to(points.dtype)
    return (points - cam.eye.to(points.dtype)) @ R.T


def project(points: torch.Tensor, cam: Camera, eps: float = 1e-9) -> tuple[torch.Tensor, torch.Tensor]:
    """Project world points to pixels.

    points: (..., 3) float. Returns ``(xy (..., 2), depth (...))``: pixel coordinates (x right, y down,
    pixel centers at +0.5, the camera axis at the principal point) and depth along the viewing axis
    (positive in front of the camera). Points at or behind the camera get meaningless pixel coordinates;
    check ``depth > 0``.
    """
    if points.shape[-1:] != (3,):
        raise InputError(f"project: expected points (..., 3), got {tuple(points.shape)}")
    pc = to_camera_space(points, cam)
    depth = -pc[..., 2]
    fpx = focal_pixels(cam).to(points.dtype)
    inv = 1.0 / torch.where(depth.abs() > eps, depth, torch.full_like(depth, eps))
    cx, cy = cam.principal_point
    x = cx + fpx * pc[..., 0] * inv
    y = cy - fpx * pc[..., 1] * inv
    return torch.stack([x, y], dim=-1), depth


def pixel_rays(cam: Camera, dtype=None) -> tuple[torch.Tensor, torch.Tensor]:
    """Rays through the pixel centers.

    Returns ``(origin (3,), directions (H, W, 3))``: unit directions in world space, row 0 at the top.
    Differentiable in the camera; dtype defaults to the camera's.
    """
    dtype = dtype or cam.eye.dtype
    dev = cam.eye.device
    fpx = focal_pixels(cam).to(dtype)
    xs = torch.arange(cam.width, dtype=dtype, device=dev) + 0.5
    ys = torch.arange(cam.height, dtype=dtype, device=dev) + 0.5
    cx, cy = cam.principal_point
    u = (xs - cx) / fpx
    v = -(ys - cy) / fpx
    d_cam = torch.stack(torch.broadcast_tensors(u[None, :], v[:, None], -torch.ones_like(v)[:, None]), -1)
    R = camera_frame(cam).to(dtype)
    d = _normalize(d_cam @ R)
    return cam.eye.to(dtype), d


# -- known intrinsics and crops ---------------------------------------------------------------------

NON_SQUARE_TOLERANCE = 0.01  # relative |fx - fy| accepted as square pixels (the camera then uses fy)


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics of a real camera, in pixels: focal lengths ``fx, fy``, principal point
    ``cx, cy`` (pixel ``(i, j)`` has its center at ``(i + 0.5, j + 0.5)``) and the image size.

    ipm's cameras have square pixels, so ``fx`` and ``fy`` must agree within 1 % (relative to the larger);
    ``InputError`` beyond. Within the tolerance but different, the camera uses ``fy`` (it fixes the
    vertical field of view, :attr:`fov_deg`), ``fx`` is ignored and a warning is logged.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def __post_init__(self) -> None:
        for name in ("fx", "fy", "cx", "cy"):
            v = getattr(self, name)
            if not _is_number(v):
                raise InputError(f"intrinsics {name}: expected a finite number of pixels, got {v!r}")
            object.__setattr__(self, name, float(v))
        for name in ("fx", "fy"):
            if not getattr(self, name) > 0:
                raise InputError(f"intrinsics {name}: expected a positive focal length in pixels, "
                                 f"got {getattr(self, name)!r}")
        for name in ("width", "height"):
            v = getattr(self, name)
            if not (_is_number(v) and float(v).is_integer() and v > 0):
                raise InputError(f"intrinsics {name}: expected a positive integer number of pixels, got {v!r}")
            object.__setattr__(self, name, int(v))
        fx, fy = self.fx, self.fy
        rel = abs(fx - fy) / max(fx, fy)
        if rel > NON_SQUARE_TOLERANCE:
            raise InputError(f"non-square pixels are not supported: fx={fx:g}, fy={fy:g}; expected fx within "
                             f"1% of fy")
        if rel > 0:
            log.warning("intrinsics: fx=%g and fy=%g differ by %.3g%%; using fy (square pixels)",
                        fx, fy, 100 * rel)

    @property
    def fov_deg(self) -> float:
        """Vertical field of view in degrees, ``2 atan(height / (2 fy))``."""
        return math.degrees(2.0 * math.atan(self.height / (2.0 * self.fy)))

    @property
    def K(self) -> list[list[float]]:
        """The 3x3 calibration matrix ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``."""
        return [[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]]


def intrinsics_camera(intr: Intrinsics, eye, target, up=(0.0, 1.0, 0.0)) -> Camera:
    """A camera with the intrinsics ``intr`` at ``eye`` looking at ``target`` (see :func:`look_at_camera`;
    the focal length is ``intr.fy``)."""
    return look_at_camera(eye, target, up, intr.fov_deg, intr.width, intr.height, cx=intr.cx, cy=intr.cy)


def crop_camera(cam: Camera, x0: int, y0: int, width: int, height: int, scale: float = 1.0) -> Camera:
    """The camera whose image is the pixel window ``[x0, x0 + width) x [y0, y0 + height)`` of ``cam``'s
    image, resized by ``scale``.

    Pixel coordinates map exactly by ``x' = (x - x0) * scale``, ``y' = (y - y0) * scale`` (pixel
    corners, not centers: pixel ``(i, j)`` has its center at ``(i + 0.5, j + 0.5)`` in both images),
    so the focal length in pixels becomes ``focal * scale`` and the principal point
    ``((cx - x0) * scale, (cy - y0) * scale)``. The new image is ``round(width * scale)`` x
    ``round(height * scale)`` pixels (at least 1); when ``width * scale`` or ``height * scale`` is not an
    integer the new image covers the window up to less than half a new pixel at its right or bottom edge
    (the pixels stay square, with the one scale). The vertical field of view is recomputed from the new
    height and focal length (differentiable in the camera's fov). x0, y0: integers (may lie outside
    the image); width, height: positive integers; scale: a positive finite number.
    """
    for name, v in (("x0", x0), ("y0", y0), ("width", width), ("height", height)):
        if isinstance(v, bool) or not isinstance(v, numbers.Integral):
            raise InputError(f"crop_camera {name}: expected an integer number of pixels, got {v!r}")
    if width < 1 or height < 1:
        raise InputError(f"crop_camera: expected a window of positive size, got {width}x{height}")
    if not (_is_number(scale) and scale > 0):
        raise InputError(f"crop_camera scale: expected a positive finite number, got {scale!r}")
    new_w, new_h = max(1, round(width * scale)), max(1, round(height * scale))
    f_new = focal_pixels(cam) * scale
    fov = torch.rad2deg(2 * torch.atan(new_h / (2 * f_new)))
    cx, cy = cam.principal_point
    return Camera(cam.eye, cam.target, cam.up, fov, new_w, new_h, (cx - int(x0)) * scale, (cy - int(y0)) * scale)


def _intrinsics_from_mapping(data: object, where: str) -> Intrinsics:
    """:class:`Intrinsics` from parsed JSON or YAML: ``fx, fy, cx, cy`` or a 3x3 ``K``, and the size as
    ``width, height`` or ``xres, yres``. ``where`` prefixes the messages."""
    expected = ("expected fx, fy, cx, cy (or a 3x3 K) and width, height (or xres, yres)")
    if not isinstance(data, dict):
        got = "an empty file" if data is None else type(data).__name__
        raise InputError(f"{where}: {expected}, got {got}")
    vals = {}
    if "K" in data:
        if any(k in data for k in ("fx", "fy", "cx", "cy")):
            raise InputError(f"{where}: expected either K or fx, fy, cx, cy, got both")
        K = data["K"]
        if not (isinstance(K, list) and len(K) == 3
                and all(isinstance(r, list) and len(r) == 3 and all(_is_number(x) for x in r) for r in K)):
            raise InputError(f"{where}: K: expected a 3x3 list of numbers, got {K!r}")
        if K[0][1] != 0 or K[1][0] != 0 or K[2] != [0, 0, 1]:
            raise InputError(f"{where}: K: expected [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (no skew), got {K!r}")
        vals = {"fx": K[0][0], "fy": K[1][1], "cx": K[0][2], "cy": K[1][2]}
    else:
        for k in ("fx", "fy", "cx", "cy"):
            if k not in data:
                raise InputError(f"{where}: missing {k}; {expected}")
            vals[k] = data[k]
    for k, alt in (("width", "xres"), ("height", "yres")):
        if k in data:
            vals[k] = data[k]
        elif alt in data:
            vals[k] = data[alt]
        else:
            raise InputError(f"{where}: missing {k} (or {alt}); {expected}")
    try:
        return Intrinsics(**vals)
    except InputError as e:
        raise InputError(f"{where}: {e}") from None


def _parse_json_intrinsics(path: Path, what: str) -> object:
    """JSON: fx fy cx cy width height, or a 3x3 K with width and height."""
    from ipm.files import read_json

    return read_json(path, what)


def _parse_yaml_intrinsics(path: Path, what: str) -> object:
    """YAML: the JSON keys, or ClearGrasp's camera_intrinsics.yaml (fx fy cx cy xres yres)."""
    import yaml

    from ipm.files import read_text

    text = read_text(path, what)
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as e:
        raise InputError(f"{what} {path}: expected YAML, got a parse error: {' '.join(str(e).split())}") from None
    except RecursionError:  # PyYAML recurses into every nested list and mapping
        raise InputError(f"{what} {path}: expected a flat mapping of intrinsics, got YAML nested too deep "
                         "to read") from None


# intrinsics file parsers by suffix: (path, what) -> a mapping of intrinsics (another format is one more add)
INTRINSICS_FORMATS: Registry[Callable[[Path, str], object]] = Registry("intrinsics format")
INTRINSICS_FORMATS.add(".json", _parse_json_intrinsics)
INTRINSICS_FORMATS.add(".yaml", _parse_yaml_intrinsics)
INTRINSICS_FORMATS.add(".yml", _parse_yaml_intrinsics)


def load_intrinsics(path: str | Path) -> Intrinsics:
    """Camera intrinsics from a file, by suffix:

    - ``.json``: ``{"fx", "fy", "cx", "cy", "width", "height"}``, or ``{"K": [[fx, 0, cx], [0, fy, cy],
      [0, 0, 1]], "width", "height"}``;
    - ``.yaml`` / ``.yml``: the same keys, or ClearGrasp's ``camera_intrinsics.yaml`` (``fx fy cx cy xres
      yres``, comments and other keys allowed).

    Values in pixels (see :class:`Intrinsics` for the checks). Raises ``InputError`` naming the file on a
    missing or unreadable file, an unknown suffix, a parse error, a missing key or a bad value.
    """
    path = Path(path)
    what = "intrinsics file"
    parse = INTRINSICS_FORMATS.get(path.suffix.lower()) if path.suffix.lower() in INTRINSICS_FORMATS else None
    if parse is None:
        raise InputError(f"{what} {path}: expected a {', '.join(INTRINSICS_FORMATS)} file, "
                         f"got suffix {path.suffix or '(none)'!r}")
    return _intrinsics_from_mapping(parse(path, what), f"{what} {path}")


def input_view_azimuths(k: int) -> list[float]:
    """Azimuths (degrees) of the protocol's K input views: 30° + i·90° for K <= 4 (K = 2 is two
    orthogonal views: opposite views leave the depth along their common axis nearly free), 30° + i·360°/K
    beyond."""
    if not isinstance(k, int) or k < 1:
        raise InputError(f"input views: expected a positive number of views, got {k}")
    step = 90.0 if k <= 4 else 360.0 / k
    return [30.0 + i * step for i in range(k)]


def input_views(k: int, size: int = 256, distance: float = PROTOCOL_DISTANCE) -> list[Camera]:
    """The protocol's K input views (DESIGN.md, protocol v2): FOV 40°, elevation 25°, distance 3.2 from the
    origin (``distance`` overrides it), azimuths from :func:`input_view_azimuths`."""
    azimuths = input_view_azimuths(k)
    _check_size(size)
    return [orbit_camera(az, PROTOCOL_ELEVATION_DEG, distance, fov_deg=PROTOCOL_FOV_DEG, width=size, height=size)
            for az in azimuths]


def heldout_views(size: int = 256, distance: float = PROTOCOL_DISTANCE) -> list[Camera]:
    """The protocol's 16 held-out views: azimuths 11.25° + k·22.5°, elevations 10° and 40° alternating,
    FOV 40°, distance 3.2 (``distance`` overrides it)."""
    _check_size(size)
    return [orbit_camera(11.25 + i * 22.5, 10.0 if i % 2 == 0 else 40.0, distance,
                         fov_deg=PROTOCOL_FOV_DEG, width=size, height=size) for i in range(16)]


def _check_size(size: int) -> None:
    if not isinstance(size, int) or size < 1:
        raise InputError(f"image size: expected a positive integer, got {size!r}")


# -- cameras.json ------------------------------------------------------------------------------------

def cameras_to_json(cameras: Sequence[Camera]) -> str:
    """cameras.json text: a JSON list with one ``{eye, target, up, fov_deg, width, height}`` per view, plus
    ``cx, cy`` (principal point, pixels) for cameras that set them."""
    return json.dumps([c.to_json() for c in cameras], indent=2) + "\n"


# the keys of a cameras.json entry
CAMERA_KEYS = ("eye", "target", "up", "fov_deg", "width", "height", "cx", "cy")
# how deeply cameras.json nests: a list of entries (under "cameras") holding lists of numbers
CAMERAS_NESTING = 4


def cameras_from_json(data: object, source: str = "cameras.json") -> list[Camera]:
    """Cameras from parsed cameras.json data (a list of entries, or ``{"cameras": [...]}``).

    Raises ``InputError`` naming the entry and the missing, malformed or unknown field (an entry's keys are
    :data:`CAMERA_KEYS`; ``{"cameras": [...]}`` has no other key).
    """
    if isinstance(data, dict) and "cameras" in data:
        if len(data) > 1:
            raise InputError(f"{source}: unknown key(s) {', '.join(sorted(map(repr, set(data) - {'cameras'})))}"
                             " beside 'cameras'; allowed: cameras")
        data = data["cameras"]
    if not isinstance(data, list):
        raise InputError(f"{source}: expected a JSON list of camera entries, got {type(data).__name__}")
    cams = []
    for i, entry in enumerate(data):
        if not isinstance(entry, dict):
            raise InputError(f"{source}: entry {i}: expected an object with eye, target, up, fov_deg, "
                             f"width, height, got {type(entry).__name__}")
        unknown = sorted(str(k) for k in entry if k not in CAMERA_KEYS)
        if unknown:
            raise InputError(f"{source}: entry {i}: unknown key(s) {', '.join(map(repr, unknown))}; allowed: "
                             f"{', '.join(CAMERA_KEYS)}")
        try:
            for key in ("eye", "target", "up"):
                v = entry.get(key)
                if not (isinstance(v, list) and len(v) == 3 and all(_is_number(x) for x in v)):
                    if key not in entry:
                        break  # reported by Camera.from_json with the list of fields
                    raise InputError(f"{key}: expected a list of 3 numbers, got {v!r}")
            for key in ("width", "height"):
                if key in entry and not (isinstance(entry[key], int) and not isinstance(entry[key], bool)):
                    raise InputError(f"{key}: expected an integer, got {entry[key]!r}")
            if "fov_deg" in entry and not _is_number(entry["fov_deg"]):
                raise InputError(f"fov_deg: expected a number, got {entry['fov_deg']!r}")
            for key in ("cx", "cy"):
                if key in entry and not _is_number(entry[key]):
                    raise InputError(f"{key}: expected a number of pixels, got {entry[key]!r}")
            cam = Camera.from_json(entry)
            check_camera(cam)
        except InputError as e:
            raise InputError(f"{source}: entry {i}: {e}") from None
        cams.append(cam)
    return cams


def _is_number(x) -> bool:
    return isinstance(x, numbers.Real) and not isinstance(x, bool) and math.isfinite(x)


def save_cameras(path: str | Path, cameras: Sequence[Camera]) -> Path:
    """Write cameras.json atomically."""
    from ipm.files import write_text

    return write_text(path, cameras_to_json(cameras))


def load_cameras(path: str | Path) -> list[Camera]:
    """Read and validate a cameras.json file (``InputError`` with the file and entry on bad input; JSON
    nested deeper than a cameras file, :data:`CAMERAS_NESTING`, is refused before it is parsed)."""
    from ipm.files import read_json

    path = Path(path)
    if not path.is_file():
        raise InputError(f"cameras file: expected an existing file, got {path}")
    try:
        data = read_json(path, "cameras file", max_nesting=CAMERAS_NESTING,
                         too_deep=f"expected a list of camera entries, JSON nested at most {CAMERAS_NESTING} deep "
                                  "(the limit)")
    except InputError as e:
        head, sep, why = str(e).partition(" is not valid JSON: ")
        if not sep:
            raise
        raise InputError(f"{head}: expected JSON, got a parse error: {why}") from None
    return cameras_from_json(data, str(path))
